"""Issue 32's security row: names from a capture or a run folder never write outside the output
folder (deblur, render --split train and test, the run's deblurred frames)."""

from __future__ import annotations

import json
import shutil

import pytest

import scenes
from ebad.cli import main
from ebad.runfolder import load_run, write_run

EVIL = "../../x/evil_0"


def _pngs_outside(root, *inside) -> list:
    """Every .png under ``root`` that is in none of the folders ``inside``."""
    return [p for p in root.rglob("*.png") if not any(d in p.parents for d in inside)]


def test_deblur_refuses_a_capture_whose_frame_name_leaves_the_folder(tiny_run, tmp_path, capsys):
    cap = tmp_path / "a" / "cap"
    shutil.copytree(tiny_run.capture, cap)
    doc = json.loads((cap / "capture.json").read_text())
    doc["frames"][0]["name"] = EVIL
    (cap / "capture.json").write_text(json.dumps(doc))
    out = tmp_path / "a" / "out" / "x"
    assert main(["deblur", str(cap), "--out", str(out), "--c", "0.2"]) == 2
    err = capsys.readouterr().err.strip()
    assert "capture.json" in err and "frames[0].name" in err and len(err.splitlines()) == 1
    assert _pngs_outside(tmp_path, cap) == []


def test_deblur_builds_output_paths_only_inside_its_folders(tiny_run, tmp_path, monkeypatch, capsys):
    """Second line of defence: a capture whose names were changed after it was validated."""
    real_load = scenes.load

    def load_then_tamper(path, *a, **k):
        cap = real_load(path, *a, **k)
        cap.names[0] = EVIL
        return cap

    monkeypatch.setattr(scenes, "load", load_then_tamper)
    out = tmp_path / "a" / "out" / "x"
    assert main(["deblur", str(tiny_run.capture), "--out", str(out), "--c", "0.2", "--max-frames", "1"]) == 2
    assert "plain file name" in capsys.readouterr().err
    assert _pngs_outside(tmp_path, out) == []


def test_render_train_refuses_a_run_whose_frame_name_leaves_the_folder(tiny_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run.run, run)
    model = json.loads((run / "model.json").read_text())
    model["names"][0] = EVIL
    (run / "model.json").write_text(json.dumps(model))
    out = tmp_path / "a" / "out" / "x"
    assert main(["render", str(run), "--out", str(out), "--split", "train"]) == 2
    err = capsys.readouterr().err.strip()
    assert "plain file name" in err and len(err.splitlines()) == 1
    assert _pngs_outside(tmp_path, out, run) == []


def test_render_test_refuses_a_test_view_name_that_leaves_the_folder(tiny_run, tmp_path, capsys):
    cap = tmp_path / "cap"
    shutil.copytree(tiny_run.capture, cap)
    doc = json.loads((cap / "capture.json").read_text())
    doc["test_views"][0]["name"] = "/tmp/evil_test"
    (cap / "capture.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    assert main(["render", str(tiny_run.run), "--capture", str(cap), "--out", str(out)]) == 2
    assert "test_views[0].name" in capsys.readouterr().err
    assert _pngs_outside(tmp_path, cap, out) == []


def test_run_folder_deblurred_frames_stay_inside_the_run(tiny_run, tmp_path):
    run = load_run(tiny_run.run)
    run.names = [EVIL, *run.names[1:]]
    with pytest.raises(scenes.CaptureError):
        write_run(run, tmp_path / "a" / "run")
    assert _pngs_outside(tmp_path, tmp_path / "a" / "run") == []
