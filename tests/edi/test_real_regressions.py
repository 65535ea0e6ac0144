"""Real-data behaviour pinned (issue 32): the street's several-frame contrast estimate and how well
it predicts the next frame, and the ni_joint frames' reliability flags. Skipped with a reason when
../shared/data is absent.

The frame-prediction yardstick here is written out with numpy on the raw event arrays and calls
nothing of ``edi.contrast``: frame k+1 predicted as frame k times exp(c (N+ - N-)), with the
counts N between the two exposure centres, clipped to the sensor's range [0, 1], scored over the
pixels that fired, against holding frame k. It reads c low (the c that predicts best is not the
threshold: counts of one or two events miss up to a threshold of the change), and the estimator
reads it high where frames are sharp and events sparse (a pixel with no later event counts with
a residual of 0), both measured on a synthetic street-like sequence of known c below; so the pins
are windows around what the estimator and the yardstick give now (docs/results.md, issue 32).
"""

from pathlib import Path

import numpy as np
import pytest

import edi

SHARED = Path(__file__).parents[2].parent / "shared" / "data"
STREET = SHARED / "davis346_street" / "davis346_street.aedat4"
NI = SHARED / "ni_joint_blur"
needs_street = pytest.mark.skipif(not STREET.exists(), reason=f"real data not found: {STREET}")
needs_ni = pytest.mark.skipif(not NI.exists(), reason=f"real data not found: {NI}")

#: the yardstick's log offset: log(F + EPS), as a dark pixel needs (the project's LOG_EPS)
EPS = 1e-3
#: the street frames of issue 32 (frames 5 to 50, the last one out, as the issue measured)
STREET_FRAMES = slice(5, 50)
#: the several-frame estimate on them, a window around 0.3923 (since 5944fe7; 0.4096-0.4106 from
#: 19491e3 to ee2417d, 0.5323 at 4496104, 0.3459 from the first estimator, f8976c6 to 52d1cd2, a
#: least squares of the log changes on c N like the yardstick's)
STREET_C = (0.385, 0.400)
#: the yardstick's gain at the estimate (dB over holding the frame): 6.92 at 0.3923, 7.36 at 0.346,
#: 6.70 at 0.4096; the best fixed c of the grid below (0.31) gains 7.47
STREET_GAIN_DB = (6.85, 7.00)
#: fixed c tried for the best-predicting one
GRID = np.round(np.arange(0.20, 0.50, 0.01), 3)


def prediction_gain(frames: np.ndarray, exposures: np.ndarray, events, c: float) -> float:
    """dB gained by predicting frame k+1 from frame k and the events between their exposure
    centres over holding frame k, pooled over the pixels that fired.

    frames [F, H, W] linear in [0, 1]; exposures [F, 2] seconds; events an ``edi.EventStream``
    (only its t, x, y, p arrays are read). An event at t (us) is between the centres a, b when
    round(a * 1e6) <= t < round(b * 1e6)."""
    t, x, y, p = events.t, events.x.astype(np.int64), events.y.astype(np.int64), events.p
    H, W = frames.shape[1:]
    bounds = np.searchsorted(t, np.rint(exposures.mean(axis=1) * 1e6).astype(np.int64))
    se_pred = se_hold = 0.0
    for k in range(len(frames) - 1):
        sel = slice(bounds[k], bounds[k + 1])
        pix = y[sel] * W + x[sel]
        signed = np.bincount(pix, weights=np.sign(p[sel]).astype(np.float64), minlength=H * W).reshape(H, W)
        fired = np.bincount(pix, minlength=H * W).reshape(H, W) > 0
        a, b = frames[k], frames[k + 1]
        pred = np.clip((a + EPS) * np.exp(c * signed) - EPS, 0.0, 1.0)
        se_pred += float(((pred - b)[fired] ** 2).sum())
        se_hold += float(((a - b)[fired] ** 2).sum())
    return 10.0 * np.log10(se_hold / se_pred)


@pytest.fixture(scope="module")
def street():
    rec = edi.read_aedat4(STREET)
    return rec.frames[STREET_FRAMES, ..., 0].astype(np.float64), rec.exposures[STREET_FRAMES], rec.events


@pytest.fixture(scope="module")
def street_estimate(street):
    fr, ex, ev = street
    rep = edi.estimate_contrast(fr, ex, ev)
    return rep.c.mean, rep


@needs_street
def test_street_estimate_is_pinned(street_estimate):
    c, rep = street_estimate
    assert rep.method == "consistency" and rep.reliable and not rep.at_bound
    assert STREET_C[0] < c < STREET_C[1], c


@needs_street
def test_street_estimate_prediction_gain_is_pinned(street, street_estimate):
    fr, ex, ev = street
    c = street_estimate[0]
    gain = prediction_gain(fr, ex, ev, c)
    assert STREET_GAIN_DB[0] < gain < STREET_GAIN_DB[1], (c, gain)
    gains = [prediction_gain(fr, ex, ev, float(g)) for g in GRID]
    best = float(GRID[int(np.argmax(gains))])
    # the yardstick's own optimum, below the estimate (it reads c low): 0.55 dB more than the estimate
    assert 0.28 <= best <= 0.33 and best < c, (best, max(gains))
    assert 0.4 < max(gains) - gain < 0.7, (c, gain, best, max(gains))


def _street_like(seed: int, c: float):
    """A sharp-frame sequence like the street's: 0.5 ms exposures 40 ms apart, slow motion, most
    pixels firing once or twice between frames, per-pixel thresholds around c."""
    from edi.moving_texture import moving_texture

    return moving_texture(
        height=40,
        width=56,
        num_frames=8,
        exposure=0.0005,
        period=0.04,
        velocity=(20.0, 6.0),
        c=c,
        sigma_c=0.05,
        seed=seed,
        lead=0.1,
        step_us=100,
    )


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_street_like_sequence_the_estimate_reads_high_and_the_yardstick_low(seed):
    """On a street-like sequence of known c (0.35) the estimator reads 1.07x (measured 0.3755 and
    0.3760 for seeds 0 and 1: a pixel with no event after a frame counts with a residual of 0, where
    its intensity went on by up to c; with the simulator's true residual it reads 0.350), and the
    c that predicts the next frame best with the yardstick above is 0.8-0.9x the truth: the street's
    0.392 is likely high by as much, and its true c between the yardstick's 0.31 and 0.392."""
    s = _street_like(seed, 0.35)
    fr = s.frames[..., 0]
    c = edi.estimate_c(fr, s.exposures, s.events).mean
    assert 1.04 < c / 0.35 < 1.10, c
    gains = [prediction_gain(fr, s.exposures, s.events, float(g)) for g in GRID]
    best = float(GRID[int(np.argmax(gains))])
    assert 0.25 <= best <= 0.33, best
    assert prediction_gain(fr, s.exposures, s.events, c) < max(gains)


# --- ni_joint: the single-frame estimate's reliability flags ------------------------------------

#: per frame: where the flow estimate sits ("low", "top" end of the bracket or "interior") and the
#: share of the events' changes its fit explains (measured, benchmarks/results/calibration.json)
NI_FLAGS = {
    "keyboard": ("low", 0.082),
    "toy": ("low", 0.077),
    "text_cambridge": ("low", 0.026),
    "badminton": ("interior", 0.203),
    "night_run": ("interior", 0.089),
    "low_light_model1": ("top", 0.267),
}


def _read_ni(name):
    from skimage import io

    png = NI / (name.rstrip("12") + ".png" if name.startswith("low_light") else name + ".png")
    B = io.imread(png)
    ev = edi.read_events(NI / f"{name}.mat", width=B.shape[1], height=B.shape[0])
    return B, ev, (ev.t[0] * 1e-6, (ev.t[-1] + 1) * 1e-6)  # no exposure stored: the span of the events


@needs_ni
@pytest.mark.parametrize("name", sorted(NI_FLAGS))
def test_ni_joint_reliability_flags_are_pinned(name):
    """Every ni_joint frame is flagged unreliable (its fit explains less than
    edi.contrast.FLOW_MIN_EXPLAINED), at the bracket end or inside it as measured, and how much
    its fit explains stays within 0.02 of the measured share."""
    where, explained = NI_FLAGS[name]
    B, ev, ex = _read_ni(name)
    rep = edi.estimate_contrast(B, ex, ev)
    c = rep.c.mean
    assert rep.method == "single" and rep.energy_name == "flow"
    assert rep.reliable is False and rep.at_bound == (where != "interior"), (c, rep.at_bound)
    lo, hi = rep.bracket
    if where == "low":
        assert c < lo * 1.02
    elif where == "top":
        assert c > hi / 1.02
    else:
        assert lo * 1.02 < c < hi / 1.02
    assert abs(rep.explained - explained) < 0.02, rep.explained
    assert rep.explained < edi.contrast.FLOW_MIN_EXPLAINED
    assert "unreliable" in rep.message and "--c" in rep.message
