"""Contrast-threshold estimation (edi.estimate_c) across generators and seeds.

The numbers in the docstrings were measured with ``python -m benchmarks.calibration`` and
the runs named in the tests; every seed of a range is used, none is picked."""

import functools
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from edi import (
    LOG_EPS,
    Contrast,
    EbadError,
    EventStream,
    InputError,
    deblur_with_report,
    estimate_c,
    estimate_contrast,
    events_in_window,
    moving_texture,
)
from tests.edi._helpers import run_python

C_BY_SEED = (0.15, 0.2, 0.3)


@functools.cache
def texture(**kw):
    """``moving_texture(**kw)`` generated once per argument set (about a second each): the flow-energy
    and mismatch tests read the same mismatched single frames. The estimators do not write to it."""
    return moving_texture(**kw)


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


# --- one frame ----------------------------------------------------------------------------------


@pytest.mark.slow
def test_single_frame_flow_energy_on_the_benchmark_textures():
    """benchmarks.calibration's texture_uniform (the sensor running 0.1 s before the frame, every
    pixel's threshold exactly c) and texture_no_lead (the sensor started at the frame, per-pixel
    mismatch sigma_c 0.03), one frame, seeds 0-9, the target of issue 11 (9 of 10 within 10%):
    measured 0.990-1.006x (10 of 10) and 0.889-1.033x (9 of 10, seed 0 at 0.889). Before the
    hidden crossings, the exact derivative and the halves' products (``edi.contrast._flow_setup``)
    1.051-1.126x (8 of 10, rising with c) and 0.808-1.053x (8 of 10)."""
    uniform, no_lead = [], []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        for kw, out in ((dict(sigma_c=0.0, lead=0.1), uniform), (dict(sigma_c=0.03), no_lead)):
            s = texture(num_frames=1, seed=seed, c=c, **kw)
            rep = estimate_contrast(s.frames[0], s.exposures[0], s.events)
            est = rep.c.mean
            assert rep.method == "single" and rep.energy_name == "flow" and not rep.at_bound
            assert rep.reliable and rep.explained > 0.9, rep.explained  # its own events: no unreliable flag
            out.append(est / c)
    uniform, no_lead = np.array(uniform), np.array(no_lead)
    assert (np.abs(uniform - 1) <= 0.1).sum() >= 9 and abs(np.median(uniform) - 1) <= 0.02, np.round(uniform, 3)
    assert (np.abs(no_lead - 1) <= 0.1).sum() >= 9 and (np.abs(no_lead - 1) <= 0.12).all(), np.round(no_lead, 3)


def fixed_level_events(seq, c, lead, seed, step_us=50):
    """Events of a sensor without hysteresis watching ``seq``'s texture on moving_texture's time
    grid: one event each time log(I + eps) crosses one of a pixel's levels phase + k c (phase
    uniform in [0, c)), up or down alike; a DVS pixel instead fires at c from its last event."""
    rng = np.random.default_rng(seed)
    H, W = seq.frames.shape[1:3]
    phase = rng.uniform(0.0, c, (H, W))
    t_end = round((seq.exposures[-1, 1]) * 1e6)
    level = None
    ts, xs, ys, ps = [], [], [], []
    for tj in range(0, t_end + step_us, step_us):
        new = np.floor((np.log(seq.sharp(tj * 1e-6).mean(axis=-1) + LOG_EPS) - phase) / c)
        if level is not None:
            for n, pol in ((new - level, 1), (level - new, -1)):
                yy, xx = np.nonzero(n > 0)
                reps = n[yy, xx].astype(np.int64)
                ts.append(np.full(reps.sum(), tj))
                xs.append(np.repeat(xx, reps))
                ys.append(np.repeat(yy, reps))
                ps.append(np.full(reps.sum(), pol))
        level = new
    t = np.concatenate(ts)
    o = np.argsort(t, kind="stable")
    return EventStream(t[o], np.concatenate(xs)[o], np.concatenate(ys)[o], np.concatenate(ps)[o], W, H)


@pytest.mark.slow
def test_the_bias_rising_with_c_was_the_sensors_hysteresis(monkeypatch):
    """A DVS pixel fires at c from the level of its last event, so after a reversal it needs a
    change of 2c: the return through its last level makes no event. Textures 24x32, the sensor
    running 0.1 s, every threshold c, seeds 0-5 (c 0.15, 0.2, 0.3 twice): a sensor firing at fixed
    levels (no hysteresis) read without hidden crossings gives 0.997-1.001x; the DVS's events
    without them 1.022-1.088x, rising with c (the bias of issue 11); with them (the default)
    0.986-1.014x."""
    from edi import contrast

    raw = lambda events, exposure: events[slice(*events_in_window(events, *exposure))]  # noqa: E731
    fixed, dvs_raw, dvs = [], [], []
    for seed in range(6):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=1, seed=seed, c=c, lead=0.1, height=24, width=32)
        B, ex = s.frames[0], s.exposures[0]
        dvs.append(estimate_c(B, ex, s.events).mean / c)
        with monkeypatch.context() as m:
            m.setattr(contrast, "_with_hidden_crossings", raw)
            fixed.append(estimate_c(B, ex, fixed_level_events(s, c, 0.1, seed)).mean / c)
            dvs_raw.append(estimate_c(B, ex, s.events).mean / c)
    fixed, dvs_raw, dvs = np.array(fixed), np.array(dvs_raw), np.array(dvs)
    assert (np.abs(fixed - 1) <= 0.03).all(), np.round(fixed, 3)
    assert (np.abs(dvs - 1) <= 0.03).all(), np.round(dvs, 3)
    assert (dvs_raw > fixed + 0.015).all() and dvs_raw[[2, 5]].min() > dvs_raw[[0, 3]].max(), np.round(dvs_raw, 3)


def test_single_frame_estimate_sharpens_the_frame():
    s = moving_texture(num_frames=1, seed=0, c=0.2)
    B, ex = s.frames[0], s.exposures[0]
    gt = s.sharp(ex.mean())
    L, rep = deblur_with_report(B, ex, s.events)  # c=None: estimated on this frame
    assert rep.c_report is not None and rep.c_report.method == "single"
    assert rep.c == Contrast(*(2 * [estimate_c(B, ex, s.events).mean]))
    assert rmse(L, gt) < 0.4 * rmse(B, gt)


def test_paper_energy_has_no_interior_minimum():
    """The EDI paper's energy (TV minus the Sobel correlation with the event integral), as
    the paper states it, grows with c on this generator: its minimum is the bracket's low
    end for every seed, and the report says so."""
    for seed in range(5):
        s = moving_texture(num_frames=1, seed=seed, c=C_BY_SEED[seed % 3], sigma_c=0.03)
        rep = estimate_contrast(s.frames[0], s.exposures[0], s.events, energy="paper")
        est = rep.c.mean
        assert rep.at_bound and est == pytest.approx(rep.bracket[0], rel=0.02)
        assert "no interior minimum" in rep.message and "--c" in rep.message
        cs, es = zip(*sorted(rep.evals))
        assert es[0] == min(es)


def test_single_frame_pair_finds_the_ratio():
    """c = (0.15, 0.3): measured c_pos / c_neg 0.470 to 0.486 (true 0.5) over seeds 0-3."""
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
        rep = estimate_contrast(sharp, ex, s.events)
        c = rep.c.mean
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
            rep = estimate_contrast(s.frames, s.exposures, s.events)
            c = rep.c.mean
            assert rep.method == "consistency" and not rep.at_bound
            ratios.append(c / c_true)
    err = np.abs(np.array(ratios) - 1)
    assert (err <= 0.05).sum() >= 14 and err.max() <= 0.06, np.round(ratios, 3)


@pytest.mark.slow
def test_consistency_pair():
    """c = (0.15, 0.3), mismatch 0.03: measured 0.99-1.03x (c_pos), 1.03-1.05x (c_neg), seeds 0-4."""
    for seed in range(5):
        s = moving_texture(num_frames=4, seed=seed, c=(0.15, 0.3), sigma_c=0.03, exposure=0.02)
        rep = estimate_contrast(s.frames, s.exposures, s.events, pair=True)
        est = rep.c
        assert rep.method == "consistency" and isinstance(est, Contrast)
        assert abs(est.pos / 0.15 - 1) < 0.1 and abs(est.neg / 0.3 - 1) < 0.1, (seed, est)


def test_auto_falls_back_to_one_frame_when_the_frames_contradict_the_events():
    """Frames given in the wrong order: the events between the centres run against the
    frames' changes. "consistency" refuses with a message; "auto" says so and uses one frame."""
    s = moving_texture(num_frames=3, seed=0, c=0.2, exposure=0.02)
    shuffled = s.frames[[1, 0, 2]]
    with pytest.raises(InputError, match="do not follow the frames' changes"):
        estimate_c(shuffled, s.exposures, s.events, method="consistency")
    rep = estimate_contrast(shuffled, s.exposures, s.events)
    assert rep.method == "single" and "used the single-frame energy" in rep.message


def test_sharp_frames_torch_input():
    s = moving_texture(num_frames=3, seed=3, c=0.25)
    sharp = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    ex = np.repeat(s.exposures.mean(axis=1)[:, None], 2, axis=1)
    c = estimate_c(torch.from_numpy(sharp), ex, s.events).mean
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
    0.03: measured single-frame 0.987-1.055x and consistency 0.944-0.984x (boxes grey, spheres
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
            rep = estimate_contrast(cap.frames[0], cap.exposures[0], cap.events)
            single = rep.c.mean
            multi = estimate_c(cap.frames, cap.exposures, cap.events).mean
            assert not rep.at_bound and rep.reliable, rep.explained
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


def _residual_case():
    from edi import EventStream

    rng = np.random.default_rng(0)
    M, W, H = 400, 4, 3
    t = np.sort(rng.integers(0, 10_000, M))
    t[50:53] = t[50]  # simultaneous events (at one pixel or several)
    ev = EventStream(t, rng.integers(0, W, M), rng.integers(0, H, M), np.where(rng.random(M) < 0.6, 1, -1), W, H)
    exposures = np.array(
        [
            [0.0, 0.004],
            [0.0025, 0.0071],  # overlaps the one before
            [0.005, 0.005],  # an instant
            [float(t[17]) * 1e-6, float(t[17]) * 1e-6],  # an instant on an event
            [float(t[50]) * 1e-6, float(t[60]) * 1e-6],  # from simultaneous events
            [0.0099, 0.0125],
            [0.02, 0.03],  # after the last event
        ]
    )
    return ev, exposures


def test_mean_residual_matches_a_per_pixel_reference():
    from edi.contrast import _mean_residual

    ev, exposures = _residual_case()
    got = _mean_residual(ev, exposures)
    want = residual_reference(ev, exposures)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8)
    assert (
        (want[:5] > 0).any() and (want[:5] < 0).any() and (want[-1] == 0).all()
    )  # something to compare; nothing after the last event


def test_mean_residual_takes_the_exposures_in_any_order():
    """The kernel walks the exposures sorted by start: given in another order (one that ends late
    first, instants between), each keeps its own residual."""
    from edi.contrast import _mean_residual

    ev, exposures = _residual_case()
    perm = np.array([6, 2, 0, 4, 1, 5, 3])
    got = _mean_residual(ev, exposures[perm])
    np.testing.assert_allclose(got, residual_reference(ev, exposures)[perm], rtol=0, atol=1e-8)


_RESIDUAL_PEAK = """
import numpy as np
from edi import EventStream
from edi.contrast import _mean_residual
rng = np.random.default_rng(1)
M, W, H = 2_000_000, 64, 48
ev = EventStream(
    np.sort(rng.integers(0, 1_000_000, M)).astype(np.int32),
    rng.integers(0, W, M).astype(np.uint16),
    rng.integers(0, H, M).astype(np.uint16),
    np.where(rng.random(M) < 0.5, 1, -1).astype(np.int8),
    W,
    H,
)
exposures = np.array([[0.1, 0.3], [0.45, 0.5], [0.7, 0.7]])
_mean_residual(ev[:10], exposures)  # the kernel loaded (or compiled) before the baseline
open("/proc/self/clear_refs", "w").write("5")  # the peak (VmHWM) from now on
base = status("VmRSS")
_mean_residual(ev, exposures)
print((status("VmHWM") - base) * 1024, M)
"""


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="VmHWM needs Linux's /proc")
def test_mean_residual_works_in_bounded_memory():
    """The residual of 2M events over a 64x48 sensor is one pass over the stream: its peak grows by
    its output and the pixels' state, not with the events (the sort it replaced took 101 bytes an
    event, 36M events 3.6 GB)."""
    grew, M = (int(v) for v in run_python(_RESIDUAL_PEAK))
    assert grew < 2 * M, f"{grew / M:.1f} bytes an event"


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
        rep = estimate_contrast(s.frames, s.exposures, s.events, pair=True)
        est = rep.c
        assert rep.method == "consistency" and not rep.at_bound
        worst.append(max(abs(est.pos / c - 1), abs(est.neg / c - 1)))
    worst = np.array(worst)
    assert (worst <= 0.05).sum() >= 9 and worst.max() <= 0.08, np.round(worst, 3)


@pytest.mark.slow
def test_single_frame_with_a_running_sensor():
    """The first frame of a sensor started 0.1 s before it, mismatch 0.03 (the benchmark's
    texture): measured 0.935-1.010x, 10 of 10 within 10% (9 of 10, up to 1.10x, before the
    hidden crossings, the exact derivative and the halves' products)."""
    ratios = []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        s = moving_texture(num_frames=1, seed=seed, c=c, sigma_c=0.03, lead=0.1)
        rep = estimate_contrast(s.frames[0], s.exposures[0], s.events)
        est = rep.c.mean
        assert rep.method == "single" and not rep.at_bound
        ratios.append(est / c)
    ratios = np.array(ratios)
    assert (np.abs(ratios - 1) <= 0.1).sum() >= 9 and (np.abs(ratios - 1) <= 0.1).all(), np.round(ratios, 3)


@pytest.mark.slow
def test_single_frame_low_reads_come_from_the_mismatch():
    """Sensor started at the exposure (the benchmark's texture_no_lead), seeds 0-9: the same
    scenes without per-pixel mismatch read 1.004-1.037x (a start-up residue: no pixel has an
    event before the frame, so a reversal at its first event is not seen); with sigma_c 0.03
    each seed reads lower or the same, by 0.004 to 0.115 (mean 0.044; 0 to 0.24, mean 0.083,
    when the fit's second moments were squares of the noisy gradients). What is left is not
    the fit's: a pixel of threshold c_px fires c / c_px times as often as one of threshold c, and
    the mean of c / c_px is 1 + (sigma_c / c)^2 and more, 1.046 at c 0.15 (a harmonic mean of
    the thresholds, 0.956 of their mean, as the consistency estimator's instruments also see),
    plus the draw of 2000 pixels' thresholds (seed 0, 0.889x, is the lowest)."""
    ideal, mismatch = [], []
    for seed in range(10):
        c = C_BY_SEED[seed % 3]
        for sigma, out in ((0.0, ideal), (0.03, mismatch)):
            s = texture(num_frames=1, seed=seed, c=c, sigma_c=sigma)
            out.append(estimate_c(s.frames[0], s.exposures[0], s.events).mean / c)
    ideal, mismatch = np.array(ideal), np.array(mismatch)
    assert (np.abs(ideal - 1) <= 0.05).all(), np.round(ideal, 3)
    assert (mismatch <= ideal + 0.01).all() and 0.02 < (ideal - mismatch).mean() < 0.07, np.round(ideal - mismatch, 3)


def test_low_end_message_says_the_events_do_not_explain_the_blur():
    """A bracket above the true c (0.3) leaves the flow energy's minimum at its low end, and the
    report says what the low end means; a bracket below it, the top end, whose message does not
    say it, nor does the paper energy's low end (its own bias). (The real frames whose estimate
    sits at the low end: tests/edi/test_real_data.py.)"""
    s = moving_texture(num_frames=1, seed=2, c=0.3, sigma_c=0.03)
    B, ex = s.frames[0], s.exposures[0]
    rep = estimate_contrast(B, ex, s.events, bracket=(0.6, 1.5))
    est = rep.c.mean
    assert rep.at_bound and est < 0.6 * 1.02
    assert "no interior minimum" in rep.message and "cover the whole exposure" in rep.message
    rep = estimate_contrast(B, ex, s.events, bracket=(0.03, 0.1))
    est = rep.c.mean
    assert rep.at_bound and est > 0.1 / 1.02 and "cover the whole exposure" not in rep.message
    rep = estimate_contrast(B, ex, s.events, energy="paper")
    assert rep.at_bound and "cover the whole exposure" not in rep.message


def test_events_unrelated_to_the_frame_explain_nothing():
    """Uniform random events, as many as the frame's own: the flow energy stays at 0.90-0.98 (the
    fit explains at most a tenth of their changes) at every c the search tries, where the frame's
    own events leave 0.007-0.012, seeds 0-4. Where it then stops means nothing (inside the bracket
    in 4 of these 5; with squared gradients in the fit, noise that a larger c amplified made it
    grow with c, and the search stopped at the low end in 3 of 5), so the report says the estimate
    is unreliable: its fit explains less than FLOW_MIN_EXPLAINED of the events' changes."""
    for seed in range(5):
        s = moving_texture(num_frames=1, seed=seed, c=C_BY_SEED[seed % 3], sigma_c=0.03)
        ex = s.exposures[0]
        rng = np.random.default_rng(seed)
        n = int(np.diff(events_in_window(s.events, *ex))[0])
        t = np.sort(rng.integers(round(ex[0] * 1e6), round(ex[1] * 1e6), n))
        ev = EventStream(
            t,
            rng.integers(0, 56, n),
            rng.integers(0, 40, n),
            np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8),
            56,
            40,
        )
        rep = estimate_contrast(s.frames[0], ex, ev)
        assert min(e for _, e in rep.evals) > 0.9, sorted(rep.evals)
        assert not rep.reliable and rep.explained < 0.1 and "do not follow the frame's blur" in rep.message
        assert "--c" in rep.message
        own = estimate_contrast(s.frames[0], ex, s.events)
        assert own.energy < 0.02, own.energy
        assert own.reliable and own.explained > 0.98 and own.message == ""


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
        rep = estimate_contrast(s.frames**g, s.exposures, s.events, pair=True, gamma=g)
        given = rep.c
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


def test_estimate_c_returns_the_reports_contrast():
    """One return type: estimate_c gives an edi.Contrast, pair or not, and it is what
    estimate_contrast reports; with one c fitted both thresholds are that c (``.mean``)."""
    s = moving_texture(num_frames=1, seed=1, c=0.25)
    for pair in (False, True):
        c = estimate_c(s.frames[0], s.exposures[0], s.events, pair=pair)
        rep = estimate_contrast(s.frames[0], s.exposures[0], s.events, pair=pair)
        assert type(c) is Contrast and c == rep.c
        assert (c.pos == c.neg) is (not pair) and c.mean == 0.5 * (c.pos + c.neg)
