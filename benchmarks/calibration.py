"""Contrast-threshold calibration: estimated against true c across generators, seeds and sensors.

    python -m benchmarks.calibration [--quick] [--seeds N] [--cache DIR]

Generators (the truth is read only by this benchmark, never passed to the estimators):

* ``texture``: ``edi.moving_texture`` (4 frames, c in {0.15, 0.2, 0.3} by seed, per-pixel
  mismatch sigma_c 0.03).
* ``boxes_grey_strong`` / ``boxes_grey_weak`` / ``spheres_rgb_strong`` / ``spheres_rgb_weak``:
  ray-cast scenes of ``scenes.make_scene`` ("small", 160x120, 3 frames, c 0.2, sigma_c 0.03;
  shake 1.0 and 0.5).
* ``realistic``: boxes, grey, shake 1.0 with the sensor this benchmark simulates itself
  (``scenes.simulate_events`` has one c for both polarities): per-pixel C+ ~ N(0.18, 0.03),
  C- ~ N(0.24, 0.03), shot noise 2 Hz per pixel, 5 hot pixels at 500 Hz, and APS frames
  through a gamma of 0.8 (a non-linear response); ``realistic_linear`` is the same sensor
  with linear frames, to tell the effect of the response from the rest.

Rows: for each generator and estimator, |c_est / c_true - 1| per seed (c_true the mean of
the per-pixel thresholds, per polarity for pairs), how many seeds are within 10% (single
frame) and 5% (multi-frame), and the deblurred frame's RMSE against the true sharp frame
with c_est and with the true mean pair. Then the street recording (multi-frame estimate
against a scan of fixed c, next-frame prediction gain in dB) and the six ni_joint frames
(single-frame estimate, whether it is at a bracket end, and a no-reference sharpness/noise
measure of the deblurred frame against the blurry one).
"""
from __future__ import annotations

import argparse
import math
import pickle
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import edi
from edi import LOG_EPS, Contrast

from ._common import seed_all, write_json

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NI_NAMES = ["keyboard", "toy", "text_cambridge", "badminton", "night_run", "low_light_model1"]

#: the realistic sensor (see the module docstring)
REAL_C_POS, REAL_C_NEG, REAL_SIGMA_C = 0.18, 0.24, 0.03
REAL_NOISE_HZ, REAL_HOT_PIXELS, REAL_HOT_HZ = 2.0, 5, 500.0
REAL_GAMMA = 0.8


@dataclass
class Case:
    """One synthetic capture and its truth (kept apart: estimators get frames/exposures/events)."""

    generator: str
    seed: int
    frames: np.ndarray  # [F, H, W, D] float64 in [0, 1]
    exposures: np.ndarray  # [F, 2] seconds
    events: edi.EventStream
    c_true: Contrast  # mean of the per-pixel thresholds, per polarity
    sharp: np.ndarray  # [F, H, W, D] true sharp frames at mid-exposure


def texture_case(seed: int) -> Case:
    c = (0.15, 0.2, 0.3)[seed % 3]
    s = edi.moving_texture(num_frames=4, seed=seed, c=c, sigma_c=0.03)
    sharp = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    return Case("texture", seed, s.frames, s.exposures, s.events, Contrast(c, c), sharp)


def scene_case(name: str, rgb: bool, shake: float, seed: int, generator: str) -> Case:
    from scenes import make_scene

    sc = make_scene(name, "small", seed=seed, rgb=rgb, c=0.2, sigma_c=0.03, shake=shake, n_frames=3, n_test=0)
    cap = sc.capture
    c_true = Contrast(float(sc.c_pos.mean()), float(sc.c_neg.mean()))
    return Case(generator, seed, np.asarray(cap.frames, np.float64), np.asarray(cap.exposures), cap.events,
                c_true, np.asarray(sc.gt_frames, np.float64))


def realistic_case(seed: int, gamma: float = REAL_GAMMA, generator: str = "realistic") -> Case:
    """boxes, grey: our own asymmetric noisy sensor on the scene's renders; ``gamma`` on the frames."""
    from scenes import make_scene
    from scenes.simulate import MIN_C_FRACTION, _crossings_numba

    sc = make_scene("boxes", "small", seed=seed, rgb=False, c=0.2, sigma_c=0.03, shake=1.0, n_frames=3, n_test=0)
    cap = sc.capture
    ex = np.asarray(cap.exposures)
    n_blur = int(cap.meta["n_blur"])
    dt = (ex[0, 1] - ex[0, 0]) / n_blur
    t_end = ex[-1, 1] + 0.02
    grid = np.arange(int(round(t_end / dt)) + 1) * dt
    renders = sc.render(sc.c2w_at(grid))[..., 0].astype(np.float64)  # [S, H, W]
    S, H, W = renders.shape
    rng = np.random.default_rng(10_000 + seed)
    c_pos = np.maximum(REAL_C_POS + REAL_SIGMA_C * rng.standard_normal(H * W), MIN_C_FRACTION * REAL_C_POS)
    c_neg = np.maximum(REAL_C_NEG + REAL_SIGMA_C * rng.standard_normal(H * W), MIN_C_FRACTION * REAL_C_NEG)
    logi = np.ascontiguousarray(np.log(renders.reshape(S, -1) + LOG_EPS))
    te, pix, pol = _crossings_numba(logi, grid, c_pos, c_neg, 0.0)
    ts, pxs, ps = [te], [pix], [pol]
    span = float(grid[-1] - grid[0])
    n = rng.poisson(REAL_NOISE_HZ * span, H * W)
    ts.append(span * rng.random(n.sum()))
    pxs.append(np.repeat(np.arange(H * W), n))
    ps.append(np.where(rng.random(n.sum()) < 0.5, 1, -1).astype(np.int8))
    for p in rng.choice(H * W, REAL_HOT_PIXELS, replace=False):
        k = int(REAL_HOT_HZ * span)
        ts.append(np.sort(span * rng.random(k)))
        pxs.append(np.full(k, p))
        ps.append(np.ones(k, np.int8))
    t_us = edi.seconds_to_us(np.concatenate(ts))
    pix = np.concatenate(pxs)
    order = np.argsort(t_us, kind="stable")
    ev = edi.EventStream(t_us[order], pix[order] % W, pix[order] // W, np.concatenate(ps)[order], W, H)
    frames = np.asarray(cap.frames, np.float64) ** gamma
    sharp = np.asarray(sc.gt_frames, np.float64)
    return Case(generator, seed, frames, ex, ev, Contrast(float(c_pos.mean()), float(c_neg.mean())), sharp)


GENERATORS = {
    "texture": texture_case,
    "boxes_grey_strong": lambda s: scene_case("boxes", False, 1.0, s, "boxes_grey_strong"),
    "boxes_grey_weak": lambda s: scene_case("boxes", False, 0.5, s, "boxes_grey_weak"),
    "spheres_rgb_strong": lambda s: scene_case("spheres", True, 1.0, s, "spheres_rgb_strong"),
    "spheres_rgb_weak": lambda s: scene_case("spheres", True, 0.5, s, "spheres_rgb_weak"),
    "realistic": realistic_case,
    "realistic_linear": lambda s: realistic_case(s, 1.0, "realistic_linear"),
}


def load_case(generator: str, seed: int, cache: Path | None) -> Case:
    if cache is not None:
        f = cache / f"{generator}_{seed}.pkl"
        if f.exists():
            with open(f, "rb") as fh:
                return pickle.load(fh)
    case = GENERATORS[generator](seed)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        with open(f, "wb") as fh:
            pickle.dump(case, fh)
    return case


# --- the street recording: next-frame prediction ----------------------------------------------------


def street_gain(frames: np.ndarray, exposures: np.ndarray, events: edi.EventStream, c) -> float:
    """dB gained by predicting frame k+1 from frame k and the events between the centres
    (log(F_k + eps) + c_pos N+ - c_neg N-, clipped to [0, 1]) over holding frame k, pooled
    over the pixels that fired and are saturated in neither frame."""
    cc = edi.parse_c(c)
    centres = exposures.mean(axis=1)
    se_pred = se_hold = 0.0
    n = 0
    for k in range(len(frames) - 1):
        i0, i1 = edi.events_in_window(events, centres[k], centres[k + 1])
        win = events[i0:i1]
        n_pos, n_neg = win.count_image(1), win.count_image(-1)
        ok = ((n_pos + n_neg) > 0) & (frames[k] < edi.SATURATION) & (frames[k + 1] < edi.SATURATION)
        if not ok.any():
            continue
        pred = np.clip(np.exp(np.log(frames[k] + LOG_EPS) + cc.pos * n_pos - cc.neg * n_neg) - LOG_EPS, 0.0, 1.0)
        se_pred += float(((pred - frames[k + 1])[ok] ** 2).sum())
        se_hold += float(((frames[k] - frames[k + 1])[ok] ** 2).sum())
        n += int(ok.sum())
    return 10.0 * math.log10(se_hold / se_pred)
