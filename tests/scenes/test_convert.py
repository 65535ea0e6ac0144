"""``python -m scenes.convert``: the README's "your own data" commands, run on each layout's fixture."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scenes import load
from scenes.convert import main
from tests.scenes.test_e2nerf import write_e2nerf, write_ebad_nerf

ROOT = Path(__file__).resolve().parents[2]


def test_ebad_nerf_folder_converts(tmp_path, capsys):
    write_ebad_nerf(tmp_path / "scene")
    assert main([str(tmp_path / "scene"), "--out", str(tmp_path / "capture")]) == 0
    out = capsys.readouterr().out
    assert "layout: ebad-nerf" in out and "binned: 4 bins" in out and "nominal" in out and "test views: 2" in out
    src, cap = load(tmp_path / "scene"), load(tmp_path / "capture")
    np.testing.assert_array_equal(cap.frames, src.frames)
    np.testing.assert_array_equal(cap.events.t, src.events.t)
    np.testing.assert_array_equal(cap.c2w, src.c2w)
    assert cap.meta["events_binned"]["bins"] == 4


def test_ebad_nerf_llffhold_option(tmp_path):
    write_ebad_nerf(tmp_path / "scene", novel=False, gt_blur=False)
    assert main([str(tmp_path / "scene"), "--out", str(tmp_path / "c"), "--llffhold", "3"]) == 0
    assert load(tmp_path / "c").num_frames == 10  # no images_gt_novel/: nothing held out


def test_e2nerf_folder_converts(tmp_path, capsys):
    write_e2nerf(tmp_path / "lego")
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "capture")]) == 0
    assert "layout: e2nerf" in capsys.readouterr().out
    assert load(tmp_path / "capture").num_frames == 3


def test_ros_bag_converts_with_and_without_exposure_topic(tmp_path, capsys):
    pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")
    from tests.scenes.test_rosbag import write_bag

    write_bag(tmp_path / "rec.bag")
    assert main([str(tmp_path / "rec.bag"), "--out", str(tmp_path / "c1")]) == 0
    assert "layout: rosbag1" in capsys.readouterr().out
    write_bag(tmp_path / "noexp.bag", exposure_topic=False, camera_info=False)
    assert main([str(tmp_path / "noexp.bag"), "--out", str(tmp_path / "c2")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "noexp.bag" in err and "--exposure-us" in err
    assert not (tmp_path / "c2").exists()
    assert (
        main(
            [
                str(tmp_path / "noexp.bag"),
                "--out",
                str(tmp_path / "c2"),
                "--exposure-us",
                "5000",
                "--intrinsics",
                "6",
                "6",
                "3.5",
                "2.5",
            ]
        )
        == 0
    )
    cap = load(tmp_path / "c2")
    np.testing.assert_allclose(np.diff(cap.exposures, axis=1), 0.005)
    np.testing.assert_array_equal(cap.K, [[6, 0, 3.5], [0, 6, 2.5], [0, 0, 1]])


def test_user_mistakes_exit_2_with_one_line(tmp_path, capsys):
    assert main([str(tmp_path / "nothing"), "--out", str(tmp_path / "c")]) == 2
    assert "no such file" in capsys.readouterr().err
    write_e2nerf(tmp_path / "lego")
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c")]) == 0
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c")]) == 2  # exists, no --overwrite
    assert "already exists" in capsys.readouterr().err
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c"), "--overwrite"]) == 0


def test_runs_as_a_module(tmp_path):
    write_e2nerf(tmp_path / "lego")
    r = subprocess.run(
        [sys.executable, "-m", "scenes.convert", str(tmp_path / "lego"), "--out", str(tmp_path / "c")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and (tmp_path / "c" / "capture.json").is_file()


def test_overwrite_replaces_only_a_capture_folder(tmp_path, capsys):
    """The rule of ``ebad synth --overwrite`` (scenes.synth.check_replaceable): a folder of a user's own files is
    refused, one line, nothing deleted; a capture written before is replaced."""
    write_e2nerf(tmp_path / "lego")
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c")]) == 0
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c"), "--overwrite"]) == 0  # a capture: replaced
    assert load(tmp_path / "c").num_frames == 3
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "thesis.txt").write_text("years of work")
    capsys.readouterr()
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "f"), "--overwrite"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refusing to overwrite" in err and "thesis.txt" in err and "--out" in err
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == ["thesis.txt"]
    assert (tmp_path / "f" / "thesis.txt").read_text() == "years of work"
    (tmp_path / "c" / "notes.txt").write_text("mine")  # a capture with a user's file added: refused too
    assert main([str(tmp_path / "lego"), "--out", str(tmp_path / "c"), "--overwrite"]) == 2
    assert (tmp_path / "c" / "notes.txt").read_text() == "mine"
