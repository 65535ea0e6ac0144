"""``ebad demo``'s run folders are ordinary run folders (issue 30: they had no checkpoints/last.pt
although the README lists it): made from a capture written beside them, resumable and loadable."""

from __future__ import annotations

import json

import pytest

from ebad.cli import main


@pytest.mark.slow
def test_demo_run_folders_resume_and_load(tmp_path, capsys):
    from ebad.runfolder import load_run

    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--size", "tiny", "--seconds", "1", "--iters", "2", "--no-progress"]
    assert main(argv) == 0
    capsys.readouterr()
    for name in ("3dgs", "ebad"):
        run = out / f"run_{name}"
        assert (run / "checkpoints" / "last.pt").is_file() and (run / "config.json").is_file()
        assert json.loads((run / "metrics.json").read_text())["complete"] is True
        assert load_run(run).names == load_run(out / "run_ebad").names  # what render / eval / view open
    assert (out / "capture" / "capture.json").is_file()
    steps = json.loads((out / "run_ebad" / "metrics.json").read_text())["steps"]
    assert steps == 2
    # `--resume` continues the demo's checkpoint from the demo's capture
    cmd = ["reconstruct", str(out / "capture"), "--out", str(out / "run_ebad"), "--resume"]
    assert main([*cmd, "--train.iters", "3", "--train.progress", "False"]) == 0
    assert "--resume applies train.iters = 3 (was 2)" in capsys.readouterr().err
    assert json.loads((out / "run_ebad" / "metrics.json").read_text())["steps"] == 3
