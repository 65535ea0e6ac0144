"""The saturation rule ("at or above SATURATION", recorded units) on every path that applies it after
a response transform: a value recorded at exactly 0.99 is saturated and the next float below is not,
in float32 and float64, with gamma 1, 0.75 and 2.2 (for gamma > 1 two neighbouring recorded values can
linearise to one irradiance, so a rule applied after the transform misclassed the one below)."""

from __future__ import annotations

import numpy as np
import pytest

from edi import SATURATION, deblur_with_report, moving_texture
from edi.contrast import _check_estimate_inputs
from edi.model import linearize, linearize_saturated

GAMMAS = [1.0, 0.75, 2.2]
DTYPES = [np.float32, np.float64]


def _edge(dtype) -> tuple[float, float]:
    """0.99 and the next float below it, as recorded in ``dtype``."""
    at = dtype(SATURATION)
    return float(at), float(np.nextafter(at, dtype(0)))


@pytest.fixture(scope="module")
def seq1():
    return moving_texture(num_frames=1, seed=0, c=0.2)


def test_the_old_rule_after_the_transform_misclassed_the_value_below():
    # why the rule must be applied to the recorded value: with gamma 2.2 the float below 0.99 lands on the level
    below = np.nextafter(SATURATION, 0.0)
    assert linearize(np.array([below]), 2.2)[0] >= linearize(np.float64(SATURATION), 2.2)


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_linearize_saturated_keeps_the_rule_on_the_recorded_values(gamma, dtype):
    at, below = _edge(dtype)
    rec = np.array([0.5, below, at, 1.0], dtype=dtype)
    lin, t = linearize_saturated(rec, gamma)
    assert (lin >= t).tolist() == [False, False, True, True]
    np.testing.assert_allclose(lin, linearize(rec, gamma), rtol=1e-6)  # moved by an ulp at most


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_deblur_reports_exactly_the_pixels_recorded_at_or_above_0_99(seq1, gamma, dtype):
    at, below = _edge(dtype)
    B, ex = seq1.frames[0].astype(dtype), seq1.exposures[0]
    B[3, 4], B[6, 2] = at, below
    out, rep = deblur_with_report(B, ex, seq1.events, c=0.2, gamma=gamma)
    assert rep.saturated[3, 4] and not rep.saturated[6, 2]
    assert rep.saturated.sum() == 1
    assert out[3, 4, 0] == pytest.approx(at, abs=1e-12)  # kept as recorded (gamma round trip)


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_deblur_with_a_cfa_reports_exactly_the_pixels_recorded_at_or_above_0_99(seq1, gamma, dtype):
    at, below = _edge(dtype)
    B = np.repeat(seq1.frames[0].astype(dtype), 3, axis=-1)
    B[3, 4, 1], B[6, 2] = at, below  # one channel of three at the level; a pixel just below in all
    _, rep = deblur_with_report(B, seq1.exposures[0], seq1.events, c=0.2, gamma=gamma, cfa="RGGB")
    assert rep.saturated[3, 4] and not rep.saturated[6, 2]
    assert rep.saturated.sum() == 1


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_the_contrast_estimate_classes_the_edge_on_the_recorded_values(seq1, gamma, dtype):
    at, below = _edge(dtype)
    fr = seq1.frames.astype(dtype)
    fr[0, 3, 4], fr[0, 6, 2] = at, below
    lin, *_ = _check_estimate_inputs(fr, seq1.exposures, seq1.events, "auto", "flow", (0.01, 1.0), gamma)
    assert lin[0, 3, 4, 0] >= SATURATION and lin[0, 6, 2, 0] < SATURATION
    assert ((lin >= SATURATION) == (fr >= SATURATION)).all()  # every pixel as recorded


@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("dtype", DTYPES)
def test_the_cli_medi_path_classes_the_edge_on_the_recorded_values(seq1, gamma, dtype, monkeypatch):
    import edi
    from ebad.cli import deblur as cli_deblur

    at, below = _edge(dtype)
    fr = seq1.frames.astype(dtype)
    fr[0, 3, 4], fr[0, 6, 2] = at, below
    seen = {}

    def fake_medi(lin, exposures, events, c, saturation, cfa):
        seen["sat"] = np.asarray(lin) >= saturation
        return np.asarray(lin)

    monkeypatch.setattr(edi, "medi", fake_medi)
    cli_deblur._medi(fr, seq1.exposures, seq1.events, 0.2, gamma, None)
    np.testing.assert_array_equal(seen["sat"], fr >= SATURATION)
