"""Sharpness from events that carry structure (issue 31): a still camera's noise events do not make it blurry."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from ebad.config import preset
from ebad.data import prepare, sharp_views, structured_events_per_pixel
from ebad.virtual_views import events_per_pixel
from edi import EventStream


@pytest.fixture(scope="module")
def still_and_moving():
    still = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1, shake=0.0, tremor=0.0)
    moving = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    return still.capture, moving.capture


def test_a_still_realistic_camera_is_sharp_and_a_moving_one_blurry(still_and_moving):
    still, moving = still_and_moving
    ex = np.asarray(still.exposures)
    raw = events_per_pixel(still.events, ex)
    assert (raw > 0.05).all()  # the realistic sensor's noise alone: "blurry" under the raw count
    s = structured_events_per_pixel(still.events, ex)
    assert (s < 0.02).all(), s  # measured 0.005-0.009 (tiny, seed 0)
    V, structured, why = sharp_views(ex, still.events, 5, True, 0.05)
    assert V.tolist() == [1, 1, 1, 1] and structured == [round(float(v), 4) for v in s]
    assert why.startswith("4 of 4 frames sharp: 4 with fewer than 0.05 structured events per pixel")
    mx = np.asarray(moving.exposures)
    Vm, sm, why_m = sharp_views(mx, moving.events, 5, True, 0.05)
    assert Vm.tolist() == [5, 5, 5, 5] and min(sm) > 1.0 and why_m == "0 of 4 frames sharp"  # type: ignore[type-var]


def test_isolated_events_are_noise_and_neighbours_within_the_window_support():
    # pixel (1, 1) at 0 and its neighbour (2, 2) at 4 ms: both supported; (8, 8) alone; (5, 5) with (5, 6) 6 ms later
    ev = EventStream([0, 1000, 4000, 5000, 11000], [1, 8, 2, 5, 5], [1, 8, 2, 5, 6], [1, 1, -1, 1, 1], 10, 10)
    s = structured_events_per_pixel(ev, np.array([[0.0, 0.02]]))
    assert s.tolist() == [2 / 100]
    assert structured_events_per_pixel(ev, np.array([[0.0, 0.02]]), support_us=6000).tolist() == [4 / 100]


def test_the_report_says_how_many_frames_are_sharp_and_why(still_and_moving):
    cfg = preset("ebad")
    cfg.loss.contrast = (0.2, 0.2)
    cfg.loss.w_edi, cfg.loss.target = 0.0, "blurry"
    d = prepare(still_and_moving[0], cfg)
    assert d.V.tolist() == [1, 1, 1, 1] and d.report.sharp_frames == 4
    assert d.report.sharp_reason is not None and "structured events per pixel" in d.report.sharp_reason
    assert d.report.structured_events_per_pixel is not None and max(d.report.structured_events_per_pixel) < 0.02
