"""Event simulator: known values, the two kernels agree, noise, refractory, bad inputs."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edi import LOG_EPS
from scenes import simulate_events
from scenes.simulate import HOT_PIXEL_HZ

L0_DEFAULT = math.log(0.1)


def _ramp(slopes, t, l0=L0_DEFAULT, eps=1e-3):
    """Images whose log(I + eps) is l0 + slope * t exactly, per pixel."""
    logi = l0 + slopes[None] * t[:, None, None]
    return np.exp(logi) - eps


def test_constant_scene_gives_no_events():
    rng = np.random.default_rng(0)
    img = rng.uniform(0.05, 1.0, size=(6, 7))
    imgs = np.repeat(img[None], 20, axis=0)
    ev = simulate_events(imgs, np.linspace(0, 1, 20), c=0.2, sigma_c=0.05, seed=3)
    assert len(ev) == 0
    assert (ev.width, ev.height) == (7, 6)


@pytest.mark.parametrize("sign", [1, -1])
def test_log_ramp_gives_floor_delta_over_c_events_at_the_right_times(sign):
    c, eps = 0.2, 1e-3
    slopes = sign * np.array([[0.5, 1.37, 2.11], [3.03, 0.0, 0.9]])  # log units per second
    t = np.linspace(0.0, 1.0, 41)
    imgs = _ramp(slopes, t, l0=math.log(0.5) if sign < 0 else math.log(0.01), eps=eps)
    ev = simulate_events(imgs, t, c=c, sigma_c=0.0, eps=eps)
    counts = ev.count_image(polarity=sign)
    expected = np.floor(np.abs(slopes) * 1.0 / c + 1e-9).astype(int)
    np.testing.assert_array_equal(counts, expected)
    assert (ev.p == sign).all()
    for y in range(2):
        for x in range(3):
            sel = (ev.x == x) & (ev.y == y)
            k = np.arange(1, expected[y, x] + 1)
            want_us = k * c / abs(slopes[y, x]) * 1e6
            np.testing.assert_allclose(ev.t[sel], want_us, atol=1.0)  # integer-microsecond rounding


def test_ramp_crossing_many_thresholds_between_two_renders_is_interpolated():
    c = 0.1
    t = np.array([0.0, 1.0])
    imgs = _ramp(np.array([[1.05]]), t)
    ev = simulate_events(imgs, t, c=c, sigma_c=0.0, eps=1e-3)
    assert len(ev) == 10
    np.testing.assert_allclose(ev.t, np.arange(1, 11) * c / 1.05 * 1e6, atol=1.0)


@pytest.mark.parametrize("refractory", [0.0, 0.01])
def test_numba_kernel_matches_reference(refractory):
    rng = np.random.default_rng(1)
    imgs = np.exp(np.cumsum(rng.normal(0, 0.15, (40, 5, 6)), 0)) * 0.3
    t = np.sort(rng.uniform(0, 0.5, 40))
    a = simulate_events(imgs, t, sigma_c=0.04, refractory=refractory, seed=5)
    b = simulate_events(imgs, t, sigma_c=0.04, refractory=refractory, seed=5, reference=True)
    assert len(a) > 50
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


def test_events_sorted_inside_sensor_and_inside_time_span():
    rng = np.random.default_rng(2)
    imgs = rng.uniform(0, 1, (30, 9, 11))
    t = np.linspace(0.2, 0.5, 30)
    ev = simulate_events(imgs, t, noise_hz=20.0, hot_pixels=2, seed=0)
    assert len(ev) > 0
    assert np.all(np.diff(ev.t) >= 0)
    assert ev.x.min() >= 0 and ev.x.max() < 11 and ev.y.min() >= 0 and ev.y.max() < 9
    assert ev.t.min() >= 200_000 and ev.t.max() <= 500_000


def test_per_pixel_thresholds_are_returned_and_used():
    t = np.linspace(0, 1, 50)
    slopes = np.full((4, 4), 2.0)
    ev, cp, cn = simulate_events(_ramp(slopes, t), t, c=0.2, sigma_c=0.05, eps=1e-3, seed=4, return_thresholds=True)
    assert cp.shape == (4, 4) and cn.shape == (4, 4)
    assert cp.std() > 0.01
    np.testing.assert_array_equal(ev.count_image(1), np.floor(2.0 / cp + 1e-9).astype(int))


def test_refractory_period_spaces_events_per_pixel():
    t = np.linspace(0, 1, 200)
    imgs = _ramp(np.full((2, 2), 20.0), t)  # one crossing every 10 ms at c = 0.2
    ev = simulate_events(imgs, t, c=0.2, sigma_c=0.0, refractory=0.025, eps=1e-3)
    no_ref = simulate_events(imgs, t, c=0.2, sigma_c=0.0, eps=1e-3)
    assert 0 < len(ev) < len(no_ref) / 2
    for x in range(2):
        tt = ev.t[(ev.x == x) & (ev.y == 0)]
        assert np.diff(tt).min() >= 25_000 - 1


def test_shot_noise_rate_and_hot_pixels():
    imgs = np.full((2, 20, 30), 0.5)
    t = np.array([0.0, 2.0])
    ev = simulate_events(imgs, t, noise_hz=5.0, seed=0)
    expected = 5.0 * 2.0 * 600
    assert abs(len(ev) - expected) < 5 * math.sqrt(expected)
    assert 0.4 < (ev.p > 0).mean() < 0.6
    hot = simulate_events(imgs, t, hot_pixels=3, seed=0)
    counts = hot.count_image()
    assert (counts > 0).sum() == 3
    assert counts.max() == round(HOT_PIXEL_HZ * 2.0)


def test_colour_is_averaged_to_grey():
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0.05, 1, (10, 4, 5, 3))
    t = np.linspace(0, 1, 10)
    a = simulate_events(rgb, t, seed=1)
    b = simulate_events(rgb.mean(axis=3), t, seed=1)
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(images=np.zeros((1, 3, 3)), times=[0.0]), "images"),
        (dict(images=np.zeros((3, 3)), times=[0.0, 1.0, 2.0]), "images"),
        (dict(images=np.zeros((2, 3, 3, 2)), times=[0.0, 1.0]), "images"),
        (dict(images=np.full((2, 3, 3), np.nan), times=[0.0, 1.0]), "images"),
        (dict(images=np.zeros((2, 3, 3)), times=[1.0, 1.0]), "times"),
        (dict(images=np.zeros((2, 3, 3)), times=[0.0, 1.0, 2.0]), "times"),
        (dict(images=np.zeros((2, 3, 3)), times=[0.0, 1.0], c=0.0), "c"),
        (dict(images=np.zeros((2, 3, 3)), times=[0.0, 1.0], sigma_c=-1.0), "sigma_c"),
        (dict(images=np.zeros((2, 3, 3)), times=[0.0, 1.0], noise_hz=-1.0), "noise_hz"),
        (dict(images=np.zeros((2, 3, 3)), times=[0.0, 1.0], hot_pixels=1.5), "hot_pixels"),
    ],
)
def test_bad_inputs_name_the_argument(kwargs, word):
    with pytest.raises(ValueError, match=word):
        simulate_events(**kwargs)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    s=st.integers(2, 12),
    sigma=st.sampled_from([0.0, 0.05]),
    refractory=st.sampled_from([0.0, 0.003]),
)
def test_kernels_agree_property(seed, s, sigma, refractory):
    rng = np.random.default_rng(seed)
    imgs = rng.uniform(0, 1, (s, 3, 4)) ** 3
    t = np.cumsum(rng.uniform(1e-3, 0.02, s))
    a = simulate_events(imgs, t, c=0.15, sigma_c=sigma, refractory=refractory, seed=seed)
    b = simulate_events(imgs, t, c=0.15, sigma_c=sigma, refractory=refractory, seed=seed, reference=True)
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    # the reference starts at the first render, so c * net count is within one threshold of
    # the total log change
    if sigma == 0 and refractory == 0:
        eps = LOG_EPS
        dl = np.log(imgs[-1] + eps) - np.log(imgs[0] + eps)
        assert np.all(np.abs(dl - 0.15 * a.count_image()) < 0.15 + 1e-9)


def test_asymmetric_thresholds_and_leak_events():
    c_pos, c_neg, eps = 0.3, 0.15, 1e-3
    t = np.linspace(0.0, 2.0, 81)
    slope = np.full((3, 4), 1.5)
    up = _ramp(slope, t[:41], l0=math.log(0.05), eps=eps)  # +1.5 log units over 1 s
    imgs = np.concatenate([up, up[-2::-1]])  # then back down over 1 s
    ev = simulate_events(imgs, t, c=(c_pos, c_neg), sigma_c=0.0, eps=eps)
    np.testing.assert_array_equal(ev.count_image(polarity=1), np.floor(1.5 / c_pos + 1e-9))
    assert (ev.count_image(polarity=-1) >= np.floor(1.5 / c_neg) - 1).all()
    # leak: positive events only, at the configured rate
    still = np.full((5, 30, 40), 0.2)
    leak = simulate_events(still, np.linspace(0, 10.0, 5), leak_hz=0.5, seed=1)
    assert (leak.p == 1).all()
    expected = 0.5 * 10.0 * 30 * 40
    assert abs(len(leak) - expected) < 5 * math.sqrt(expected)
    with pytest.raises(ValueError, match="c"):
        simulate_events(still, np.linspace(0, 1, 5), c=(0.2, 0.3, 0.1))
    with pytest.raises(ValueError, match="leak_hz"):
        simulate_events(still, np.linspace(0, 1, 5), leak_hz=-1.0)
