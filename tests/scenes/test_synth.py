"""Synthetic scenes: blur, ground truth, events consistent with the renders, writing (the CLI:
tests/ebad/cli/test_synth.py);
the realistic sensor (response, thresholds, noise, tremor, poses) and the no-leak property."""

import json
import math
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from edi.deblur import LOG_EPS
from scenes import SCENES, CaptureError, load, make_scene, write_scene
from scenes.synth import SENSORS, TRUTH_KEYS, Sensor, aps_record, aps_response, sensor_events

REALISTIC = SENSORS["realistic"]
BUILD_TIME = {}


@pytest.fixture(scope="module")
def boxes():
    t0 = time.process_time()
    sc = make_scene("boxes", "tiny", seed=0, sigma_c=0.0, sensor="ideal")
    BUILD_TIME["ideal"] = time.process_time() - t0
    return sc


@pytest.fixture(scope="module")
def real():
    t0 = time.process_time()
    sc = make_scene("boxes", "tiny", seed=0)  # the default sensor is the realistic one
    BUILD_TIME["realistic"] = time.process_time() - t0
    return sc


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
    assert boxes.truth["c"] == [0.2, 0.2] and cap.pose_trust == "exact"
    # test views are held out: away from every training pose, with sharp images
    centres = cap.c2w[:, :3, 3]
    for tv in cap.test_views:
        assert np.linalg.norm(centres - tv.c2w[:3, 3], axis=1).min() > 0.05
        np.testing.assert_array_equal(tv.image, np.clip(boxes.render(tv.c2w), 0, 1))


def test_blur_is_visible_at_shake_one_and_gone_at_zero(boxes):
    blur = np.abs(boxes.capture.frames - boxes.gt_frames).mean(axis=(1, 2, 3))
    assert blur.min() > 0.02  # every frame clearly differs from its sharp mid-exposure render
    still = make_scene("boxes", "tiny", seed=0, shake=0.0, n_frames=3, n_test=1, sensor="ideal")
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
    sc = make_scene("spheres", "tiny", seed=3, sharp_fraction=0.3, n_frames=6, n_test=1, sensor="ideal")
    sharp = sc.truth["sharp_frames"]
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
    c = boxes.truth["c"][0]
    dt = boxes.truth["exposure"] / boxes.truth["n_blur"]
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
    assert a.sensor == REALISTIC
    assert a.capture.frames.shape == (3, 48, 64, 3)
    np.testing.assert_array_equal(a.capture.frames, b.capture.frames)
    np.testing.assert_array_equal(a.capture.events.t, b.capture.events.t)
    grey = a.capture.frames.std(axis=3).mean()
    assert grey > 0.01  # genuinely coloured


def test_noise_adds_events():
    quiet = make_scene("boxes", "tiny", n_frames=2, n_test=0, shake=0.0, sensor="ideal")
    noisy = make_scene("boxes", "tiny", n_frames=2, n_test=0, shake=0.0, noise_hz=2.0, sensor="ideal")
    span = quiet.capture.exposures[-1, 1] + 0.02
    extra = len(noisy.capture.events) - len(quiet.capture.events)
    expected = 2.0 * span * 64 * 48
    assert abs(extra - expected) < 5 * math.sqrt(expected)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(name="teapot"), "name"),
        (dict(size="huge"), "size"),
        (dict(shake=-1.0), "shake"),
        (dict(n_frames=1), "n_frames"),
        (dict(n_test=20), "n_test"),
        (dict(exposure=0.5), "exposure"),
        (dict(sharp_fraction=2.0), "sharp_fraction"),
        (dict(sensor="dvxplorer"), "sensor"),
        (dict(poses="maybe"), "sensor.poses"),
        (dict(c=-0.1), "sensor.c_pos"),
        (dict(c=(0.2, 0.0)), "sensor.c_neg"),
        (dict(c="big"), "c"),
        (dict(tremor=-1.0), "sensor.tremor"),
        (dict(noise_hz=float("nan")), "sensor.noise_hz"),
        (dict(sensor=Sensor(bits=12)), "sensor.bits"),
        (dict(sensor=Sensor(black_level=1.0)), "sensor.black_level"),
        (dict(sensor=Sensor(luminance=(0.5, 0.5, 0.5))), "sensor.luminance"),
    ],
)
def test_make_scene_bad_arguments(kwargs, word):
    with pytest.raises(CaptureError, match=word):  # an EbadError: the CLI prints it as one line
        make_scene(**kwargs)


def test_write_scene_keeps_ground_truth_apart(tmp_path, boxes):
    out = write_scene(boxes, tmp_path / "s")
    assert sorted(p.name for p in out.iterdir()) == ["capture", "gt"]
    cap = load(out / "capture")
    np.testing.assert_array_equal(cap.frames, boxes.capture.frames)
    np.testing.assert_array_equal(cap.events.t, boxes.capture.events.t)
    np.testing.assert_array_equal(cap.c2w, boxes.capture.c2w)
    assert cap.pose_trust == "exact"
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
    with pytest.raises(CaptureError, match="out_dir"):
        write_scene(boxes, tmp_path / "s")


def test_write_scene_failing_midway_leaves_nothing(tmp_path, boxes, monkeypatch):
    import scenes.synth as synth

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(synth, "write_image", boom)
    with pytest.raises(OSError, match="disk full"):
        write_scene(boxes, tmp_path / "s")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- realistic sensor


def test_aps_response_is_monotone_saturating_and_the_identity_when_ideal():
    e = np.linspace(0.0, 2.0, 2001)[:, None]
    v = aps_response(e, REALISTIC)[:, 0]
    assert np.all(np.diff(v) >= 0)  # monotone
    knee = 1.0 / REALISTIC.gain
    below = e[:, 0] < knee
    assert np.all(np.diff(v[below]) > 0)  # strictly increasing below saturation
    assert np.all(v[e[:, 0] >= knee] == 1.0)  # saturated above it
    assert v[0] == pytest.approx(REALISTIC.black_level)
    mid = aps_response(np.array([[0.25]]), REALISTIC)[0, 0]
    assert mid > REALISTIC.black_level + (1 - REALISTIC.black_level) * 0.25 * REALISTIC.gain  # gamma < 1 lifts
    x = np.random.default_rng(0).uniform(0, 1, (50, 3))
    np.testing.assert_array_equal(aps_response(x, SENSORS["ideal"]), x)


@pytest.mark.parametrize("bits", [8, 16])
def test_aps_record_read_noise_and_quantisation(bits):
    sen = Sensor(read_noise=0.01, bits=bits)
    irr = np.full((200, 200, 1), 0.4)
    rec = aps_record(irr, sen, np.random.default_rng(1))
    q = 2**bits - 1
    np.testing.assert_allclose(rec * q, np.round(rec * q), atol=1e-3)  # on the k / (2^bits - 1) grid
    expected = math.sqrt(0.01**2 + 1 / (12 * q**2))  # read noise plus quantisation
    assert abs(rec.std() - expected) < 0.05 * expected
    assert abs(rec.mean() - 0.4) < 1e-3


def test_realistic_frames_saturate_and_carry_read_noise(real):
    cap = real.capture
    assert cap.frames.shape == (10, 48, 64, 1)
    assert np.all(np.abs(cap.frames * 255 - np.round(cap.frames * 255)) < 1e-4)  # 8 bits
    assert (cap.frames == 1.0).mean() > 0.002  # bright parts saturate
    assert (real.gt_frames == 1.0).mean() > 0.002
    assert cap.frames.min() >= REALISTIC.black_level - 5 * REALISTIC.read_noise
    # sharp test images: recorded (noise, quantisation) versus the noise-free truth
    for j, tv in enumerate(cap.test_views):
        d = tv.image - real.gt_test_images[j]
        ok = (real.gt_test_images[j] < 0.97) & (real.gt_test_images[j] > 0.03)
        assert abs(d[ok].std() - math.sqrt(REALISTIC.read_noise**2 + 1 / (12 * 255**2))) < 0.3 * REALISTIC.read_noise


def _log_change(i0, i1, eps):
    return np.log(i1 + eps) - np.log(i0 + eps)


def test_c_pos_and_c_neg_recovered_from_the_sensors_own_events():
    """A static scene whose brightness rises by a known factor, then falls back: each pixel's
    ON count is its log change / C+, its OFF count the same change / C-."""
    rng = np.random.default_rng(0)
    i0 = rng.uniform(0.2, 0.6, size=(40, 50))
    gain = math.exp(4.0)
    t = np.linspace(0.0, 2.0, 401)
    g = np.where(t <= 1.0, gain**t, gain ** (2.0 - t))  # up for 1 s, down for 1 s
    imgs = i0[None] * g[:, None, None]
    for seed in range(3):
        ev, cp, cn = sensor_events(imgs[..., None], t, REALISTIC, seed=seed)
        delta = _log_change(i0, i0 * gain, REALISTIC.log_eps)
        up, down = ev.slice_time(0.0, 1.0), ev.slice_time(1.0, 2.0 + 1e-6)
        n_on = up.count_image(polarity=1).astype(float)
        n_off = down.count_image(polarity=-1).astype(float)
        c_pos_hat = np.median(delta / np.maximum(n_on, 1))
        c_neg_hat = np.median(delta / np.maximum(n_off, 1))
        assert abs(c_pos_hat - REALISTIC.c_pos) < 0.08 * REALISTIC.c_pos
        assert abs(c_neg_hat - REALISTIC.c_neg) < 0.08 * REALISTIC.c_neg
        # per-pixel mismatch as configured
        assert abs(cp.std() - REALISTIC.sigma_c) < 0.2 * REALISTIC.sigma_c
        assert abs(cn.mean() - REALISTIC.c_neg) < 0.005 and abs(cp.mean() - REALISTIC.c_pos) < 0.005


def test_noise_event_rates_as_configured():
    h, w, span = 48, 64, 4.0
    t = np.linspace(0.0, span, 5)
    still = np.full((5, h, w, 1), 0.3)  # nothing changes: every event is noise
    hot = int(round(REALISTIC.hot_pixel_fraction * h * w))
    assert hot >= 1
    for seed in range(3):
        ev, _, _ = sensor_events(still, t, REALISTIC, seed=seed)
        n_off = int((ev.p < 0).sum())
        n_on = int((ev.p > 0).sum())
        exp_off = REALISTIC.noise_hz / 2 * span * h * w
        exp_on = exp_off + REALISTIC.leak_hz * span * h * w
        counts = ev.count_image(polarity=1)
        hot_on = np.sort(counts.ravel())[-hot:].sum()  # the hot pixels fire far more than the rest
        assert np.sort(counts.ravel())[-hot] > 100
        assert abs(n_off - exp_off) < 5 * math.sqrt(exp_off)
        assert abs((n_on - hot_on) - exp_on) < 5 * math.sqrt(exp_on) + hot * 10


def test_colour_events_follow_luminance_not_the_channel_mean():
    t = np.linspace(0.0, 1.0, 51)
    ramp = np.exp(3.0 * t)[:, None, None]
    base = np.full((20, 20, 3), 0.2)

    def events(channel, sensor):
        imgs = np.repeat(base[None], len(t), axis=0)
        imgs[..., channel] *= ramp
        return len(sensor_events(imgs, t, sensor, seed=0)[0])

    quiet = Sensor(sigma_c=0.0)
    real_quiet = Sensor(sigma_c=0.0, luminance=REALISTIC.luminance)
    assert events(1, quiet) == events(2, quiet)  # the ideal sensor averages the channels
    assert events(1, real_quiet) > 3 * events(2, real_quiet)  # green weighs 0.72 in Rec. 709, blue 0.07


def _linear_deviation_deg(scene, k, n=9):
    """Largest angle between the true in-exposure orientation and the constant-velocity
    (geodesic) interpolation between the exposure's end orientations."""
    poses = scene.gt_trajectory(k, n)
    rots = Rotation.from_matrix(poses[:, :3, :3])
    lin = Slerp([0.0, 1.0], rots[[0, -1]])(np.linspace(0, 1, n))
    return np.degrees((rots * lin.inv()).magnitude()).max()


def test_realistic_motion_is_not_constant_velocity(boxes, real):
    ideal_dev = max(_linear_deviation_deg(boxes, k) for k in range(10))
    real_dev = [_linear_deviation_deg(real, k) for k in range(10)]
    assert ideal_dev < 1e-6
    assert np.median(real_dev) > 0.1  # degrees: a linear trajectory model cannot reproduce it
    # the tremor is continuous (no jumps at exposure boundaries)
    ts = np.linspace(0, real.capture.exposures[-1, 1] + 0.02, 4000)
    assert np.abs(np.diff(real.c2w_at(ts), axis=0)).max() < 0.01


def test_realistic_poses_are_noisy_and_say_so(real):
    cap = real.capture
    assert cap.pose_trust == "approximate" and cap.effective_pose_trust == "approximate"
    given = np.concatenate([cap.c2w, [tv.c2w for tv in cap.test_views]])
    true = np.concatenate([real.gt_c2w, real.gt_test_c2w])
    ang = np.degrees(Rotation.from_matrix(np.einsum("nji,njk->nik", true[:, :3, :3], given[:, :3, :3])).magnitude())
    pos = np.linalg.norm(given[:, :3, 3] - true[:, :3, 3], axis=1)
    assert 0.2 < np.sqrt((ang**2).mean()) < 1.0  # RMS 0.5 degrees configured
    assert 0.004 < np.sqrt((pos**2).mean()) < 0.02  # RMS 0.01 configured
    exact = make_scene("boxes", "tiny", seed=0, poses="exact", n_frames=3, n_test=1)
    assert exact.capture.pose_trust == "exact"
    np.testing.assert_array_equal(exact.capture.c2w, exact.gt_c2w)


def test_no_truth_in_capture_meta_or_capture_json(tmp_path, real, boxes):
    for sc in (real, boxes):
        assert not set(sc.capture.meta) & set(TRUTH_KEYS)
    out = write_scene(real, tmp_path / "s")
    doc = json.loads((out / "capture" / "capture.json").read_text())
    assert not set(doc.get("meta", {})) & set(TRUTH_KEYS)
    text = (out / "capture" / "capture.json").read_text()
    for key in ("c_pos", "c_neg", "sigma_c", "log_eps", "gamma", "read_noise", "depth"):
        assert key not in text
    truth = json.loads((out / "gt" / "gt.json").read_text())
    assert truth["truth"]["sensor"]["c_pos"] == REALISTIC.c_pos  # the truth lives on the gt side
    np.testing.assert_allclose(truth["frames"][2]["c2w_mid"], real.gt_c2w[2])
    np.testing.assert_allclose(truth["test_views"][0]["c2w"], real.gt_test_c2w[0])


def test_realistic_scene_builds_about_as_fast_as_the_ideal_one(boxes, real):
    # both fixtures timed their build in this run, in CPU seconds of this process (all its threads):
    # other jobs on a shared machine slow the wall clock, not this; compared as a ratio besides
    assert BUILD_TIME["realistic"] < 1.5 * BUILD_TIME["ideal"] + 0.5


def test_16_bit_realistic_capture_round_trips(tmp_path):
    from dataclasses import replace

    sc = make_scene("spheres", "tiny", seed=4, rgb=True, n_frames=2, n_test=1, sensor=replace(REALISTIC, bits=16))
    f = sc.capture.frames
    assert np.allclose(f * 65535, np.round(f * 65535), atol=1e-2) and not np.allclose(f * 255, np.round(f * 255))
    out = write_scene(sc, tmp_path / "s")
    cap = load(out / "capture")
    np.testing.assert_array_equal(cap.frames, f)
    np.testing.assert_array_equal(cap.test_views[0].image, sc.capture.test_views[0].image)
    assert cap.pose_trust == "approximate"
