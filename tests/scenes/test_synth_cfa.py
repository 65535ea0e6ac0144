"""Synthetic colour DAVIS captures (issue 29 s.5): events on each pixel's own Bayer channel, the raw
mosaic through the response and noise, demosaiced or raw frames, ground truth in full RGB; and the
luminance captures of before unchanged bit for bit."""

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

from edi.cfa import channel_map, demosaic, mosaic
from edi.deblur import LOG_EPS
from scenes import CaptureError, load, make_scene, write_scene
from scenes.format import read_ground_truth
from scenes.images import quantize
from scenes.simulate import simulate_events
from scenes.synth import SENSORS, Sensor, sensor_events

QUIET = replace(SENSORS["realistic"], read_noise=0.0)  # the realistic camera without read noise
KW = dict(size="tiny", seed=1, n_frames=2, n_test=1)


def _events_as_stored_on_main(ev) -> tuple[np.ndarray, ...]:
    """The event fields in the dtypes of the stream the digests were computed with (t int64, x/y
    int32, p int8): the values are pinned, not how compactly a stream stores them."""
    return ev.t.astype(np.int64), ev.x.astype(np.int32), ev.y.astype(np.int32), ev.p.astype(np.int8)


def _hash(*arrays) -> str:
    m = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        m.update(str(a.dtype).encode())
        m.update(str(a.shape).encode())
        m.update(a.tobytes())
    return m.hexdigest()[:16]


@pytest.fixture(scope="module")
def quiet_pair():
    """The same world (seed, trajectory, response) as a raw-mosaic colour DAVIS and as an RGB camera."""
    raw = make_scene("boxes", sensor=QUIET, cfa="RGGB", raw_frames=True, **KW)
    rgb = make_scene("boxes", sensor=QUIET, rgb=True, **KW)
    return raw, rgb


@pytest.fixture(scope="module")
def davis():
    """A realistic colour DAVIS, demosaiced frames (the default) and raw frames."""
    return make_scene("boxes", cfa="RGGB", **KW), make_scene("boxes", cfa="RGGB", raw_frames=True, **KW)


# ------------------------------------------------------------------------------- events per channel


def _ramp(t, channel_gain):
    """[S, 6, 8, 3] irradiance 0.2 whose channels c change as exp(channel_gain[c] * t)."""
    base = np.full((len(t), 6, 8, 3), 0.2)
    return base * np.exp(np.outer(t, channel_gain))[:, None, None, :]


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG"])
def test_events_fire_on_each_pixels_own_channel_only_red_changes(pattern):
    t = np.linspace(0.0, 1.0, 41)
    imgs = _ramp(t, [3.0, 0.0, 0.0])  # only red changes
    sen = Sensor(sigma_c=0.0)  # c = 0.2 both ways, no noise
    ev, _, _ = sensor_events(imgs, t, sen, seed=0, cfa=pattern)
    red = channel_map(pattern, 6, 8) == 0
    counts = ev.count_image()
    expected = int(np.floor((np.log(0.2 * np.exp(3.0) + LOG_EPS) - np.log(0.2 + LOG_EPS)) / 0.2 + 1e-9))
    assert expected == 14
    assert (counts[red] == expected).all() and (counts[~red] == 0).all()  # 12 R pixels x 14 events, nothing else
    assert len(ev) == 12 * 14 and (ev.p > 0).all()
    # the luminance capture of before: every pixel fires on the channel mean
    ev_lum, _, _ = sensor_events(imgs, t, sen, seed=0)
    assert (ev_lum.count_image() > 0).all()


def test_event_polarity_follows_the_pixels_channel():
    t = np.linspace(0.0, 1.0, 41)
    imgs = _ramp(t, [2.0, 0.0, -2.0])  # red brightens, blue darkens, green still
    ev, _, _ = sensor_events(imgs, t, Sensor(sigma_c=0.0), seed=0, cfa="RGGB")
    ch = channel_map("RGGB", 6, 8)[ev.y, ev.x]
    assert set(np.unique(ch)) == {0, 2}  # no event at a green pixel
    assert (ev.p[ch == 0] > 0).all() and (ev.p[ch == 2] < 0).all()
    assert (ch == 0).sum() == 12 * 9 and (ch == 2).sum() == 12 * 9  # log(0.2 e^2 + eps) - ... = 1.99 -> 9 events


def test_cfa_keeps_the_sensors_per_pixel_thresholds_and_noise():
    t = np.linspace(0.0, 0.5, 21)
    imgs = _ramp(t, [1.0, 0.5, 0.0])
    real = SENSORS["realistic"]
    ev, cp, cn = sensor_events(imgs, t, real, seed=4, cfa="RGGB")
    ev_l, cp_l, cn_l = sensor_events(imgs, t, real, seed=4)
    np.testing.assert_array_equal(cp, cp_l)  # the same mismatch drawn per pixel
    np.testing.assert_array_equal(cn, cn_l)
    still, _, _ = sensor_events(np.repeat(imgs[:1], len(t), 0), t, real, seed=4, cfa="RGGB")
    assert len(still) > 0  # noise, leak and hot pixels on a still scene, as without cfa


def test_simulate_events_cfa_needs_rgb_renders_and_a_pattern():
    t = np.linspace(0.0, 1.0, 3)
    with pytest.raises(ValueError, match="images"):
        simulate_events(np.ones((3, 4, 4)), t, cfa="RGGB")
    with pytest.raises(ValueError, match="cfa"):
        simulate_events(np.ones((3, 4, 4, 3)), t, cfa="RGBW")


# ------------------------------------------------------------------------------- frames and ground truth


def test_raw_frames_are_the_mosaic_of_the_rgb_cameras_frames(quiet_pair):
    raw, rgb = quiet_pair
    cap = raw.capture
    assert cap.cfa == "RGGB" and cap.raw_mosaic and cap.frames.shape == (2, 48, 64, 1)
    np.testing.assert_array_equal(cap.frames[..., 0], mosaic(rgb.capture.frames, "RGGB"))
    # the ground truth stays full RGB through the response: what a perfect camera shows
    assert raw.gt_frames.shape == (2, 48, 64, 3)
    np.testing.assert_array_equal(raw.gt_frames, rgb.gt_frames)
    np.testing.assert_array_equal(raw.gt_test_images, rgb.gt_test_images)
    # the capture's test images are in its frames' domain: raw mosaics of the recorded test views
    np.testing.assert_array_equal(cap.test_views[0].image[..., 0], mosaic(rgb.capture.test_views[0].image, "RGGB"))
    assert raw.truth["cfa"] == "RGGB" and raw.truth["frames"] == "raw mosaic"
    assert "RGGB" in raw.truth["event_channel"]


def test_demosaiced_frames_are_the_bilinear_demosaic_of_the_raw_mosaic(davis):
    dem, raw = davis
    assert dem.capture.cfa == "RGGB" and not dem.capture.raw_mosaic and dem.capture.frames.shape == (2, 48, 64, 3)
    np.testing.assert_array_equal(dem.capture.frames, quantize(demosaic(raw.capture.frames[..., 0], "RGGB"), 8))
    np.testing.assert_array_equal(mosaic(dem.capture.frames, "RGGB"), raw.capture.frames[..., 0])  # own channel kept
    # read noise on the raw mosaic: the frames differ from the noise-free truth's mosaic, by about the noise
    err = raw.capture.frames[..., 0] - mosaic(raw.gt_frames, "RGGB")
    assert err.std() > 0.002
    # the events are the same either way (only the frames' form differs)
    np.testing.assert_array_equal(dem.capture.events.t, raw.capture.events.t)
    np.testing.assert_array_equal(dem.capture.events.x, raw.capture.events.x)
    assert dem.truth["frames"] == "demosaiced" and dem.capture.meta["cfa"] == "RGGB"


def test_cfa_capture_is_seeded_and_differs_from_the_luminance_capture(davis):
    dem, _ = davis
    again = make_scene("boxes", cfa="RGGB", **KW)
    np.testing.assert_array_equal(again.capture.frames, dem.capture.frames)
    np.testing.assert_array_equal(again.capture.events.t, dem.capture.events.t)
    np.testing.assert_array_equal(again.capture.events.p, dem.capture.events.p)
    lum = make_scene("boxes", rgb=True, **KW)  # the luminance baseline of the same world
    assert len(lum.capture.events) != len(dem.capture.events)
    assert lum.capture.cfa is None and "cfa" not in lum.capture.meta


def test_cfa_capture_written_and_read_back(tmp_path, davis):
    _, raw = davis
    write_scene(raw, tmp_path / "s")
    cap = load(tmp_path / "s" / "capture")
    assert cap.cfa == "RGGB" and cap.raw_mosaic and cap.test_views[0].image.shape == (48, 64, 1)
    np.testing.assert_array_equal(cap.frames, raw.capture.frames)
    gt = read_ground_truth(tmp_path / "s" / "gt")
    assert gt.cfa == "RGGB"
    assert gt.frames(cap.names).shape == (2, 48, 64, 3)  # the truth in full RGB
    assert json.loads((tmp_path / "s" / "gt" / "gt.json").read_text())["truth"]["cfa"] == "RGGB"


@pytest.mark.parametrize(
    "kwargs, word",
    [({"cfa": "RGBW"}, "cfa"), ({"raw_frames": True}, "raw_frames"), ({"raw_frames": True, "rgb": True}, "raw_frames")],
)
def test_bad_cfa_arguments_name_the_argument(kwargs, word):
    with pytest.raises(CaptureError, match=word):
        make_scene("boxes", **KW, **kwargs)


# ------------------------------------------------------------------------------- before is unchanged


# sha256 (16 hex) of frames, events (t, x, y, p), gt frames, gt test images and recorded test images, computed on
# main (4dff722) before colour DAVIS captures existed; scenes tiny, seed 3, 3 frames, 1 test view
PINNED = [
    (dict(name="boxes"), "b92e4a1d5b5db998", 74649),
    (dict(name="boxes", rgb=True), "e2b49c13f6f111bf", 77569),
    (dict(name="spheres", rgb=True, sensor="ideal"), "176a54cadb011c7c", 58088),
]


@pytest.mark.parametrize("kwargs, digest, n_events", PINNED)
def test_grey_and_luminance_captures_unchanged_bit_for_bit(kwargs, digest, n_events):
    sc = make_scene(size="tiny", seed=3, n_frames=3, n_test=1, **kwargs)
    cap, ev = sc.capture, sc.capture.events
    assert len(ev) == n_events
    images = np.stack([tv.image for tv in cap.test_views])
    assert _hash(cap.frames, *_events_as_stored_on_main(ev), sc.gt_frames, sc.gt_test_images, images) == digest
