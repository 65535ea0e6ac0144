"""``ebad eval``: scores before and after pose refinement, the renders and the JSON it writes."""

from __future__ import annotations

import json

from ebad.cli import main


def test_eval_cli_reports_before_and_after_and_writes_renders(tiny_run, tmp_path, capsys):
    out = tmp_path / "renders"
    assert (
        main(
            [
                "eval",
                str(tiny_run.run),
                str(tiny_run.capture),
                "--refine-poses",
                "--refine-iters",
                "30",
                "--renders",
                str(out),
                "--out",
                str(tmp_path / "e.json"),
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    text = captured.out
    assert "test views, poses refined" in text and "deblurred training frames" in text
    res = json.loads((tmp_path / "e.json").read_text())
    n = len(res["poses"])  # the refinement says how far it is, its first and last view at least
    for k in (1, n):
        assert f"ebad: refining test poses (up to 30 steps a view): {k}/{n} (" in captured.err
    assert res["test_refined"]["psnr"] >= res["test"]["psnr"] - 1e-6  # the best pose seen is kept
    assert set(res["refine_steps"]) == set(res["poses"]) and max(res["refine_steps"].values()) <= 30
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(res["poses"])
