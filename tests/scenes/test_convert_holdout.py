"""Held-out test views and pose trust from the command line (issue 30, item 2): ``python -m
scenes.convert --test-every N --test-frames NAME,NAME --pose-trust ...`` and the same options on
``ebad reconstruct``, on a tiny synthetic capture saved and converted."""

from __future__ import annotations

import json

import numpy as np
import pytest

import scenes
from scenes.convert import hold_out, main


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A tiny posed capture (6 frames, no test views) and a copy without poses, saved as folders."""
    root = tmp_path_factory.mktemp("holdout")
    cap = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=6, n_test=1, sensor="ideal").capture
    cap.test_views, cap.pose_trust = [], None  # unstated: approximate
    scenes.save(cap, root / "posed")
    cap.c2w = None
    scenes.save(cap, root / "unposed")
    return root


def test_test_every_holds_out_frames_as_test_views(saved, tmp_path):
    src = scenes.load(saved / "posed")
    assert main([str(saved / "posed"), "--out", str(tmp_path / "c"), "--test-every", "3"]) == 0
    cap = scenes.load(tmp_path / "c")
    held = [src.names[0], src.names[3]]
    assert cap.num_frames == 4 and [v.name for v in cap.test_views] == held
    assert held[0] not in cap.names and held[1] not in cap.names
    for v, i in zip(cap.test_views, (0, 3), strict=True):
        np.testing.assert_allclose(v.image, src.frames[i], atol=1 / 65535)  # the recorded frame, 16-bit PNG
        np.testing.assert_allclose(v.c2w, src.c2w[i], atol=1e-9)
        assert v.t == pytest.approx(float(src.exposures[i].mean()))
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert doc["meta"]["held_out_frames"] == held and doc.get("pose_trust") == src.pose_trust  # kept


def test_test_frames_and_pose_trust(saved, tmp_path, capsys):
    src = scenes.load(saved / "posed")
    names = f"{src.names[1]},{src.names[4]}"
    rc = main([str(saved / "posed"), "--out", str(tmp_path / "c"), "--test-frames", names, "--pose-trust", "exact"])
    assert rc == 0
    assert "pose trust: exact" in capsys.readouterr().out
    cap = scenes.load(tmp_path / "c")
    assert [v.name for v in cap.test_views] == names.split(",") and cap.num_frames == 4
    assert cap.pose_trust == "exact"
    assert json.loads((tmp_path / "c" / "capture.json").read_text())["pose_trust"] == "exact"


def test_a_capture_without_poses_holds_out_images_only(saved, tmp_path):
    assert main([str(saved / "unposed"), "--out", str(tmp_path / "c"), "--test-every", "2"]) == 0
    cap = scenes.load(tmp_path / "c")
    assert cap.num_frames == 3 and len(cap.test_views) == 3
    assert all(v.c2w is None and v.image is not None for v in cap.test_views)


@pytest.mark.parametrize(
    ("folder", "argv", "says"),
    [
        ("posed", ["--test-frames", "nope"], "--test-frames: no frame named nope"),
        ("posed", ["--test-every", "1"], "hold out all 6 frames"),
        ("posed", ["--test-every", "-1"], "--test-every must be >= 0"),
        ("unposed", ["--pose-trust", "exact"], "--pose-trust exact: the capture's frames carry no poses"),
    ],
)
def test_mistakes_are_one_line_naming_the_option(saved, tmp_path, capsys, folder, argv, says):
    assert main([str(saved / folder), "--out", str(tmp_path / "c"), *argv]) == 2
    err = capsys.readouterr().err
    assert says in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()


def test_hold_out_leaves_the_capture_unchanged(saved):
    src = scenes.load(saved / "posed")
    out = hold_out(src, test_every=4, pose_trust="approximate")
    assert src.num_frames == 6 and not src.test_views and src.pose_trust is None
    assert out.num_frames == 4 and len(out.test_views) == 2 and out.pose_trust == "approximate"
    assert hold_out(src).num_frames == 6


def test_reconstruct_options_hold_out_views_and_state_trust_for_the_run(saved, tmp_path):
    from ebad.cli import main as ebad_main
    from ebad.cli.reconstruct import parse

    args, _, _ = parse(["c", "--out", "r", "--test-every", "3", "--test-frames", "a,b", "--pose-trust", "exact"])
    assert (args.test_every, args.test_frames, args.pose_trust) == (3, "a,b", "exact")
    rc = ebad_main(
        [
            "reconstruct",
            str(saved / "posed"),
            "--out",
            str(tmp_path / "run"),
            "--no-progress",
            "--preset",
            "3dgs",
            "--train.iters",
            "2",
            "--train.eval_every",
            "0",
            "--test-every",
            "3",
            "--pose-trust",
            "exact",
        ]
    )
    assert rc == 0
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["prepare"]["pose_trust"] == "exact" and m["prepare"]["train_frames"] == 4
    assert m["test"] is not None and m["test"]["n"] == 2
    assert scenes.load(saved / "posed").num_frames == 6  # the capture on disk is unchanged


def test_reconstruct_option_mistake_is_one_line(saved, tmp_path, capsys):
    from ebad.cli import main as ebad_main

    rc = ebad_main(["reconstruct", str(saved / "posed"), "--out", str(tmp_path / "run"), "--test-frames", "zz"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--test-frames: no frame named zz" in err and len(err.strip().splitlines()) == 1
