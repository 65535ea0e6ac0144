"""The EDI pass: the numba kernel against the numpy reference, binning, numerical range."""

import numpy as np
import pytest

from edi import EventStream, deblur
from edi._kernels import edi_pass, edi_pass_binned, edi_pass_reference
from edi.contrast import TURN_CROSSING


def random_events(rng, m, w, h, t_max_us, t_min_us=0):
    t = np.sort(rng.integers(t_min_us, t_max_us, m))
    return EventStream(t, rng.integers(0, w, m), rng.integers(0, h, m), rng.choice([-1, 1], m), w, h)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_pass_matches_reference(seed):
    rng = np.random.default_rng(seed)
    ev = random_events(rng, 3000, 7, 5, 1000)
    inst = np.sort(np.concatenate([rng.uniform(0, 1000, 6), ev.t[[0, 10, 500]].astype(float), [0.0, 1000.0]]))
    args = (ev.t, ev.x, ev.y, ev.p, 7, 5, 0.0, 1000.0, inst, 0.23, 0.31)
    lm_f, ef_f = edi_pass(*args)
    lm_r, ef_r = edi_pass_reference(*args)
    np.testing.assert_allclose(lm_f, lm_r, rtol=0, atol=1e-10)
    np.testing.assert_allclose(ef_f, ef_r, rtol=0, atol=1e-12)


def test_exact_integral_is_the_limit_of_fine_binning():
    rng = np.random.default_rng(3)
    ev = random_events(rng, 2000, 6, 4, 10_000)
    args = (ev.t, ev.x, ev.y, ev.p, 6, 4, 0.0, 10_000.0, np.array([5000.0]), 0.2, 0.2)
    exact, _ = edi_pass(*args)
    errs = [np.abs(edi_pass_binned(*args, n_bins=n)[0] - exact).max() for n in (100, 1000, 10_000)]
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 1e-2 * errs[0] + 1e-12
    # with one bin per microsecond every bin centre sits inside one inter-event interval
    fine, _ = edi_pass_binned(*args, n_bins=10_000)
    np.testing.assert_allclose(fine, exact, atol=1e-12)


@pytest.mark.parametrize("n, pol", [(800, -1), (800, 1), (5000, -1)])
def test_many_events_at_the_exposure_start_do_not_underflow(n, pol):
    """All events at t0 drive E to -800 (or +800) on the whole exposure: the running maximum
    must start at -inf, not 0, or every dt * exp(E - 0) underflows (issue 11: fast 1.0,
    reference 0.4)."""
    t = np.zeros(n, np.int64)
    ev = EventStream(t, np.zeros(n), np.zeros(n), np.full(n, pol), 2, 1)
    args = (ev.t, ev.x, ev.y, ev.p, 2, 1, 0.0, 1000.0, np.array([0.0, 500.0, 1000.0]), 1.0, 1.0)
    lm_f, ef_f = edi_pass(*args)
    lm_r, ef_r = edi_pass_reference(*args)
    assert lm_f[0] == pytest.approx(pol * n, abs=1e-9) and np.isfinite(lm_f).all()
    np.testing.assert_allclose(lm_f, lm_r, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ef_f, ef_r, rtol=0, atol=0)
    # E is constant over the exposure after t0, so the latent is the blurry frame itself
    B = np.array([[0.4, 0.7]])
    L = deblur(B, (0.0, 1e-3), ev, times=[1e-4, 5e-4], c=1.0)
    np.testing.assert_allclose(L[:, 0, 0], 0.4, atol=1e-12)
    Lr = deblur(B, (0.0, 1e-3), ev, times=[1e-4, 5e-4], c=1.0, impl="reference")
    np.testing.assert_allclose(L, Lr, atol=1e-12)


def test_ten_thousand_events_at_one_pixel_with_c_one_stay_finite():
    n = 10_000
    t = np.arange(n, dtype=np.int64)
    ev = EventStream(t, np.zeros(n), np.zeros(n), np.ones(n), 2, 2)
    B = np.full((2, 2), 0.5)
    L = deblur(B, (0.0, n * 1e-6), ev, times=[0.0, n * 1e-6 / 2, n * 1e-6], c=1.0)
    assert np.isfinite(L).all()
    # the pixel brightens by e^10000 over the exposure: almost all its mean comes from the end,
    # so the start is black and the end is clipped to 1; untouched pixels keep B
    assert L[0, 0, 0] == pytest.approx(0.0, abs=1e-12) and L[2, 0, 0] == 1.0
    np.testing.assert_allclose(L[:, 1, 1], 0.5)


def test_ten_to_six_random_events():
    rng = np.random.default_rng(7)
    ev = random_events(rng, 1_000_000, 346, 260, 40_000)
    B = rng.uniform(0, 1, (260, 346))
    times = np.linspace(0, 0.04, 8)
    L = deblur(B, (0.0, 0.04), ev, times=times, c=0.3)
    assert L.shape == (8, 260, 346) and np.isfinite(L).all() and L.min() >= 0 and L.max() <= 1
    _assert_pixels_match_reference(L, B, (0.0, 0.04), ev, times, 0.3, rng)


def _assert_pixels_match_reference(L, B, exposure, ev, times, c, rng, n_pixels=40):
    """``L`` (deblur's fast path on the whole stream) at ``n_pixels`` random pixels equals the
    numpy reference run on those pixels' events alone (EDI is per pixel)."""
    H, W = B.shape
    chosen = rng.choice(H * W, n_pixels, replace=False)
    pix = ev.y.astype(np.int64) * W + ev.x.astype(np.int64)
    sel = np.isin(pix, chosen)
    sub = EventStream(ev.t[sel], ev.x[sel], ev.y[sel], ev.p[sel], W, H)
    assert len(sub) > 5 * n_pixels  # the chosen pixels have events to integrate
    ref = deblur(B, exposure, sub, times=times, c=c, impl="reference")
    yy, xx = np.divmod(chosen, W)
    np.testing.assert_allclose(L[..., yy, xx], ref[..., yy, xx], rtol=0, atol=1e-9)
    assert np.abs(L[..., yy, xx] - B[yy, xx]).max() > 0.1  # the events changed these pixels


def test_ten_to_seven_random_events():
    rng = np.random.default_rng(8)
    m = 10_000_000
    t = np.sort(rng.integers(0, 40_000, m))
    ev = EventStream(t, rng.integers(0, 346, m), rng.integers(0, 260, m), rng.integers(0, 2, m), 346, 260)
    B = rng.uniform(0, 1, (260, 346))
    L = deblur(B, (0.0, 0.04), ev, c=0.3)
    assert np.isfinite(L).all() and L.min() >= 0 and L.max() <= 1
    _assert_pixels_match_reference(L, B, (0.0, 0.04), ev, None, 0.3, rng)


# --- the crossings a DVS pixel's hysteresis hides -------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_hidden_crossings_match_reference(seed):
    """The one-pass kernel against a sort of the whole stream, for windows inside, around and past
    the events, including crossings whose reversing event comes after the window."""
    from edi._kernels import hidden_crossings, hidden_crossings_reference

    rng = np.random.default_rng(seed)
    ev = random_events(rng, 4000, 7, 5, 20_000)
    sizes = []
    for t0, t1 in ((5000, 9000), (0, 20_000), (19_990, 30_000), (-100, 50), (3000, 3000)):
        for frac in (0.0, 0.5, TURN_CROSSING, 1.0):
            got = hidden_crossings(ev.t, ev.x, ev.y, ev.p, 7, 5, t0, t1, frac)
            want = hidden_crossings_reference(ev.t, ev.x, ev.y, ev.p, 7, 5, t0, t1, frac)
            for g, w in zip(got, want):
                np.testing.assert_array_equal(g, w)
            sizes.append(len(got[0]))
    assert max(sizes) > 1000 and min(sizes) == 0  # something to compare; an empty window gives none


def test_hidden_crossings_known_values():
    """Pixel 0: +, + (no reversal), - at 1000 after + at 600 (crossing 600 + 0.5 * 400 = 800),
    + at 3000 after - at 1000 (2000); pixel 1: - then + after the window, its crossing inside."""
    from edi._kernels import hidden_crossings

    t = np.array([100, 600, 1000, 1500, 3000, 9000])
    x = np.array([0, 0, 0, 1, 0, 1])
    p = np.array([1, 1, -1, -1, 1, 1])
    ev = EventStream(t, x, np.zeros(6), p, 2, 1)
    ct, cpx, cp = hidden_crossings(ev.t, ev.x, ev.y, ev.p, 2, 1, 0, 5000, 0.5)
    np.testing.assert_array_equal(ct, [800, 2000])
    np.testing.assert_array_equal(cpx, [0, 0])
    np.testing.assert_array_equal(cp, [-1, 1])
    ct, cpx, cp = hidden_crossings(ev.t, ev.x, ev.y, ev.p, 2, 1, 0, 5300, 0.5)  # pixel 1: 1500 + 0.5 * 7500
    np.testing.assert_array_equal(ct, [800, 2000, 5250])
    np.testing.assert_array_equal(cpx, [0, 0, 1])
    np.testing.assert_array_equal(cp, [-1, 1, 1])
