"""EDI (edi.deblur) on seeded synthetic ground truth (edi.moving_texture), and its inputs."""

import numpy as np
import pytest
import torch

from edi import LOG_EPS, EbadError, EventStream, InputError, deblur, deblur_with_report, moving_texture


@pytest.fixture(scope="module")
def seq1():
    return moving_texture(num_frames=1, seed=0, c=0.2)


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


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
    out, rep = deblur_with_report(B, (0.01, 0.01), seq1.events, c=0.2)
    np.testing.assert_allclose(out, B)
    assert "sharp frame" in rep.notes[0]
    far = (10.0, 10.04)
    out, rep = deblur_with_report(B, far, seq1.events)  # c=None, no events: no estimate needed
    np.testing.assert_allclose(out, B)
    assert rep.num_events == 0
    np.testing.assert_allclose(deblur(B, (0.0, 0.04), EventStream.empty(56, 40), c=0.3), B)


# --- numerics


def test_zero_pixel_gives_zero_not_nan():
    ev = EventStream([10, 20], [0, 0], [0, 0], [1, -1], 2, 1)
    B = np.array([[0.0, 0.3]])
    L = deblur(B, (0.0, 1e-4), ev, times=[0.0, 15e-6], c=0.5)
    assert np.isfinite(L).all() and (L >= 0).all()
    assert L[0, 0, 0] == pytest.approx(0.0, abs=1e-12)


def test_saturated_pixels_are_kept_and_reported(seq1):
    B = seq1.frames[0].copy()
    B[5:8, 5:8] = 1.0
    L, rep = deblur_with_report(B, seq1.exposures[0], seq1.events, c=0.2)
    np.testing.assert_allclose(L[5:8, 5:8], 1.0)
    assert rep.saturated[5:8, 5:8].all() and rep.saturated.sum() == 9


# --- bad input ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        (dict(exposure=(0.04, 0.0)), InputError, "ends before it starts"),
        (dict(exposure=(0.0, float("nan"))), InputError, "exposure must be finite"),
        (dict(blur="nan"), InputError, r"blur has a non-finite value at \(3, 4, 0\)"),
        (dict(blur=np.zeros((5, 5))), InputError, "events' sensor is 40x56"),
        (dict(blur=np.zeros((40, 56, 3, 1))), InputError, r"blur must be \[H, W\] or \[H, W, D\]"),
        (dict(times=[0.5]), ValueError, r"times\[0\] = 0.5 s is outside the exposure"),
        (dict(c=-0.2), InputError, "c must be finite and > 0"),
        (dict(c=(0.2, 0.3, 0.1)), InputError, r"pair \(c_pos, c_neg\)"),
        (dict(events="x"), TypeError, "edi.EventStream"),
        (dict(impl="gpu"), InputError, "impl must be one of"),
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


# --- input ranges (issue 13, row 5) -------------------------------------------------------------


def test_integer_frames_are_converted_with_their_dtype_range(seq1):
    B, ex = seq1.frames[0][..., 0], seq1.exposures[0]
    b8 = np.round(B * 255).astype(np.uint8)
    b16 = np.round(B * 65535).astype(np.uint16)
    L8 = deblur(b8, ex, seq1.events, c=0.2)
    L16 = deblur(b16, ex, seq1.events, c=0.2)
    np.testing.assert_allclose(L8, deblur(b8 / 255.0, ex, seq1.events, c=0.2), atol=1e-12)
    np.testing.assert_allclose(L16, deblur(b16 / 65535.0, ex, seq1.events, c=0.2), atol=1e-12)
    assert L8.max() < 1.0  # not "all white": the uint8 frame was not read as values up to 255
    Lt = deblur(torch.from_numpy(b8), ex, seq1.events, c=0.2)
    np.testing.assert_allclose(Lt.numpy(), L8, atol=1e-6)


@pytest.mark.parametrize(
    "blur, match",
    [
        (lambda B: B * 255.0, r"blur must be linear intensity in \[0, 1\], found values in \[\d"),
        (lambda B: B - 0.5, r"found values in \[-0\.4"),
        (lambda B: np.round(B * 255).astype(np.int64), "blur has dtype int64"),
        (lambda B: B > 0.5, "blur has dtype bool"),
    ],
)
def test_frames_outside_the_unit_range_are_refused(seq1, blur, match):
    with pytest.raises(InputError, match=match) as exc:
        deblur(blur(seq1.frames[0][..., 0]), seq1.exposures[0], seq1.events, c=0.2)
    assert isinstance(exc.value, EbadError)


def test_rounding_just_outside_the_unit_range_is_clipped(seq1):
    B = seq1.frames[0].copy()
    B[0, 0] = 1.0 + 1e-7
    B[0, 1] = -1e-7
    L = deblur(B, seq1.exposures[0], seq1.events, c=0.2)
    assert np.isfinite(L).all() and L.min() >= 0 and L.max() <= 1


# --- the window rule ------------------------------------------------------------------------


def test_an_event_at_t_start_is_in_and_one_at_t_end_is_out():
    B = np.full((1, 2), 0.5)
    ex = (100e-6, 200e-6)
    at_start = EventStream([100], [0], [0], [1], 2, 1)
    at_end = EventStream([200], [0], [0], [1], 2, 1)
    _, rep = deblur_with_report(B, ex, at_start, c=0.5)
    assert rep.num_events == 1
    L, rep = deblur_with_report(B, ex, at_end, c=0.5)
    assert rep.num_events == 0 and "no events" in rep.notes[0]
    np.testing.assert_allclose(L, B)
    # the event at t_start is in: the whole exposure after it is brighter, so every instant
    # inside shows B (E constant on (t_start, t_end)); E(t) counts the events before t
    L0 = deblur(B, ex, at_start, times=[101e-6, 150e-6, 199e-6], c=0.5)
    np.testing.assert_allclose(L0, np.broadcast_to(B, L0.shape), atol=1e-12)
    # moved 1 us later it splits the exposure: the start is darker than the end by exp(0.5)
    later = EventStream([101], [0], [0], [1], 2, 1)
    L1 = deblur(B, ex, later, times=[100e-6, 150e-6], c=0.5)
    assert (L1[1, 0, 0] + LOG_EPS) / (L1[0, 0, 0] + LOG_EPS) == pytest.approx(np.exp(0.5))


# --- a power response (gamma) ---------------------------------------------------------------------


@pytest.mark.parametrize("gamma", [0.45, 0.8, 2.2])
def test_gamma_deblurs_the_linearised_frame_and_maps_the_latent_back(seq1, gamma):
    """deblur(B ** g, gamma=g) is deblur(B) ** g: the frame is linearised, the latent re-encoded."""
    B, ex = seq1.frames[0], seq1.exposures[0]
    times = np.linspace(ex[0], ex[1], 3)
    got, rep = deblur_with_report(B**gamma, ex, seq1.events, times=times, c=0.2, gamma=gamma)
    want = deblur(B, ex, seq1.events, times=times, c=0.2) ** gamma
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert not rep.saturated.any()


def test_gamma_keeps_saturated_recorded_pixels(seq1):
    B, ex = seq1.frames[0].copy(), seq1.exposures[0]
    B[3, 4] = 0.995  # recorded at or above SATURATION: left as it is, whatever gamma
    out, rep = deblur_with_report(B, ex, seq1.events, c=0.2, gamma=0.5)
    assert rep.saturated[3, 4] and out[3, 4, 0] == pytest.approx(0.995, abs=1e-12)
    assert rep.saturated.sum() == 1


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), 10.0, "x"])
def test_bad_gamma_is_refused_naming_it(seq1, bad):
    with pytest.raises(InputError, match="gamma"):
        deblur(seq1.frames[0], seq1.exposures[0], seq1.events, c=0.2, gamma=bad)


def test_deblur_with_report_gives_deblurs_latents(seq1):
    """deblur_with_report returns deblur's latents (the input's kind) and the report; deblur
    returns the latents alone, whatever the arguments."""
    B, ex = seq1.frames[0], seq1.exposures[0]
    times = [ex[0], 0.5 * (ex[0] + ex[1])]
    for blur in (B, torch.from_numpy(B).float()):
        L = deblur(blur, ex, seq1.events, times=times, c=(0.2, 0.25))
        L2, rep = deblur_with_report(blur, ex, seq1.events, times=times, c=(0.2, 0.25))
        assert type(L) is type(L2) is type(blur)
        np.testing.assert_array_equal(np.asarray(L), np.asarray(L2))
        assert rep.c == (0.2, 0.25) and rep.num_events > 0
