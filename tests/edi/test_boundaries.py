"""Documented rules at their exact boundaries: saturation "at or above SATURATION" at 0.99 itself,
and the ``sensor_size`` key of an event file, which is (H, W)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from edi import SATURATION, EventError, deblur, deblur_with_report, moving_texture, read_events
from edi.model import latent_from_ratio


@pytest.fixture(scope="module")
def seq1():
    return moving_texture(num_frames=1, seed=0, c=0.2)


def test_saturation_is_0_99():
    assert SATURATION == 0.99  # the value the docstrings and the tests below state


def test_latent_from_ratio_keeps_pixels_at_exactly_the_saturation_level():
    b = np.full((2, 3, 3), 0.5)
    b[0, 0] = SATURATION  # every channel exactly at the level
    b[0, 1, 2] = SATURATION  # one channel of three at it
    b[1, 0] = np.nextafter(SATURATION, 0.0)  # just below, in every channel
    r = np.full((1, 2, 3), -0.3)  # a darkening latent everywhere
    lat, sat = latent_from_ratio(b, r)
    assert sat.tolist() == [[True, True, False], [False, False, False]]
    np.testing.assert_array_equal(lat[0, 0, 0], b[0, 0])
    np.testing.assert_array_equal(lat[0, 0, 1], b[0, 1])
    assert (lat[0, 1, 0] < b[1, 0]).all()  # just below the level: deblurred like any other pixel


@pytest.mark.parametrize("gamma", [1.0, 0.5, 2.2])
def test_deblur_keeps_and_reports_a_pixel_recorded_at_exactly_0_99_whatever_gamma(seq1, gamma):
    B, ex = seq1.frames[0].astype(np.float64), seq1.exposures[0]
    B[3, 4] = 0.99
    B[6, 2] = np.nextafter(0.99, 0.0)  # one ulp below (linearised by 1 / 2.2 it reaches the level: the rule is on B)
    out, rep = deblur_with_report(B, ex, seq1.events, c=0.2, gamma=gamma)
    assert rep.saturated[3, 4] and out[3, 4, 0] == pytest.approx(0.99, abs=1e-12)  # gamma round trip
    assert not rep.saturated[6, 2]
    assert rep.saturated.sum() == 1


def _events(tmp_path, name, **extra):
    t = np.array([10, 20, 35, 50], dtype=np.int64)
    x, y, p = np.array([0, 6, 1, 2]), np.array([1, 0, 3, 2]), np.array([1, 0, 0, 1])
    path = tmp_path / name
    if name.endswith(".npz"):
        np.savez(path, t=t, x=x, y=y, p=p, **extra)
    else:
        with h5py.File(path, "w") as f:
            for k, v in dict(t=t, x=x, y=y, p=p, **extra).items():
                f[k] = v
    return path


@pytest.mark.parametrize("name", ["e.npz", "e.h5"])
def test_sensor_size_is_height_then_width(tmp_path, name):
    path = _events(tmp_path, name, sensor_size=np.array([5, 8]))  # H 5, W 8 (E-NeRF, tonic)
    ev = read_events(path, t_unit="us")
    assert (ev.width, ev.height) == (8, 5)
    assert read_events(path, t_unit="us", width=8, height=5).width == 8
    with pytest.raises(EventError, match="declares a 8x5 \\(WxH\\) sensor but 5x8 was given"):
        read_events(path, t_unit="us", width=5, height=8)
    # a three-element (H, W, 2) sensor size as tonic writes it reads the same
    ev3 = read_events(_events(tmp_path, "3" + name, sensor_size=np.array([5, 8, 2])), t_unit="us")
    assert (ev3.width, ev3.height) == (8, 5)


def test_rounding_just_outside_the_unit_range_reads_as_the_bound_itself(seq1):
    """A frame value within RANGE_TOL outside [0, 1] is that bound: the latent is the one of the
    clipped frame, pixel for pixel (1 + 1e-7 is saturated and stays exactly 1)."""
    B = seq1.frames[0].astype(np.float64)
    B[0, 0], B[0, 1], B[2, 3] = 1.0 + 1e-7, -1e-7, 1.0
    ex = seq1.exposures[0]
    L, rep = deblur_with_report(B, ex, seq1.events, c=0.2)
    want = deblur(np.clip(B, 0.0, 1.0), ex, seq1.events, c=0.2)
    np.testing.assert_array_equal(L, want)
    assert L[0, 0, 0] == 1.0 and L[2, 3, 0] == 1.0 and rep.saturated[0, 0] and rep.saturated[2, 3]
    zero = B.copy()
    zero[0, 1] = 0.0
    assert L[0, 1, 0] == deblur(zero, ex, seq1.events, c=0.2)[0, 1, 0]
