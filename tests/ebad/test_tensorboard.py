"""TensorBoard event files behind ``ebad reconstruct --tensorboard`` (issue 30, item 7): read back
with TensorBoard's own reader, the scalars match the run's history.json and the renders are there
at each evaluation; without the package the option is one line naming it, and nothing is written."""

from __future__ import annotations

import importlib.util
import json

import pytest

from ebad.cli import main


def test_event_file_holds_losses_psnr_count_time_and_renders(tiny_run, tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "run"
    argv = ["reconstruct", str(tiny_run.capture), "--out", str(out), "--no-progress", "--tensorboard"]
    assert main([*argv, "--train.iters", "4", "--train.eval_every", "2", "--train.checkpoint_every", "0"]) == 0
    acc = EventAccumulator(str(out / "tensorboard"), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    tags = acc.Tags()
    history = json.loads((out / "history.json").read_text())
    assert [h["step"] for h in history] == [1, 2, 3, 4]

    def series(tag):
        return [(e.step, e.value) for e in acc.Scalars(tag)]

    assert series("loss/total") == [(h["step"], pytest.approx(h["loss"], rel=1e-6)) for h in history]
    assert series("loss/blur") == [(h["step"], pytest.approx(h["blur"], rel=1e-6)) for h in history]
    assert series("psnr/train") == [(h["step"], pytest.approx(h["train_psnr"], rel=1e-6)) for h in history]
    assert series("gaussians") == [(h["step"], h["gaussians"]) for h in history]
    steps_s = [b["time"] - a["time"] for a, b in zip(history, history[1:])]
    assert series("time/step_s") == [(h["step"], pytest.approx(s, abs=1e-5)) for h, s in zip(history[1:], steps_s)]
    if history[0]["c"] is not None:
        assert series("threshold/c_pos") == [(h["step"], pytest.approx(h["c"][0], rel=1e-6)) for h in history]
        assert "threshold/c_neg" in tags["scalars"]
    evaluated = [(h["step"], pytest.approx(h["test_psnr"], rel=1e-6)) for h in history if h["test_psnr"] is not None]
    assert evaluated and series("psnr/test") == evaluated
    # renders at each evaluation (steps 2 and 4): the first training frame and every posed test view
    cap_names = json.loads((tiny_run.capture / "capture.json").read_text())
    first = cap_names["frames"][0]["name"]
    test_names = [v["name"] for v in cap_names.get("test_views", []) if "c2w" in v]
    assert sorted(tags["images"]) == sorted([f"render/train_{first}", *(f"render/{n}" for n in test_names)])
    for tag in tags["images"]:
        imgs = acc.Images(tag)
        assert [i.step for i in imgs] == [2, 4]
        assert (imgs[0].width, imgs[0].height) == (tiny_run.scene.capture.width, tiny_run.scene.capture.height)


def test_without_the_package_the_option_is_one_line_and_writes_nothing(tiny_run, tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "tensorboard" else real(name, *a))
    rc = main(["reconstruct", str(tiny_run.capture), "--out", str(tmp_path / "r"), "--tensorboard", "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--tensorboard needs the tensorboard package" in err
    assert "pip install 'ebad[tensorboard]'" in err
    assert not (tmp_path / "r").exists()
