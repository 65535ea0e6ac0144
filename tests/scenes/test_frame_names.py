"""Frame names: 5 digits wherever a capture's frames carry none (issue 30: ``scenes.convert`` wrote ``00000``,
synth, ``scenes.save`` and ``ebad`` ``0000``); a capture written with 4-digit names keeps them when read."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import scenes
from scenes.capture import frame_name
from scenes.holdout import hold_out


@pytest.fixture(scope="module")
def tiny():
    """The tiny boxes scene's capture (4 frames, one test view), as ``ebad synth`` makes it."""
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1).capture


def test_frame_name_is_the_index_in_5_digits(tiny):
    assert [frame_name(i) for i in (0, 7, 42, 99999)] == ["00000", "00007", "00042", "99999"]
    assert dataclasses.replace(tiny, names=[]).frame_names() == ["00000", "00001", "00002", "00003"]


def test_synth_and_save_name_frames_in_5_digits(tiny, tmp_path):
    cap = dataclasses.replace(
        tiny,
        frames=tiny.frames[:3],
        exposures=tiny.exposures[:3],
        c2w=tiny.c2w[:3],
        names=tiny.names[:3],
        split=tiny.split[:3],
    )
    assert tiny.names == ["00000", "00001", "00002", "00003"]  # make_scene (ebad synth)
    assert cap.names == ["00000", "00001", "00002"]  # make_scene (ebad synth)
    scenes.save(dataclasses.replace(cap, names=[]), tmp_path / "c")  # a capture without names
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert [fr["name"] for fr in doc["frames"]] == ["00000", "00001", "00002"]
    assert sorted(p.stem for p in (tmp_path / "c" / "frames").iterdir()) == ["00000", "00001", "00002"]
    assert scenes.load(tmp_path / "c").names == ["00000", "00001", "00002"]


def test_duplicate_names_read_back_as_5_digit_indices(tiny, tmp_path):
    scenes.save(tiny, tmp_path / "c")
    jf = tmp_path / "c" / "capture.json"
    doc = json.loads(jf.read_text())
    for fr in doc["frames"]:
        fr["name"] = "same"
    jf.write_text(json.dumps(doc))
    assert scenes.load(tmp_path / "c").names == ["00000", "00001", "00002", "00003"]


def test_a_capture_with_4_digit_names_keeps_them(tiny, tmp_path):
    """Captures written before the change (frames/0000.png, names "0000") read and hold out as before."""
    scenes.save(dataclasses.replace(tiny, names=[f"{i:04d}" for i in range(4)]), tmp_path / "old")
    jf = tmp_path / "old" / "capture.json"
    doc = json.loads(jf.read_text())
    assert doc["frames"][0]["file"] == "frames/0000.png"
    del doc["frames"][2]["name"]  # a frame without a name is named by its file's stem
    jf.write_text(json.dumps(doc))
    old = scenes.load(tmp_path / "old")
    assert old.names == ["0000", "0001", "0002", "0003"] and old.frame_names() == old.names
    held = hold_out(old, test_frames=["0002"])
    assert held.names == ["0000", "0001", "0003"] and [tv.name for tv in held.test_views][-1] == "0002"
    np.testing.assert_array_equal(old.frames, tiny.frames)


def test_ebad_names_unnamed_frames_in_5_digits(tiny):
    """ebad.data (the run's cameras, deblurred frames) names a capture's unnamed frames as convert would."""
    from ebad.config import preset
    from ebad.data import prepare

    cfg = preset("ebad")
    cfg.train.progress = False
    assert prepare(dataclasses.replace(tiny, names=[]), cfg).names == ["00000", "00001", "00002", "00003"]
