"""EDI, contrast estimation and mEDI on seeded synthetic ground truth (edi.synthetic)."""
import math

import numpy as np
import pytest
import torch

import edi
from edi import LOG_EPS, EventStream, deblur, estimate_c, medi
from edi._kernels import edi_pass, edi_pass_binned, edi_pass_reference
from edi.deblur import edi_log_ratio
from edi.synthetic import moving_texture


@pytest.fixture(scope="module")
def seq1():
    return moving_texture(num_frames=1, seed=0, c=0.2)


@pytest.fixture(scope="module")
def seq3():
    return moving_texture(num_frames=3, seed=1, c=0.2)


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def random_events(rng, m, w, h, t_max_us, t_min_us=0):
    t = np.sort(rng.integers(t_min_us, t_max_us, m))
    return EventStream(t, rng.integers(0, w, m), rng.integers(0, h, m), rng.choice([-1, 1], m), w, h)


# --- the kernel: fast path against the reference --------------------------------------------


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


# --- EDI on synthetic ground truth ----------------------------------------------------------


def test_edi_with_true_c_recovers_mid_exposure_image(seq1):
    B, ex = seq1.frames[0], seq1.exposures[0]
    gt = seq1.sharp(ex.mean())
    L = deblur(B, ex, seq1.events, c=0.2)
    assert L.shape == B.shape and L.dtype == np.float64
    e_edi, e_blur = rmse(L, gt), rmse(B, gt)
    assert e_edi < 0.3 * e_blur, (e_edi, e_blur)


def test_mean_of_latents_over_exposure_reproduces_blur():
    s = moving_texture(num_frames=1, seed=4, c=0.2, hi=0.6)  # no latent reaches the clip at 1
    B, ex = s.frames[0], s.exposures[0]
    step = 50e-6  # the simulator's grid: E is constant on each step, so the mean is exact
    ts = np.arange(ex[0], ex[1] - 1e-9, step) + step / 2
    Ls = deblur(B, ex, s.events, times=ts, c=0.2)
    assert Ls.shape == (len(ts),) + B.shape
    np.testing.assert_allclose(Ls.mean(axis=0), B, atol=1e-9)


def test_polarity_pair_c(seq1):
    s = moving_texture(num_frames=1, seed=5, c=(0.15, 0.3))
    B, ex = s.frames[0], s.exposures[0]
    gt = s.sharp(ex.mean())
    e_pair = rmse(deblur(B, ex, s.events, c=(0.15, 0.3)), gt)
    e_sym = min(rmse(deblur(B, ex, s.events, c=c), gt) for c in (0.15, 0.225, 0.3))
    e_swapped = rmse(deblur(B, ex, s.events, c=(0.3, 0.15)), gt)
    assert e_pair < 0.9 * e_sym and e_pair < 0.6 * e_swapped, (e_pair, e_sym, e_swapped)


def test_times_order_and_single_instant(seq1):
    B, ex = seq1.frames[0], seq1.exposures[0]
    ts = [ex[1], ex[0], ex.mean()]
    many = deblur(B, ex, seq1.events, times=ts, c=0.2)
    one = deblur(B, ex, seq1.events, times=float(ex[0]), c=0.2)
    assert many.shape == (3,) + B.shape and one.shape == B.shape
    np.testing.assert_allclose(many[1], one)
    np.testing.assert_allclose(many[2], deblur(B, ex, seq1.events, c=0.2))
    gt_start = seq1.sharp(ex[0])
    assert rmse(one, gt_start) < 0.5 * rmse(B, gt_start)


def test_colour_frames_share_the_event_integral():
    s = moving_texture(num_frames=1, seed=6, c=0.2, channels=3)
    B, ex = s.frames[0], s.exposures[0]
    L = deblur(B, ex, s.events, c=0.2)
    assert L.shape == B.shape == (40, 56, 3)
    grey = deblur(B.mean(axis=-1), ex, s.events, c=0.2)
    assert grey.shape == (40, 56)
    # same gain per pixel for every channel
    gain = (L + LOG_EPS) / (B + LOG_EPS)
    unclipped = (L < 1.0).all(axis=-1) & (L > 0.0).all(axis=-1)
    assert unclipped.mean() > 0.9
    np.testing.assert_allclose(gain[..., 0][unclipped], gain[..., 2][unclipped], rtol=1e-9)


def test_torch_in_torch_out(seq1):
    B, ex = seq1.frames[0], seq1.exposures[0]
    Lt = deblur(torch.from_numpy(B).float(), ex, seq1.events, times=[ex[0], ex[1]], c=0.2)
    assert isinstance(Lt, torch.Tensor) and Lt.dtype == torch.float32 and Lt.shape == (2,) + B.shape
    assert torch.isfinite(Lt).all()
    Ln = deblur(B.astype(np.float32), ex, seq1.events, times=[ex[0], ex[1]], c=0.2)
    np.testing.assert_allclose(Lt.numpy(), Ln, atol=1e-6)


def test_sharp_frame_or_no_events_returns_blur(seq1):
    B = seq1.frames[0]
    out, rep = deblur(B, (0.01, 0.01), seq1.events, c=0.2, return_report=True)
    np.testing.assert_allclose(out, B)
    assert "sharp frame" in rep.notes[0]
    far = (10.0, 10.04)
    out, rep = deblur(B, far, seq1.events, return_report=True)  # c=None, no events: no estimate needed
    np.testing.assert_allclose(out, B)
    assert rep.num_events == 0
    np.testing.assert_allclose(deblur(B, (0.0, 0.04), EventStream.empty(56, 40), c=0.3), B)


# --- numerics -------------------------------------------------------------------------------


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


def test_zero_pixel_gives_zero_not_nan():
    ev = EventStream([10, 20], [0, 0], [0, 0], [1, -1], 2, 1)
    B = np.array([[0.0, 0.3]])
    L = deblur(B, (0.0, 1e-4), ev, times=[0.0, 15e-6], c=0.5)
    assert np.isfinite(L).all() and (L >= 0).all()
    assert L[0, 0, 0] == pytest.approx(0.0, abs=1e-12)


def test_saturated_pixels_are_kept_and_reported(seq1):
    B = seq1.frames[0].copy()
    B[5:8, 5:8] = 1.0
    L, rep = deblur(B, seq1.exposures[0], seq1.events, c=0.2, return_report=True)
    np.testing.assert_allclose(L[5:8, 5:8], 1.0)
    assert rep.saturated[5:8, 5:8].all() and rep.saturated.sum() == 9


def test_ten_to_six_random_events():
    rng = np.random.default_rng(7)
    ev = random_events(rng, 1_000_000, 346, 260, 40_000)
    B = rng.uniform(0, 1, (260, 346))
    L = deblur(B, (0.0, 0.04), ev, times=np.linspace(0, 0.04, 8), c=0.3)
    assert L.shape == (8, 260, 346) and np.isfinite(L).all() and L.min() >= 0 and L.max() <= 1


def test_ten_to_seven_random_events():
    rng = np.random.default_rng(8)
    m = 10_000_000
    t = np.sort(rng.integers(0, 40_000, m))
    ev = EventStream(t, rng.integers(0, 346, m), rng.integers(0, 260, m), rng.integers(0, 2, m), 346, 260)
    L = deblur(rng.uniform(0, 1, (260, 346)), (0.0, 0.04), ev, c=0.3)
    assert np.isfinite(L).all()


# --- bad input ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        (dict(exposure=(0.04, 0.0)), ValueError, "ends before it starts"),
        (dict(exposure=(0.0, float("nan"))), ValueError, "exposure must be finite"),
        (dict(blur="nan"), ValueError, r"blur has a non-finite value at \(3, 4, 0\)"),
        (dict(blur=np.zeros((5, 5))), ValueError, "events' sensor is 40x56"),
        (dict(blur=np.zeros((40, 56, 3, 1))), ValueError, r"blur must be \[H, W\] or \[H, W, D\]"),
        (dict(times=[0.5]), ValueError, r"times\[0\] = 0.5 s is outside the exposure"),
        (dict(c=-0.2), ValueError, "c must be finite and > 0"),
        (dict(c=(0.2, 0.3, 0.1)), ValueError, r"pair \(c_pos, c_neg\)"),
        (dict(events="x"), TypeError, "edi.EventStream"),
        (dict(impl="gpu"), ValueError, "impl must be one of"),
    ],
)
def test_deblur_bad_input(seq1, kw, exc, match):
    args = dict(blur=seq1.frames[0].copy(), exposure=seq1.exposures[0], events=seq1.events, c=0.2)
    if isinstance(kw.get("blur"), str):
        kw = dict(blur=args["blur"].copy())
        kw["blur"][3, 4, 0] = np.nan
    args.update(kw)
    with pytest.raises(exc, match=match):
        deblur(**args)


# --- contrast threshold ---------------------------------------------------------------------


@pytest.mark.parametrize("c_true, seed", [(0.15, 1), (0.3, 2)])
def test_estimate_c_within_ten_percent(c_true, seed):
    s = moving_texture(num_frames=3, seed=seed, c=c_true)
    c, rep = estimate_c(s.frames, s.exposures, s.events, return_report=True)
    assert abs(c - c_true) < 0.1 * c_true, (c, c_true)
    assert rep.method == "consistency" and rep.bracket[0] <= c <= rep.bracket[1]
    assert rep.bracket[1] / rep.bracket[0] < 1.01 and math.isfinite(rep.energy)
    assert rep.energy == min(e for _, e in rep.evals)


def test_estimate_c_polarity_pair():
    s = moving_texture(num_frames=3, seed=0, c=(0.2, 0.3))
    (cp, cn), rep = estimate_c(s.frames, s.exposures, s.events, polarity=True, return_report=True)
    assert abs(cp - 0.2) < 0.1 * 0.2 and abs(cn - 0.3) < 0.1 * 0.3, (cp, cn)


def test_estimate_c_sharp_frames():
    """Frames with t_start == t_end: the consistency relation alone gives c."""
    s = moving_texture(num_frames=3, seed=3, c=0.25)
    sharp = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    ex = np.repeat(s.exposures.mean(axis=1)[:, None], 2, axis=1)
    c = estimate_c(torch.from_numpy(sharp), ex, s.events)
    assert abs(c - 0.25) < 0.1 * 0.25, c


def test_estimate_c_single_frame_improves_the_frame(seq1):
    """One blurry frame: the estimated c gives a latent much sharper than the blur."""
    B, ex = seq1.frames[0], seq1.exposures[0]
    c, rep = estimate_c(B, ex, seq1.events, return_report=True)
    assert rep.method == "single" and rep.bracket[0] <= c <= rep.bracket[1]
    gt = seq1.sharp(ex.mean())
    assert rmse(deblur(B, ex, seq1.events, c=c), gt) < 0.7 * rmse(B, gt)
    L, drep = deblur(B, ex, seq1.events, return_report=True)  # c=None estimates the same c
    assert drep.c[0] == pytest.approx(c) and drep.c_report.method == "single"


def test_estimate_c_bad_input(seq1):
    with pytest.raises(ValueError, match="bracket"):
        estimate_c(seq1.frames[0], seq1.exposures[0], seq1.events, bracket=(0.5, 0.1))
    with pytest.raises(ValueError, match="exposures must be"):
        estimate_c(seq1.frames, np.zeros((1, 3)), seq1.events)
    with pytest.raises(ValueError, match="no blurry frame with events"):
        estimate_c(seq1.frames[0], (5.0, 5.1), seq1.events)
    with pytest.raises(ValueError, match="needs at least two frames"):
        estimate_c(seq1.frames[0], seq1.exposures[0], seq1.events, method="consistency")


# --- mEDI -----------------------------------------------------------------------------------


def test_medi_flickers_less_than_frame_by_frame():
    s = moving_texture(num_frames=5, seed=0, c=0.2)
    rng = np.random.default_rng(0)
    gains = rng.uniform(0.85, 1.15, (5, 1, 1, 1))  # exposure flicker of the APS frames
    noisy = np.clip(s.frames * gains, 0, 1)
    gt = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    fbf = np.stack([deblur(noisy[i], s.exposures[i], s.events, c=0.2) for i in range(5)])
    joint = medi(noisy, s.exposures, s.events, c=0.2)
    assert joint.shape == noisy.shape

    def flicker(L):  # error of the frame-to-frame log change
        return np.abs(np.diff(np.log(L + LOG_EPS), axis=0) - np.diff(np.log(gt + LOG_EPS), axis=0)).mean()

    assert flicker(joint) < 0.85 * flicker(fbf), (flicker(joint), flicker(fbf))
    assert rmse(joint, gt) < rmse(fbf, gt)
    # lam = 0 is frame by frame
    np.testing.assert_allclose(medi(noisy, s.exposures, s.events, c=0.2, lam=0.0), fbf, atol=1e-9)


def test_medi_torch_grey_and_estimated_c(seq3):
    out = medi(torch.from_numpy(seq3.frames[..., 0]), seq3.exposures, seq3.events)
    assert isinstance(out, torch.Tensor) and out.shape == seq3.frames.shape[:3] and torch.isfinite(out).all()
    with pytest.raises(ValueError, match="time order"):
        medi(seq3.frames, seq3.exposures[::-1].copy(), seq3.events, c=0.2)
    with pytest.raises(ValueError, match=r"exposures must be \[F, 2\]"):
        medi(seq3.frames, seq3.exposures[:2], seq3.events, c=0.2)


def test_estimate_c_with_per_pixel_threshold_mismatch():
    """Real sensors have per-pixel C+ != C-: a pixel that goes up and down drifts in its
    signed count. Using only single-polarity pixels keeps the estimate within 10%; using
    every pixel is biased (that is what the monotone rule is for)."""
    s = moving_texture(num_frames=4, seed=5, c=0.2, sigma_c=0.03)
    c_mono = estimate_c(s.frames, s.exposures, s.events)
    c_all = estimate_c(s.frames, s.exposures, s.events, monotone_only=False)
    assert abs(c_mono - 0.2) < 0.1 * 0.2, (c_mono, c_all)
    assert abs(c_mono - 0.2) < abs(c_all - 0.2), (c_mono, c_all)


@pytest.mark.parametrize("c_true, seed", [(0.15, 2), (0.2, 0), (0.3, 1)])
def test_estimate_c_single_frame_within_ten_percent(c_true, seed):
    """The single-frame energy (edges of the latent against the events around mid-exposure),
    with per-pixel threshold mismatch in the sensor."""
    s = moving_texture(num_frames=1, seed=seed, c=c_true, sigma_c=0.03)
    c, rep = estimate_c(s.frames[0], s.exposures[0], s.events, return_report=True)
    assert rep.method == "single" and not rep.at_bound
    assert abs(c - c_true) < 0.1 * c_true, (c, c_true)
