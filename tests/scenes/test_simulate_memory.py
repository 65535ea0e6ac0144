"""The event simulator's memory: log(I + eps) a block of pixels at a time, never the whole renders in float64."""

import tracemalloc

import numpy as np
import pytest

from scenes import simulate as S

KW = dict(c=0.2, sigma_c=0.03, refractory=1e-4, noise_hz=2.0, hot_pixels=2, seed=1)


def _renders(s=400, h=40, w=50):
    """[S, H, W] float32 renders of a drifting grating (about 45k events with KW) and their times."""
    t = np.linspace(0.0, 0.2, s)
    y, x = np.mgrid[0:h, 0:w]
    phase = 2 * np.pi * (x[None] / 17.0 + y[None] / 23.0 - 5.0 * t[:, None, None])
    return (0.3 + 0.25 * np.sin(phase)).astype(np.float32), t


def _fields(ev):
    return [np.asarray(getattr(ev, k)) for k in "txyp"]


@pytest.mark.parametrize("block", [1, 7_919, 100_000])  # one pixel, uneven blocks, 250 pixels a block
def test_blocks_give_the_events_of_one_pass(monkeypatch, block):
    imgs, t = _renders(s=60, h=12, w=15)
    whole = S.simulate_events(imgs, t, **KW)  # 60 x 180 values: one block
    monkeypatch.setattr(S, "LOG_BLOCK_VALUES", block)
    blocked = S.simulate_events(imgs, t, **KW)
    assert len(whole) > 1000
    for a, b in zip(_fields(whole), _fields(blocked)):
        np.testing.assert_array_equal(a, b)


def test_float64_renders_are_not_changed():
    imgs, t = _renders(s=30, h=6, w=7)
    imgs64 = imgs.astype(np.float64)
    before = imgs64.copy()
    S.simulate_events(imgs64[..., None], t, **KW)  # [S, H, W, 1]: the one channel is a view, not a copy
    np.testing.assert_array_equal(imgs64, before)


def test_peak_memory_is_a_block_and_the_events_not_the_renders_in_float64(monkeypatch):
    # 400 renders of 40x50 in float32 are 3.2 MB; the whole of log(I + eps) in float64 is 6.4 MB, and
    # log(x.astype(float64) + eps) held three such arrays at once at its peak (12.2 MB traced here
    # before the fix; 6.4 GB at 40 views of 346x260). Now one block of LOG_BLOCK_VALUES float64 values
    # (0.8 MB) is logged at a time; the events cost a bounded number of bytes each while they are
    # gathered and ordered (t float64 + pixel int64 + polarity int8 twice, the microsecond times, the
    # order and the reordered fields: about 60; 72 allowed). Bound: 2 blocks + 72 B an event (4.8 MB).
    imgs, t = _renders()
    S.simulate_events(imgs[:3], t[:3], **KW)  # the kernel loaded before tracing
    block = 100_000
    monkeypatch.setattr(S, "LOG_BLOCK_VALUES", block)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        ev = S.simulate_events(imgs, t, **KW)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert 40_000 < len(ev) < 50_000
    bound = 2 * block * 8 + 72 * len(ev)
    assert peak < bound, (peak, bound)
    assert bound < imgs.size * 8 * 1.5  # the bound is below a float64 copy of every render and a half
