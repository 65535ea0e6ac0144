"""Synthetic scenes: blur, ground truth, events consistent with the renders, writing, the CLI."""
import math

import numpy as np
import pytest

from ebad.cli import main
from edi.deblur import LOG_EPS
from scenes import SCENES, load, make_scene, write_scene


@pytest.fixture(scope="module")
def boxes():
    return make_scene("boxes", "tiny", seed=0, sigma_c=0.0)


def test_scenes_registry_has_two_scenes():
    assert {"boxes", "spheres"} <= set(SCENES)


def test_tiny_scene_shapes_and_ground_truth(boxes):
    cap = boxes.capture
    assert cap.frames.shape == (10, 48, 64, 1)
    assert boxes.gt_frames.shape == cap.frames.shape and boxes.gt_depths.shape == (10, 48, 64)
    assert cap.c2w.shape == (10, 4, 4) and len(cap.test_views) == 3
    # frames are 8-bit quantised
    assert np.all(np.abs(cap.frames * 255 - np.round(cap.frames * 255)) < 1e-4)
    # the recorded poses are the true mid-exposure poses, and gt frames are renders there
    mids = cap.exposures.mean(axis=1)
    for k in (0, 7):
        np.testing.assert_allclose(cap.c2w[k], boxes.gt_c2w_at(k, mids[k]), atol=1e-12)
        np.testing.assert_array_equal(boxes.gt_frames[k], np.clip(boxes.render(cap.c2w[k]), 0, 1))
    # a textured scene: every frame has plenty of contrast, and no pixel sees the void
    assert (boxes.gt_depths > 0).all()
    assert all(f.std() > 0.1 for f in boxes.gt_frames)
    assert cap.meta["c"] == 0.2
    # test views are held out: away from every training pose, with sharp images
    centres = cap.c2w[:, :3, 3]
    for tv in cap.test_views:
        assert np.linalg.norm(centres - tv.c2w[:3, 3], axis=1).min() > 0.05
        np.testing.assert_array_equal(tv.image, np.clip(boxes.render(tv.c2w), 0, 1))


def test_blur_is_visible_at_shake_one_and_gone_at_zero(boxes):
    blur = np.abs(boxes.capture.frames - boxes.gt_frames).mean(axis=(1, 2, 3))
    assert blur.min() > 0.02  # every frame clearly differs from its sharp mid-exposure render
    still = make_scene("boxes", "tiny", seed=0, shake=0.0, n_frames=3, n_test=1)
    diff = np.abs(still.capture.frames - still.gt_frames).max()
    assert diff <= 0.5 / 255 + 1e-6  # only 8-bit quantisation remains
    # the blurry frame is the exposure average of renders
    k = 4
    t0, t1 = boxes.capture.exposures[k]
    ts = np.linspace(t0, t1, 33)
    w = np.full(33, 1 / 32)
    w[[0, -1]] /= 2
    avg = np.tensordot(w, boxes.render(boxes.c2w_at(ts)), axes=1)
    np.testing.assert_allclose(boxes.capture.frames[k], avg, atol=0.5 / 255 + 1e-6)


def test_sharp_fraction_makes_some_frames_sharp_and_silent():
    sc = make_scene("spheres", "tiny", seed=3, sharp_fraction=0.3, n_frames=6, n_test=1)
    sharp = sc.capture.meta["sharp_frames"]
    assert len(sharp) == 2
    ev = sc.capture.events
    for k in range(6):
        t0, t1 = sc.capture.exposures[k]
        n = len(ev.slice_time(t0, t1))
        err = np.abs(sc.capture.frames[k] - sc.gt_frames[k]).max()
        if k in sharp:
            assert n == 0 and err <= 0.5 / 255 + 1e-6
        else:
            assert n > 500 and err > 0.1


def test_events_cover_the_whole_capture_and_match_log_intensity_changes(boxes):
    cap = boxes.capture
    ev = cap.events
    assert np.all(np.diff(ev.t) >= 0) and ev.x.max() < 64 and ev.y.max() < 48
    # events also fire between exposures (the camera moves there)
    gap = ev.slice_time(cap.exposures[2, 1], cap.exposures[3, 0])
    assert len(gap) > 1000
    # with sigma_c = 0: c * (net events between two instants) tracks the log-intensity change
    c = cap.meta["c"]
    dt = cap.meta["exposure"] / cap.meta["n_blur"]
    ta, tb = 100 * dt, 230 * dt  # two render instants of the simulator's grid
    la, lb = (np.log(boxes.render(boxes.c2w_at(t))[..., 0].astype(np.float64) + LOG_EPS) for t in (ta, tb))
    net = ev.slice_time(ta, tb).count_image()
    resid = np.abs(lb - la - c * net)
    assert resid.max() < 2 * c + 1e-6
    assert resid.mean() < c


def test_gt_c2w_at_checks_the_exposure_and_trajectory_is_continuous(boxes):
    cap = boxes.capture
    t0, t1 = cap.exposures[2]
    traj = boxes.gt_trajectory(2, 5)
    assert traj.shape == (5, 4, 4)
    assert np.linalg.norm(traj[0, :3, 3] - traj[-1, :3, 3]) > 1e-3  # the camera moves in the exposure
    with pytest.raises(ValueError, match="exposure"):
        boxes.gt_c2w_at(2, t1 + 0.01)
    with pytest.raises(ValueError, match="frame_index"):
        boxes.gt_c2w_at(10, t0)
    ts = np.linspace(0, cap.exposures[-1, 1] + 0.02, 4000)
    poses = boxes.c2w_at(ts)
    steps = np.abs(np.diff(poses, axis=0)).max()
    assert steps < 0.01  # no jumps anywhere, exposure boundaries included


def test_rgb_scene_and_determinism():
    a = make_scene("spheres", "tiny", seed=1, rgb=True, n_frames=3, n_test=1)
    b = make_scene("spheres", "tiny", seed=1, rgb=True, n_frames=3, n_test=1)
    assert a.capture.frames.shape == (3, 48, 64, 3)
    np.testing.assert_array_equal(a.capture.frames, b.capture.frames)
    np.testing.assert_array_equal(a.capture.events.t, b.capture.events.t)
    grey = a.capture.frames.std(axis=3).mean()
    assert grey > 0.01  # genuinely coloured


def test_noise_adds_events():
    quiet = make_scene("boxes", "tiny", n_frames=2, n_test=0, shake=0.0)
    noisy = make_scene("boxes", "tiny", n_frames=2, n_test=0, shake=0.0, noise_hz=2.0)
    span = quiet.capture.exposures[-1, 1] + 0.02
    extra = len(noisy.capture.events) - len(quiet.capture.events)
    expected = 2.0 * span * 64 * 48
    assert abs(extra - expected) < 5 * math.sqrt(expected)


@pytest.mark.parametrize("kwargs, word", [
    (dict(name="teapot"), "name"), (dict(size="huge"), "size"), (dict(shake=-1.0), "shake"),
    (dict(n_frames=1), "n_frames"), (dict(n_test=20), "n_test"), (dict(exposure=0.5), "exposure"),
    (dict(sharp_fraction=2.0), "sharp_fraction"),
])
def test_make_scene_bad_arguments(kwargs, word):
    with pytest.raises(ValueError, match=word):
        make_scene(**kwargs)


def test_write_scene_keeps_ground_truth_apart(tmp_path, boxes):
    out = write_scene(boxes, tmp_path / "s")
    assert sorted(p.name for p in out.iterdir()) == ["capture", "gt"]
    cap = load(out / "capture")
    np.testing.assert_array_equal(cap.frames, boxes.capture.frames)
    np.testing.assert_array_equal(cap.events.t, boxes.capture.events.t)
    np.testing.assert_array_equal(cap.c2w, boxes.capture.c2w)
    for tv, tv0 in zip(cap.test_views, boxes.capture.test_views):
        np.testing.assert_array_equal(tv.image, tv0.image)
    assert not any("gt" in p.name for p in (out / "capture").rglob("*"))
    assert (out / "gt" / "gt.json").is_file() and len(list((out / "gt" / "frames").iterdir())) == 10
    import json

    from scenes.images import read_image

    doc = json.loads((out / "gt" / "gt.json").read_text())
    np.testing.assert_array_equal(read_image(out / "gt" / doc["frames"][3]["file"]), boxes.gt_frames[3])
    np.testing.assert_allclose(doc["frames"][3]["trajectory"]["c2w"], boxes.gt_trajectory(3, 9))
    assert len(doc["test_views"]) == 3
    with pytest.raises(ValueError, match="out_dir"):
        write_scene(boxes, tmp_path / "s")


def test_cli_synth(tmp_path, capsys):
    rc = main(["synth", "spheres", "--out", str(tmp_path / "o"), "--frames", "3", "--test-views", "1", "--seed", "2"])
    assert rc == 0
    cap = load(tmp_path / "o" / "capture")
    assert cap.num_frames == 3 and len(cap.test_views) == 1 and cap.meta["seed"] == 2
    assert "3 frames" in capsys.readouterr().out
    rc = main(["synth", "spheres", "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "out_dir" in capsys.readouterr().err


def test_write_scene_failing_midway_leaves_nothing(tmp_path, boxes, monkeypatch):
    import scenes.synth as synth

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(synth, "write_image", boom)
    with pytest.raises(OSError, match="disk full"):
        write_scene(boxes, tmp_path / "s")
    assert list(tmp_path.iterdir()) == []
