"""Contrast-threshold estimation (edi.estimate_c) across generators and seeds.

The numbers in the docstrings were measured with ``python -m benchmarks.calibration`` and
the runs named in the tests; every seed of a range is used, none is picked."""
import math
import warnings

import numpy as np
import pytest
import torch

from edi import Contrast, EbadError, EventStream, InputError, LOG_EPS, deblur, estimate_c, events_in_window, moving_texture

C_BY_SEED = (0.15, 0.2, 0.3)


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


# --- one frame ----------------------------------------------------------------------------------


@pytest.mark.slow
def test_single_frame_flow_energy_ideal_sensor_all_seeds():
    """Measured c/c_true 1.025 to 1.053 over seeds 0-9 (no mismatch)."""
    ratios = []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=1, seed=seed, c=c)
        est, rep = estimate_c(s.frames[0], s.exposures[0], s.events, return_report=True)
        assert rep.method == "single" and rep.energy_name == "flow" and not rep.at_bound
        ratios.append(est / c)
    assert all(abs(r - 1) <= 0.1 for r in ratios), np.round(ratios, 3)


@pytest.mark.slow
def test_single_frame_flow_energy_with_mismatch_all_seeds():
    """Per-pixel mismatch sigma_c 0.03 (20% of c = 0.15): measured c/c_true 0.81 to 1.05,
    8 of 10 seeds within 10% (issue 11's target is 9 of 10; not met on this generator)."""
    ratios = []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=1, seed=seed, c=c, sigma_c=0.03)
        est, rep = estimate_c(s.frames[0], s.exposures[0], s.events, return_report=True)
        assert not rep.at_bound
        ratios.append(est / c)
    ratios = np.array(ratios)
    assert (np.abs(ratios - 1) <= 0.1).sum() >= 8 and (np.abs(ratios - 1) <= 0.2).all(), np.round(ratios, 3)


def test_single_frame_estimate_sharpens_the_frame():
    s = moving_texture(num_frames=1, seed=0, c=0.2)
    B, ex = s.frames[0], s.exposures[0]
    gt = s.sharp(ex.mean())
    L, rep = deblur(B, ex, s.events, return_report=True)  # c=None: estimated on this frame
    assert rep.c_report is not None and rep.c_report.method == "single"
    assert rep.c == Contrast(*(2 * [estimate_c(B, ex, s.events)]))
    assert rmse(L, gt) < 0.4 * rmse(B, gt)


def test_paper_energy_has_no_interior_minimum():
    """The EDI paper's energy (TV minus the Sobel correlation with the event integral), as
    the paper states it, grows with c on this generator: its minimum is the bracket's low
    end for every seed, and the report says so."""
    for seed in range(5):
        s = moving_texture(num_frames=1, seed=seed, c=C_BY_SEED[seed % 3], sigma_c=0.03)
        est, rep = estimate_c(s.frames[0], s.exposures[0], s.events, energy="paper", return_report=True)
        assert rep.at_bound and est == pytest.approx(rep.bracket[0], rel=0.02)
        assert "no interior minimum" in rep.message and "--c" in rep.message
        cs, es = zip(*sorted(rep.evals))
        assert es[0] == min(es)


def test_single_frame_pair_finds_the_ratio():
    """c = (0.15, 0.3): measured c_pos / c_neg 0.46 to 0.48 (true 0.5) over seeds 0-3."""
    for seed in range(4):
        s = moving_texture(num_frames=1, seed=seed, c=(0.15, 0.3), sigma_c=0.03)
        est = estimate_c(s.frames[0], s.exposures[0], s.events, pair=True)
        assert isinstance(est, Contrast)
        assert abs(est.pos / est.neg / 0.5 - 1) < 0.1, est


# --- several frames -------------------------------------------------------------------------------


def naive_least_squares(frames, centres, events):
    """The estimator issue 11 found biased: c = sum D N / sum N^2 (a least squares on c N)."""
    num = den = 0.0
    for i in range(len(centres) - 1):
        j0, j1 = events_in_window(events, centres[i], centres[i + 1])
        n = events[j0:j1].count_image().astype(np.float64)
        d = np.log(frames[i + 1].mean(-1) + LOG_EPS) - np.log(frames[i].mean(-1) + LOG_EPS)
        m = n != 0
        num += float((d[m] * n[m]).sum())
        den += float((n[m] ** 2).sum())
    return num / den


@pytest.mark.slow
def test_consistency_is_unbiased_under_mismatch():
    """Sharp frames (t_start == t_end, the exact log change), c 0.15, mismatch 0.03: the
    least squares on c N weights each pixel by N^2, and low-threshold pixels fire more, so it
    reads 0.66-0.86x; the instrumental moment equations read 0.975-0.995x (seeds 0-5)."""
    ours, naive = [], []
    for seed in range(6):
        s = moving_texture(num_frames=4, seed=seed, c=0.15, sigma_c=0.03)
        mid = s.exposures.mean(axis=1)
        sharp = np.stack([s.sharp(t) for t in mid])
        ex = np.stack([mid, mid], axis=1)
        c, rep = estimate_c(sharp, ex, s.events, return_report=True)
        assert rep.method == "consistency"
        ours.append(c / 0.15)
        naive.append(naive_least_squares(sharp, mid, s.events) / 0.15)
    assert all(abs(r - 1) <= 0.05 for r in ours), np.round(ours, 3)
    assert np.mean(naive) < 0.85 and max(naive) < 0.9, np.round(naive, 3)


@pytest.mark.slow
def test_consistency_blurry_frames():
    """Blurry frames with gaps between the exposures (exposure 20 ms, period 50 ms), mismatch
    0.03, seeds 0-4 at each c: measured 0.949-0.979x at c 0.15, 0.986-1.003x at 0.2,
    1.007-1.028x at 0.3, 14 of 15 within 5% (issue 11's multi-frame target is 9 of 10). Before
    the residual model (pixels that turn lose up to a step to the hysteresis of their
    reference) c 0.3 read 1.05-1.07x."""
    ratios = []
    for c_true in (0.15, 0.2, 0.3):
        for seed in range(5):
            s = moving_texture(num_frames=4, seed=seed, c=c_true, sigma_c=0.03, exposure=0.02)
            c, rep = estimate_c(s.frames, s.exposures, s.events, return_report=True)
            assert rep.method == "consistency" and not rep.at_bound
            ratios.append(c / c_true)
    err = np.abs(np.array(ratios) - 1)
    assert (err <= 0.05).sum() >= 14 and err.max() <= 0.06, np.round(ratios, 3)


@pytest.mark.slow
def test_consistency_pair():
    """c = (0.15, 0.3), mismatch 0.03: measured 0.99-1.03x (c_pos), 1.03-1.05x (c_neg), seeds 0-4."""
    for seed in range(5):
        s = moving_texture(num_frames=4, seed=seed, c=(0.15, 0.3), sigma_c=0.03, exposure=0.02)
        est, rep = estimate_c(s.frames, s.exposures, s.events, pair=True, return_report=True)
        assert rep.method == "consistency" and isinstance(est, Contrast)
        assert abs(est.pos / 0.15 - 1) < 0.1 and abs(est.neg / 0.3 - 1) < 0.1, (seed, est)


def test_auto_falls_back_to_one_frame_when_the_frames_contradict_the_events():
    """Frames given in the wrong order: the events between the centres run against the
    frames' changes. "consistency" refuses with a message; "auto" says so and uses one frame."""
    s = moving_texture(num_frames=3, seed=0, c=0.2, exposure=0.02)
    shuffled = s.frames[[1, 0, 2]]
    with pytest.raises(InputError, match="do not follow the frames' changes"):
        estimate_c(shuffled, s.exposures, s.events, method="consistency")
    c, rep = estimate_c(shuffled, s.exposures, s.events, return_report=True)
    assert rep.method == "single" and "used the single-frame energy" in rep.message


def test_sharp_frames_torch_input():
    s = moving_texture(num_frames=3, seed=3, c=0.25)
    sharp = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    ex = np.repeat(s.exposures.mean(axis=1)[:, None], 2, axis=1)
    c = estimate_c(torch.from_numpy(sharp), ex, s.events)
    assert abs(c - 0.25) < 0.1 * 0.25, c  # measured 1.061x (ideal sensor, c 0.25: see above)


# --- faults -------------------------------------------------------------------------------------


def test_all_saturated_frames_give_one_message():
    s = moving_texture(num_frames=3, seed=0, c=0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any numpy warning fails the test
        with pytest.raises(InputError, match=r"every pixel of the 3 frame\(s\) is saturated.*give c") as exc:
            estimate_c(np.ones_like(s.frames), s.exposures, s.events)
    assert isinstance(exc.value, EbadError)


def test_estimate_c_bad_input():
    s = moving_texture(num_frames=1, seed=0, c=0.2)
    with pytest.raises(InputError, match="bracket"):
        estimate_c(s.frames[0], s.exposures[0], s.events, bracket=(0.5, 0.1))
    with pytest.raises(InputError, match="exposures must be"):
        estimate_c(s.frames, np.zeros((1, 3)), s.events)
    with pytest.raises(InputError, match="no blurry frame with events"):
        estimate_c(s.frames[0], (5.0, 5.1), s.events)
    with pytest.raises(InputError, match="needs at least two frames"):
        estimate_c(s.frames[0], s.exposures[0], s.events, method="consistency")
    with pytest.raises(InputError, match="energy must be"):
        estimate_c(s.frames[0], s.exposures[0], s.events, energy="tv")
    with pytest.raises(InputError, match=r"frames\[0\] must be linear intensity"):
        estimate_c(s.frames[0] * 255, s.exposures[0], s.events)


# --- the ray-cast scenes ----------------------------------------------------------------------------


@pytest.mark.slow
def test_ray_cast_scenes_single_and_consistency():
    """scenes.make_scene with the idealised (linear) sensor, 64x48, 3 frames, c 0.2, mismatch
    0.03: measured single-frame 0.97-1.06x and consistency 0.944-0.984x (boxes grey, spheres
    colour, seeds 0-2; 0.999-1.03x before the residual model, which the 160x120 scenes of the
    benchmark read 0.97-0.99x with). (The realistic sensor's gamma makes any estimate from its
    frames read about gamma x c: benchmarks.calibration.)"""
    from scenes import make_scene

    multis = []
    for name, rgb in (("boxes", False), ("spheres", True)):
        for seed in range(3):
            sc = make_scene(name, "tiny", seed=seed, rgb=rgb, n_frames=3, n_test=0, sensor="ideal")
            cap = sc.capture
            c_true = 0.5 * (sc.c_pos.mean() + sc.c_neg.mean())  # truth: read here only
            single, rep = estimate_c(cap.frames[0], cap.exposures[0], cap.events, return_report=True)
            multi = estimate_c(cap.frames, cap.exposures, cap.events)
            assert not rep.at_bound
            assert abs(single / c_true - 1) <= 0.1, (name, seed, single)
            multis.append(multi / c_true)
    err = np.abs(np.array(multis) - 1)
    assert (err <= 0.05).sum() >= 5 and err.max() <= 0.06, np.round(multis, 3)


# --- the quantisation residual of the consistency relation ----------------------------------------


def residual_reference(events, exposures, n_steps=20_000):
    """Per pixel, in plain Python and by midpoint sums: over the fraction u of the interval
    between two events, the residual u after an event of the same polarity as the closing one,
    (2 + sqrt 3) u^2 - (1 + sqrt 3) u after one of the other polarity, 0 before the first; its
    mean over each exposure (its value at the instant when t_start == t_end; an event at the
    instant has not fired yet), per polarity of the closing event."""
    from edi import seconds_to_us

    def shape(u, same):
        return u if same else (2 + math.sqrt(3)) * u * u - (1 + math.sqrt(3)) * u

    H, W = events.height, events.width
    out = np.zeros((len(exposures), 2, H, W))
    for y in range(H):
        for x in range(W):
            sel = (events.x == x) & (events.y == y)
            ts, ps = events.t[sel].astype(float), events.p[sel]
            for f, (t_s, t_e) in enumerate(exposures):
                A, B = float(seconds_to_us(t_s)), float(seconds_to_us(t_e))
                for k in range(1, len(ts)):
                    t0, t1 = ts[k - 1], ts[k]
                    row, same = (0 if ps[k] > 0 else 1), ps[k] == ps[k - 1]
                    if B == A:
                        if t0 < A <= t1:
                            out[f, row, y, x] += shape((A - t0) / max(t1 - t0, 1.0), same)
                        continue
                    lo, hi = max(A, t0), min(B, t1)
                    if hi > lo:
                        tm = lo + (np.arange(n_steps) + 0.5) * (hi - lo) / n_steps
                        out[f, row, y, x] += shape((tm - t0) / max(t1 - t0, 1.0), same).mean() * (hi - lo) / (B - A)
    return out


def test_mean_residual_matches_a_per_pixel_reference():
    from edi import EventStream
    from edi.contrast import _mean_residual

    rng = np.random.default_rng(0)
    M, W, H = 400, 4, 3
    t = np.sort(rng.integers(0, 10_000, M))
    ev = EventStream(t, rng.integers(0, W, M), rng.integers(0, H, M), np.where(rng.random(M) < 0.6, 1, -1), W, H)
    exposures = np.array([[0.0, 0.004], [0.0025, 0.0071], [0.005, 0.005], [float(t[17]) * 1e-6, float(t[17]) * 1e-6],
                          [0.0099, 0.0125], [0.02, 0.03]])
    got = _mean_residual(ev, exposures)
    want = residual_reference(ev, exposures)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8)
    assert (want[:4] > 0).any() and (want[:4] < 0).any() and (want[-1] == 0).all()  # something to compare; nothing after the last event


@pytest.mark.slow
def test_consistency_pair_on_blurry_texture_with_a_running_sensor():
    """moving_texture with exposures filling 80% of the frame interval, mismatch 0.03, the
    sensor running 0.1 s before frame 0, seeds 0-9: measured 0.969-1.014x, 10 of 10 within 5%
    in the worse polarity (issue 11's target: 9 of 10); 5 of 10 (up to 1.11x) before the
    instruments followed the exposure means and the counts carried the residual, 8 of 10 with
    a residual of 0 where a pixel turns."""
    worst = []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=4, seed=seed, c=c, sigma_c=0.03, lead=0.1)
        est, rep = estimate_c(s.frames, s.exposures, s.events, pair=True, return_report=True)
        assert rep.method == "consistency" and not rep.at_bound
        worst.append(max(abs(est.pos / c - 1), abs(est.neg / c - 1)))
    worst = np.array(worst)
    assert (worst <= 0.05).sum() >= 9 and worst.max() <= 0.08, np.round(worst, 3)


@pytest.mark.slow
def test_single_frame_with_a_running_sensor():
    """The first frame of a sensor started 0.1 s before it (the others as in the benchmark):
    9 of 10 seeds within 10% (the tenth at 1.10x); started at the exposure, 8 of 10, from the
    per-pixel mismatch rather than the start (``test_single_frame_low_reads_come_from_the_mismatch``)."""
    ratios = []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=1, seed=seed, c=c, sigma_c=0.03, lead=0.1)
        est, rep = estimate_c(s.frames[0], s.exposures[0], s.events, return_report=True)
        assert rep.method == "single" and not rep.at_bound
        ratios.append(est / c)
    ratios = np.array(ratios)
    assert (np.abs(ratios - 1) <= 0.1).sum() >= 9 and (np.abs(ratios - 1) <= 0.15).all(), np.round(ratios, 3)


@pytest.mark.slow
def test_single_frame_low_reads_come_from_the_mismatch():
    """Sensor started at the exposure (the benchmark's texture_no_lead), seeds 0-9: the same
    scenes without per-pixel mismatch read 1.025-1.053x, all within 10%; with sigma_c 0.03 each
    seed reads lower or the same (measured 0 to 0.24 lower, mean 0.083; seeds 0 and 7, 0.81x and
    0.90x, fall outside 10%). The mismatch's noise (the pixel's threshold error times its count)
    is in the latent's gradients as well as in the event-driven change, and the flow fit explains
    less of the change as that noise grows with c."""
    ideal, mismatch = [], []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        for sigma, out in ((0.0, ideal), (0.03, mismatch)):
            s = moving_texture(num_frames=1, seed=seed, c=c, sigma_c=sigma)
            out.append(estimate_c(s.frames[0], s.exposures[0], s.events) / c)
    ideal, mismatch = np.array(ideal), np.array(mismatch)
    assert (np.abs(ideal - 1) <= 0.1).all(), np.round(ideal, 3)
    assert (mismatch <= ideal + 0.01).all() and (ideal - mismatch).mean() > 0.04, np.round(ideal - mismatch, 3)


def test_low_end_message_says_the_events_do_not_explain_the_blur():
    """Events that have nothing to do with the frame: uniform random ones (as many as the frame's
    own) leave the flow energy's minimum at the low end in 3 of seeds 0-4 (seeds 2 and 4 stop
    inside, at 0.56 and 0.051: an interior estimate does not prove that the events explain the
    blur), and the report then says what the low end means; another texture's events drive it to
    the top end, whose message does not say it, nor does the paper energy's low end (its own bias)."""
    low = 0
    for seed in range(5):
        s = moving_texture(num_frames=1, seed=seed, c=C_BY_SEED[seed % 3], sigma_c=0.03)
        ex = s.exposures[0]
        rng = np.random.default_rng(seed)
        n = int(np.diff(events_in_window(s.events, *ex))[0])
        t = np.sort(rng.integers(round(ex[0] * 1e6), round(ex[1] * 1e6), n))
        ev = EventStream(t, rng.integers(0, 56, n), rng.integers(0, 40, n),
                         np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8), 56, 40)
        est, rep = estimate_c(s.frames[0], ex, ev, return_report=True)
        if rep.at_bound and est < rep.bracket[0] * 1.02:
            low += 1
            assert "no interior minimum" in rep.message and "cover the whole exposure" in rep.message
        else:
            assert "cover the whole exposure" not in rep.message
    assert low >= 3
    other = moving_texture(num_frames=1, seed=100, c=0.2, sigma_c=0.03)
    est, rep = estimate_c(s.frames[0], ex, other.events, return_report=True)
    assert rep.at_bound and est > rep.bracket[1] / 1.02 and "cover the whole exposure" not in rep.message
    _, rep = estimate_c(s.frames[0], ex, s.events, energy="paper", return_report=True)
    assert rep.at_bound and "cover the whole exposure" not in rep.message


# --- a power response (gamma) ---------------------------------------------------------------------


def test_gamma_frames_read_gamma_times_c_unless_gamma_is_given():
    """Frames recorded through irradiance ** 0.8: with gamma given the estimate is that of the
    linear frames; taken as linear it is about 0.8 x that (c in the frames' units): measured
    0.765-0.77 x here, seeds 0-2 (0.79-0.80 x on the benchmark's realistic sensor). Were gamma
    told apart from c by the frames, the ratio would be near 1."""
    g = 0.8
    for seed in range(3):
        s = moving_texture(num_frames=3, seed=seed, c=0.2, lead=0.1)
        lin = estimate_c(s.frames, s.exposures, s.events, pair=True)
        given, rep = estimate_c(s.frames**g, s.exposures, s.events, pair=True, gamma=g, return_report=True)
        assumed = estimate_c(s.frames**g, s.exposures, s.events, pair=True)
        assert rep.gamma == g
        np.testing.assert_allclose(given, lin, rtol=1e-6)
        ratio = np.array(assumed) / np.array(lin)
        assert (np.abs(ratio - g) <= 0.05).all(), ratio


def test_estimate_c_bad_gamma_names_it():
    s = moving_texture(num_frames=1, seed=0, c=0.2)
    for bad in (0.0, float("inf"), "estimate", None):
        with pytest.raises(InputError, match="gamma"):
            estimate_c(s.frames[0], s.exposures[0], s.events, gamma=bad)
