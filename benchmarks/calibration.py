"""Contrast-threshold calibration: estimated against true c across generators, seeds and sensors.

    python -m benchmarks.calibration [--quick] [--seeds N] [--cache DIR]

Generators (the truth is read only by this benchmark, never passed to the estimators):

* ``texture``: ``edi.moving_texture`` (4 frames, c in {0.15, 0.2, 0.3} by seed, per-pixel
  mismatch sigma_c 0.03), the sensor running 0.1 s before the first exposure as a camera
  does; ``texture_no_lead`` starts the sensor at the first exposure (every pixel a whole
  threshold from firing: the first frame, the one the single-frame rows use, gets too few
  events); ``texture_uniform`` is ``texture`` with every pixel's threshold exactly c (no
  mismatch), to tell the single-frame energy's own bias from the mismatch's.
* ``boxes_grey_strong`` / ``boxes_grey_weak`` / ``spheres_rgb_strong`` / ``spheres_rgb_weak``:
  ray-cast scenes of ``scenes.make_scene`` ("small", 160x120, 3 frames, c 0.2, sigma_c 0.03;
  shake 1.0 and 0.5).
* ``realistic``: boxes, grey, shake 1.0 with the sensor this benchmark simulates itself
  (``scenes.simulate_events`` has one c for both polarities): per-pixel C+ ~ N(0.18, 0.03),
  C- ~ N(0.24, 0.03), shot noise 2 Hz per pixel, 5 hot pixels at 500 Hz, and APS frames
  through a gamma of 0.8 (a non-linear response); ``realistic_linear`` is the same sensor
  with linear frames, to tell the effect of the response from the rest.

Rows: for each generator and estimator, c_est / c_true over the seeds (median, min, max;
c_true the mean of the per-pixel thresholds, per polarity for pairs, and the mean of the two
for one c), how many seeds are within 10% (single frame) and 5% (multi-frame) in the worse
polarity, how many estimates sit at a bracket end, how many are reported unreliable (at a bracket
end, or a flow fit explaining less than ``edi.contrast.FLOW_MIN_EXPLAINED`` of the events' changes)
and the least share the flow fit explained, and the PSNR of ``edi.deblur`` over all
frames with the joint pair estimate (what ``ebad deblur CAPTURE`` does) minus the PSNR with
the true mean pair and the true response (both scored against the sharp frames as the
camera records them). Then the next-frame yardstick on synthetic sharp frames whose c is
known, with the errors-in-variables bracket (forward and reverse least squares of the log
change on the counts) that shows why its best fixed c is low; the realistic generator with
its frames linearised by a range of gamma (only gamma x c is seen); the street recording
(multi-frame estimate against a scan of fixed c and against the bracket for frame gaps 1, 2,
4); and the six ni_joint frames (single-frame estimate, also with the frames linearised by
gamma 0.45 and 2.2, whether it is at a bracket end, and a no-reference sharpness/noise
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
    sharp: np.ndarray  # [F, H, W, D] true sharp frames at mid-exposure (irradiance, linear)
    gamma: float = 1.0  # the frames' response, recorded = irradiance ** gamma


#: seconds the texture's sensor runs before its first exposure (two frame periods; see edi.moving_texture)
TEXTURE_LEAD = 0.1


def texture_case(seed: int, lead: float = TEXTURE_LEAD, generator: str = "texture", sigma_c: float = 0.03) -> Case:
    c = (0.15, 0.2, 0.3)[seed % 3]
    s = edi.moving_texture(num_frames=4, seed=seed, c=c, sigma_c=sigma_c, lead=lead)
    sharp = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    return Case(generator, seed, s.frames, s.exposures, s.events, Contrast(c, c), sharp)


def scene_case(name: str, rgb: bool, shake: float, seed: int, generator: str) -> Case:
    from scenes import make_scene

    sc = make_scene(
        name, "small", seed=seed, rgb=rgb, sensor="ideal", c=0.2, sigma_c=0.03, shake=shake, n_frames=3, n_test=0
    )
    cap = sc.capture
    c_true = Contrast(float(sc.c_pos.mean()), float(sc.c_neg.mean()))
    return Case(
        generator,
        seed,
        np.asarray(cap.frames, np.float64),
        np.asarray(cap.exposures),
        cap.events,
        c_true,
        np.asarray(sc.gt_frames, np.float64),
    )


def realistic_case(seed: int, gamma: float = REAL_GAMMA, generator: str = "realistic") -> Case:
    """boxes, grey: our own asymmetric noisy sensor on the scene's renders; ``gamma`` on the frames."""
    from scenes import make_scene
    from scenes.simulate import MIN_C_FRACTION, _crossings_numba

    sc = make_scene(
        "boxes", "small", seed=seed, rgb=False, sensor="ideal", c=0.2, sigma_c=0.03, shake=1.0, n_frames=3, n_test=0
    )
    cap = sc.capture
    ex = np.asarray(cap.exposures)
    n_blur = int(sc.truth["n_blur"])  # the generator's own setting (benchmark side)
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
    return Case(generator, seed, frames, ex, ev, Contrast(float(c_pos.mean()), float(c_neg.mean())), sharp, gamma)


GENERATORS = {
    "texture": texture_case,
    "texture_no_lead": lambda s: texture_case(s, 0.0, "texture_no_lead"),
    "texture_uniform": lambda s: texture_case(s, TEXTURE_LEAD, "texture_uniform", sigma_c=0.0),
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


#: regression bounds: pixels darker than this in either frame are left out (log(F + eps) is noise there)
DARK = 0.02


def regression_bounds(frames: np.ndarray, exposures: np.ndarray, events: edi.EventStream, gap: int = 1) -> dict:
    """The errors-in-variables bracket of c from frames k and k + gap (grey [F, H, W]) and the
    signed counts N between their centres, over the pixels that fired, are neither saturated
    nor darker than ``DARK``: with D = log(F_{k+gap} + eps) - log(F_k + eps) = c N + errors in
    both (the counts are quantised and hold noise events; the frames hold noise), the forward
    least squares sum D N / sum N^2 (what the best fixed c of the prediction yardstick is, in
    log units) is biased towards 0 by the errors of N, and the reverse one sum D^2 / sum D N is
    biased away from 0 by the errors of D: c lies between them (Frisch)."""
    centres = exposures.mean(axis=1)
    xs, ys = [], []
    for k in range(len(frames) - gap):
        i0, i1 = edi.events_in_window(events, centres[k], centres[k + gap])
        win = events[i0:i1]
        n = win.count_image(1).astype(np.float64) - win.count_image(-1)
        ok = n != 0
        for f in (frames[k], frames[k + gap]):
            ok &= (f < edi.SATURATION) & (f > DARK)
        xs.append(n[ok])
        ys.append((np.log(frames[k + gap] + LOG_EPS) - np.log(frames[k] + LOG_EPS))[ok])
    x, y = np.concatenate(xs), np.concatenate(ys)
    return {
        "gap": gap,
        "forward": float((x * y).sum() / (x * x).sum()),
        "reverse": float((y * y).sum() / (x * y).sum()),
        "pixels": int(x.size),
        "fraction_one_event": float(np.mean(np.abs(x) == 1)),
    }


# --- the single-frame and multi-frame estimators on the synthetic generators ---------------------------


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return 10.0 * math.log10(1.0 / max(float(np.mean((np.asarray(a, np.float64) - b) ** 2)), 1e-12))


def deblur_psnr(case: Case, c, gamma: float = 1.0) -> float:
    """Mean PSNR (dB) of the mid-exposure EDI latents of every frame (frames linearised with
    ``gamma``, latents mapped back) against the true sharp frames as the camera records them
    (sharp ** the true gamma)."""
    return float(
        np.mean(
            [
                psnr(
                    edi.deblur(case.frames[i], case.exposures[i], case.events, c=c, gamma=gamma),
                    case.sharp[i] ** case.gamma,
                )
                for i in range(len(case.frames))
            ]
        )
    )


ESTIMATORS = {
    # name: (kwargs of estimate_c, uses all frames)
    "single_flow": (dict(method="single", energy="flow"), False),
    "single_flow_pair": (dict(method="single", energy="flow", pair=True), False),
    "single_paper": (dict(method="single", energy="paper"), False),
    "consistency": (dict(method="consistency"), True),
    "consistency_pair": (dict(method="consistency", pair=True), True),
}


def run_case(case: Case) -> dict:
    row = {"generator": case.generator, "seed": case.seed, "c_true": list(case.c_true)}
    for name, (kw, multi) in ESTIMATORS.items():
        t = time.perf_counter()
        frames, ex = (case.frames, case.exposures) if multi else (case.frames[0], case.exposures[0])
        rep = edi.estimate_contrast(frames, ex, case.events, **kw)
        # a pair against the true pair; one c against the true mean (c_pos + c_neg) / 2
        ratio = (
            [rep.c.pos / case.c_true.pos, rep.c.neg / case.c_true.neg]
            if kw.get("pair")
            else [rep.c.mean / case.c_true.mean]
        )
        row[name] = {
            "c": list(rep.c),
            "ratio": ratio,
            "at_bound": rep.at_bound,
            "reliable": rep.reliable,
            "explained": rep.explained,
            "method": rep.method,
            "seconds": time.perf_counter() - t,
        }
    # what `ebad deblur CAPTURE` does (the joint pair, frames taken as linear) against EDI with
    # the true mean pair and the true response, both scored in the camera's recorded units
    row["psnr_true_c"] = deblur_psnr(case, case.c_true, case.gamma)
    row["psnr_estimated_c"] = deblur_psnr(case, row["consistency_pair"]["c"])
    row["psnr_blurry"] = float(
        np.mean([psnr(case.frames[i], case.sharp[i] ** case.gamma) for i in range(len(case.frames))])
    )
    return row


def summarise(rows: list[dict]) -> list[dict]:
    out = []
    for gen in dict.fromkeys(r["generator"] for r in rows):
        rs = [r for r in rows if r["generator"] == gen]
        for name, (_, multi) in ESTIMATORS.items():
            err = np.array([max(abs(v - 1) for v in r[name]["ratio"]) for r in rs])  # worst polarity
            tol = 0.05 if multi else 0.10
            out.append(
                {
                    "generator": gen,
                    "estimator": name,
                    "seeds": len(rs),
                    "median_ratio": float(np.median([np.mean(r[name]["ratio"]) for r in rs])),
                    "min_ratio": float(min(min(r[name]["ratio"]) for r in rs)),
                    "max_ratio": float(max(max(r[name]["ratio"]) for r in rs)),
                    "tolerance": tol,
                    "within": int((err <= tol).sum()),
                    "at_bound": int(sum(r[name]["at_bound"] for r in rs)),
                    "unreliable": int(sum(not r[name]["reliable"] for r in rs)),
                    "min_explained": min(
                        (r[name]["explained"] for r in rs if r[name]["explained"] is not None), default=None
                    ),
                }
            )
        d = np.array([r["psnr_estimated_c"] - r["psnr_true_c"] for r in rs])
        out.append(
            {
                "generator": gen,
                "estimator": "deblur dB (estimated - true c, gamma)",
                "seeds": len(rs),
                "median_ratio": float(np.median(d)),
                "min_ratio": float(d.min()),
                "max_ratio": float(d.max()),
                "tolerance": 0.5,
                "within": int((d >= -0.5).sum()),
                "at_bound": 0,
                "unreliable": 0,
                "min_explained": None,
            }
        )
    return out


# --- real data ---------------------------------------------------------------------------------


def sharpness_and_noise(img: np.ndarray) -> tuple[float, float]:
    """No-reference measures: gradient energy of the 3x3 median (structure, not impulses) and
    the mean square of what the median removes (salt-and-pepper noise)."""
    from scipy import ndimage

    img = np.asarray(img, np.float64)
    med = ndimage.median_filter(img, 3)
    gy, gx = np.gradient(med)
    return float(np.mean(gx**2 + gy**2)), float(np.mean((img - med) ** 2))


def prediction_metric_check(cases: list[Case]) -> list[dict]:
    """The street's yardstick on captures whose c is known: the true sharp frames at the
    exposure centres (t_start == t_end) and their events. The fixed c that predicts the next
    frame best is well below the true c (the prediction error is least for a c shrunk towards
    holding the frame when counts are quantised and frames noisy), so a gain below the best
    fixed c's does not by itself mean a wrong estimate."""
    out = []
    grid = np.round(np.arange(0.06, 0.40, 0.01), 3)
    for case in cases:
        sharp = case.sharp.mean(axis=-1)
        mid = case.exposures.mean(axis=1)
        ex = np.stack([mid, mid], axis=1)
        gains = [street_gain(sharp, ex, case.events, float(c)) for c in grid]
        est = edi.estimate_c(sharp, ex, case.events).mean
        out.append(
            {
                "generator": case.generator,
                "seed": case.seed,
                "c_true": case.c_true.mean,
                "best_fixed_c": float(grid[int(np.argmax(gains))]),
                "best_gain_db": float(max(gains)),
                "estimate": est,
                "estimate_gain_db": street_gain(sharp, ex, case.events, est),
                "bounds": regression_bounds(sharp, ex, case.events),
            }
        )
    return out


def street_rows() -> dict:
    path = SHARED / "davis346_street" / "davis346_street.aedat4"
    if not path.exists():
        return {"skipped": f"not found: {path}"}
    rec = edi.read_aedat4(path)
    fr, ex, ev = rec.frames[..., 0].astype(np.float64), rec.exposures, rec.events
    out: dict = {"scan": {}}
    for c in np.round(np.arange(0.1, 0.81, 0.025), 3):
        out["scan"][float(c)] = street_gain(fr, ex, ev, float(c))
    best = max(out["scan"], key=out["scan"].get)
    out["best_fixed_c"], out["best_gain_db"] = best, out["scan"][best]
    for pair in (False, True):
        rep = edi.estimate_contrast(fr, ex, ev, pair=pair)
        key = "estimate_pair" if pair else "estimate"
        out[key] = {"c": list(rep.c), "gain_db": street_gain(fr, ex, ev, rep.c), "method": rep.method}
    out["bounds"] = [regression_bounds(fr, ex, ev, gap) for gap in STREET_GAPS]
    est = out["estimate"]["c"][0]
    out["estimate_within_bounds"] = bool(all(b["forward"] <= est <= b["reverse"] for b in out["bounds"]))
    return out


#: frame gaps of the street's regression bounds
STREET_GAPS = (1, 2, 4)
#: responses tried on the real ni_joint frames (recorded = irradiance ** gamma): sRGB-like and its inverse
NI_GAMMAS = (0.45, 2.2)
#: the realistic generator's frames linearised with each of these exponents (the flatness along gamma x c)
GAMMA_SCAN = (0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.25)


def gamma_scan(cases: list[Case]) -> list[dict]:
    """The consistency estimate (pair, mean reported) and its residual with the frames linearised
    by each gamma of ``GAMMA_SCAN``: flat along gamma x c = const means only gamma x c is seen."""
    out = []
    for case in cases:
        for g in GAMMA_SCAN:
            rep = edi.estimate_contrast(
                case.frames, case.exposures, case.events, method="consistency", pair=True, gamma=g
            )
            c = rep.c
            out.append(
                {
                    "generator": case.generator,
                    "seed": case.seed,
                    "gamma_true": case.gamma,
                    "gamma": g,
                    "c_mean": c.mean,
                    "c_true_mean": case.c_true.mean,
                    "gamma_times_c": g * c.mean,
                    "energy": rep.energy,
                }
            )
    return out


#: events_displacement: the grid (px over the window, x and y) of the global translations tried, and its refinement step
CMAX_GRID_X, CMAX_GRID_Y, CMAX_STEP, CMAX_FINE = 40, 20, 2.0, 0.5
#: frame_blur_against_events: blur lengths (px) and directions (degrees) tried
BLUR_LENGTHS = (1, 2, 4, 6, 8, 12, 16, 20, 24, 32, 40, 48, 64)
BLUR_ANGLES = tuple(range(0, 180, 15))
#: pixels of the image border left out of the blur fit
BLUR_MARGIN = 32


def _warped_count(ev: edi.EventStream, dx: float, dy: float) -> np.ndarray:
    """[H, W] events counted after moving each back along a global translation of (dx, dy) px over
    the window (to the window's middle), smoothed by 1 px: the image of warped events."""
    from scipy import ndimage

    t = (ev.t - ev.t[0]).astype(np.float64)
    u = (t - t.mean()) / max(float(t[-1]), 1.0)
    xi = np.round(ev.x - dx * u).astype(np.int64)
    yi = np.round(ev.y - dy * u).astype(np.int64)
    ok = (xi >= 0) & (xi < ev.width) & (yi >= 0) & (yi < ev.height)
    img = np.bincount(yi[ok] * ev.width + xi[ok], minlength=ev.width * ev.height).reshape(ev.height, ev.width)
    return ndimage.gaussian_filter(img.astype(np.float64), 1.0)


def events_displacement(ev: edi.EventStream) -> dict:
    """How far the scene moved during the events' window, from the events alone (contrast
    maximisation): the global translation (px over the window) whose warped-event image has the
    largest variance, and that variance over the unwarped one's (1: warping concentrates nothing)."""

    def var(d):
        return float(_warped_count(ev, *d).var())

    coarse = [
        (dx, dy)
        for dx in np.arange(-CMAX_GRID_X, CMAX_GRID_X + 1e-9, CMAX_STEP)
        for dy in np.arange(-CMAX_GRID_Y, CMAX_GRID_Y + 1e-9, CMAX_STEP)
    ]
    bx, by = max(coarse, key=var)
    fine = [
        (bx + a, by + b)
        for a in np.arange(-CMAX_STEP, CMAX_STEP + 1e-9, CMAX_FINE)
        for b in np.arange(-CMAX_STEP, CMAX_STEP + 1e-9, CMAX_FINE)
    ]
    best = max(fine, key=var)
    return {
        "dx": float(best[0]),
        "dy": float(best[1]),
        "px": float(math.hypot(*best)),
        "variance_gain": var(best) / var((0.0, 0.0)),
    }


def _line_kernel(length: float, angle_deg: float) -> np.ndarray:
    """A normalised straight blur kernel of ``length`` px along ``angle_deg`` (bilinear splats)."""
    th = math.radians(angle_deg)
    s = int(math.ceil(length)) + 3
    k = np.zeros((s, s))
    for u in np.linspace(-length / 2, length / 2, 4 * s + 1):
        x, y = s // 2 + u * math.cos(th), s // 2 + u * math.sin(th)
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        for ddx, ddy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= x0 + ddx < s and 0 <= y0 + ddy < s:
                k[y0 + ddy, x0 + ddx] += w
    return k / k.sum()


def frame_blur_against_events(B: np.ndarray, ev: edi.EventStream) -> dict:
    """The frame's blur measured against the events' own edge map: the smoothed |signed count| of
    the window draws the scene's edges as thick as the motion during the window; box-blurring it
    along a direction over l px and correlating with |grad log B| (normalised cross-correlation,
    away from the border) finds the (l, direction) that makes it look like the frame."""
    from scipy import ndimage
    from scipy.signal import fftconvolve

    H, W = B.shape[:2]
    b = np.log(np.asarray(B, np.float64).reshape(H, W, -1).mean(axis=-1) / 255.0 + LOG_EPS)
    gy, gx = np.gradient(ndimage.gaussian_filter(b, 1.0))
    frame_edges = np.hypot(gx, gy)
    cnt = np.abs(ev.count_image().astype(np.float64))
    ev_edges = ndimage.gaussian_filter(cnt, 1.0)
    m = np.zeros((H, W), bool)
    m[BLUR_MARGIN:-BLUR_MARGIN, BLUR_MARGIN:-BLUR_MARGIN] = True

    def ncc(a):
        x, y = a[m] - a[m].mean(), frame_edges[m] - frame_edges[m].mean()
        return float((x * y).sum() / math.sqrt((x * x).sum() * (y * y).sum()))

    fits = {
        (n, a): ncc(fftconvolve(ev_edges, _line_kernel(n, a), mode="same")) for n in BLUR_LENGTHS for a in BLUR_ANGLES
    }
    (length, a) = max(fits, key=fits.get)
    return {
        "length_px": float(length),
        "angle_deg": float(a),
        "ncc": fits[(length, a)],
        "ncc_unblurred": max(v for (ll, _), v in fits.items() if ll == BLUR_LENGTHS[0]),
    }


#: partial_window: fractions of the exposure whose events the estimator gets, and the seeds
PARTIAL_FRACTIONS = (1.0, 0.5, 0.25, 0.15)
PARTIAL_SEEDS = range(5)


def partial_window() -> list[dict]:
    """``moving_texture`` frame 0 (sensor running, mismatch 0.03) with only the events of a centred
    fraction of its exposure (the exposure passed whole): what the single-frame estimate does when
    the events do not cover the blur."""
    out = []
    for frac in PARTIAL_FRACTIONS:
        for seed in PARTIAL_SEEDS:
            c = (0.15, 0.2, 0.3)[seed % 3]
            s = edi.moving_texture(num_frames=1, seed=seed, c=c, sigma_c=0.03, lead=TEXTURE_LEAD)
            t0, t1 = s.exposures[0]
            mid, half = 0.5 * (t0 + t1), 0.5 * frac * (t1 - t0)
            i0, i1 = edi.events_in_window(s.events, mid - half, mid + half)
            rep = edi.estimate_contrast(s.frames[0], s.exposures[0], s.events[i0:i1])
            est = rep.c.mean
            out.append({"fraction": frac, "seed": seed, "ratio": est / c, "at_bound": rep.at_bound})
    return out


def ni_rows() -> list[dict]:
    from PIL import Image

    ni = SHARED / "ni_joint_blur"
    rows = []
    for name in NI_NAMES if ni.exists() else []:
        png = ni / (name.rstrip("12") + ".png" if name.startswith("low_light") else name + ".png")
        B = np.asarray(Image.open(png))
        ev = edi.read_events(ni / f"{name}.mat", width=B.shape[1], height=B.shape[0])
        ex = (ev.t[0] * 1e-6, (ev.t[-1] + 1) * 1e-6)
        s_b, n_b = sharpness_and_noise(B / 255.0)
        cnt = np.bincount(ev.y.astype(np.int64) * ev.width + ev.x, minlength=ev.width * ev.height)
        row = {
            "name": name,
            "window_ms": (ex[1] - ex[0]) * 1e3,
            "events": len(ev),
            "positive_fraction": float(np.mean(ev.p > 0)),
            "events_per_fired_pixel": float(cnt[cnt > 0].mean()),
            "max_events_per_pixel": int(cnt.max()),
            "events_motion": events_displacement(ev),
            "frame_blur": frame_blur_against_events(B, ev),
        }
        for energy in ("flow", "paper"):
            rep = edi.estimate_contrast(B, ex, ev, energy=energy)
            c = rep.c.mean
            s_l, n_l = sharpness_and_noise(edi.deblur(B, ex, ev, c=c))
            row[energy] = {
                "c": c,
                "at_bound": rep.at_bound,
                "reliable": rep.reliable,
                "explained": rep.explained,
                "sharpness_gain": s_l / s_b,
                "noise_gain": n_l / n_b,
                "evals": sorted(rep.evals),
            }
        for g in NI_GAMMAS:  # is a non-linear response why the estimate ends at the bracket?
            rep = edi.estimate_contrast(B, ex, ev, gamma=g)
            c = rep.c.mean
            s_l, n_l = sharpness_and_noise(edi.deblur(B, ex, ev, c=c, gamma=g))
            row[f"flow_gamma_{g:g}"] = {
                "c": c,
                "at_bound": rep.at_bound,
                "sharpness_gain": s_l / s_b,
                "noise_gain": n_l / n_b,
            }
        s_t, n_t = sharpness_and_noise(edi.deblur(B, ex, ev, c=edi.contrast.DEFAULT_BRACKET[1]))
        row["bracket_top"] = {"sharpness_gain": s_t / s_b, "noise_gain": n_t / n_b}
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> None:
    import logging

    logging.getLogger("edi.contrast").setLevel(logging.ERROR)  # at-bound estimates are in the table
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds per generator")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--cache", type=Path, default=None, help="keep the generated captures here (pickles)")
    args = ap.parse_args(argv)
    seed_all(0)
    seeds = range(3 if args.quick else args.seeds)
    t0 = time.perf_counter()
    rows = []
    for gen in GENERATORS:
        for seed in seeds:
            rows.append(run_case(load_case(gen, seed, args.cache)))
            print(f"{gen} seed {seed}: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    table = summarise(rows)
    print(
        f"\n{'generator':20s} {'estimator':32s} {'median':>7s} {'min':>6s} {'max':>6s} {'within':>8s} {'at_bound':>8s} "
        f"{'unreliable':>10s} {'min explained':>13s}"
    )
    for r in table:
        expl = "" if r["min_explained"] is None else f"{r['min_explained']:.3f}"
        print(
            f"{r['generator']:20s} {r['estimator']:32s} {r['median_ratio']:7.3f} {r['min_ratio']:6.3f} "
            f"{r['max_ratio']:6.3f} {r['within']:>3d}/{r['seeds']:<2d}{'':2s} {r['at_bound']:>8d} "
            f"{r['unreliable']:>10d} {expl:>13s}"
        )
    check = prediction_metric_check(
        [
            load_case(g, seed, args.cache)
            for g in ("boxes_grey_strong", "realistic_linear")
            for seed in range(2 if args.quick else 3)
        ]
    )
    print("\nnext-frame prediction on synthetic sharp frames (known c), and the regression bracket:")
    for r in check:
        b = r["bounds"]
        print(
            f"  {r['generator']:18s} seed {r['seed']}: true c {r['c_true']:.3f}, best fixed c {r['best_fixed_c']:.3f} "
            f"({r['best_gain_db']:.2f} dB), estimate {r['estimate']:.3f} ({r['estimate_gain_db']:.2f} dB); "
            f"forward {b['forward']:.3f}, reverse {b['reverse']:.3f}"
        )
    scan = gamma_scan([load_case("realistic", seed, args.cache) for seed in range(2 if args.quick else 3)])
    print("\nrealistic (gamma 0.8): consistency with the frames linearised by gamma (c mean, gamma x c, residual):")
    for r in scan:
        print(
            f"  seed {r['seed']} gamma {r['gamma']:.2f}: c {r['c_mean']:.4f} (true {r['c_true_mean']:.4f}), "
            f"gamma x c {r['gamma_times_c']:.4f}, residual {r['energy']:.5f}"
        )
    street = street_rows()
    if "scan" in street:
        print(
            f"\nstreet: best fixed c {street['best_fixed_c']} gains {street['best_gain_db']:.2f} dB; "
            f"estimate {street['estimate']['c'][0]:.3f} gains {street['estimate']['gain_db']:.2f} dB; pair "
            f"({street['estimate_pair']['c'][0]:.3f}, {street['estimate_pair']['c'][1]:.3f}) gains "
            f"{street['estimate_pair']['gain_db']:.2f} dB"
        )
        for b in street["bounds"]:
            print(
                f"  regression bracket, frames k and k + {b['gap']}: forward {b['forward']:.3f}, reverse "
                f"{b['reverse']:.3f} ({b['pixels']} pixels, {100 * b['fraction_one_event']:.0f}% with one event)"
            )
        print(f"  estimate within every bracket: {street['estimate_within_bounds']}")
    ni = ni_rows()
    if ni:
        print(
            f"\n{'ni_joint':18s} {'energy':15s} {'c':>7s} {'bound':>6s} {'sharp x':>8s} {'noise x':>8s} "
            f"{'explained':>9s} {'reliable':>8s}"
        )
        for r in ni:
            for energy in ("flow", "paper") + tuple(f"flow_gamma_{g:g}" for g in NI_GAMMAS):
                e = r[energy]
                expl = f"{e['explained']:.3f}" if e.get("explained") is not None else ""
                rel = str(e["reliable"]) if "reliable" in e else ""
                print(
                    f"{r['name']:18s} {energy:15s} {e['c']:7.4f} {str(e['at_bound']):>6s} "
                    f"{e['sharpness_gain']:8.2f} {e['noise_gain']:8.2f} {expl:>9s} {rel:>8s}"
                )
            print(
                f"{r['name']:18s} {'c=1.5':15s} {'':7s} {'':6s} {r['bracket_top']['sharpness_gain']:8.2f} "
                f"{r['bracket_top']['noise_gain']:8.2f}"
            )
    if ni:
        print("\nni_joint: the events' motion over their window against the frame's blur")
        for r in ni:
            m, b = r["events_motion"], r["frame_blur"]
            print(
                f"  {r['name']:18s} window {r['window_ms']:5.1f} ms, {r['events']:6d} events, "
                f"{100 * r['positive_fraction']:.0f}% "
                f"positive, {r['events_per_fired_pixel']:.2f} per fired pixel (max {r['max_events_per_pixel']}); "
                f"events moved ({m['dx']:+.1f}, {m['dy']:+.1f}) px (warp variance gain {m['variance_gain']:.3f}); "
                f"frame blur {b['length_px']:.0f} px at {b['angle_deg']:.0f} deg (ncc {b['ncc']:.2f}, unblurred "
                f"{b['ncc_unblurred']:.2f})"
            )
            ev_f = r["flow"]["evals"]
            print(
                f"  {'':18s} flow energy {ev_f[0][1]:.4f} at c {ev_f[0][0]:.3f} .. "
                f"{ev_f[-1][1]:.4f} at c {ev_f[-1][0]:.3f}, "
                f"increasing: {all(b2 >= a2 for (_, a2), (_, b2) in zip(ev_f, ev_f[1:]))}"
            )
    partial = partial_window()
    print("\nmoving texture, events of a centred fraction of the exposure only: c / c_true per seed (* bracket end)")
    for frac in PARTIAL_FRACTIONS:
        rs = [r for r in partial if r["fraction"] == frac]
        print(f"  {frac:4.0%}: " + " ".join(f"{r['ratio']:.2f}{'*' if r['at_bound'] else ''}" for r in rs))
    path = write_json(
        "calibration_quick" if args.quick else "calibration",
        {
            "seeds": len(seeds),
            "table": table,
            "rows": rows,
            "street": street,
            "ni_joint": ni,
            "partial_window": partial,
            "prediction_metric_check": check,
            "gamma_scan": scan,
            "seconds": time.perf_counter() - t0,
        },
    )
    print(f"\nwrote {path} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
