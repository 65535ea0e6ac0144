"""An ESIM-style event simulator over a sequence of renders.

Each pixel keeps a reference log level ``log(I + eps)`` (I: linear intensity; colour renders
are averaged over channels first, as ``edi.moving_texture`` does, unless a colour filter array
``cfa`` is given: then each pixel sees its own channel of the Bayer mosaic, ``edi.cfa.mosaic``,
as the pixels of a colour DAVIS do). Between two renders the log
intensity is taken as linear in time; every time it climbs ``C+`` above the reference (or
falls ``C-`` below it) the pixel fires one event at the interpolated crossing time and the
reference moves by exactly that threshold. ``C+`` and ``C-`` are drawn per pixel from
N(c_pos, sigma_c) and N(c_neg, sigma_c) (``c`` a float gives c_pos = c_neg = c; each clipped to
at least ``MIN_C_FRACTION`` of its mean). A refractory period drops events that follow the
pixel's previous emitted event too closely (the reference still moves, as if the pixel had
reset). Shot noise adds Poisson events of random polarity at ``noise_hz`` per pixel; leak
noise adds Poisson positive events at ``leak_hz`` per pixel (the slow upward drift of a DVS
pixel's reference, modelled as independent events); ``hot_pixels`` random pixels fire
positive events at ``hot_pixel_hz``. The log offset ``eps`` is a sensor parameter (the
photoreceptor's dark level), by default the project's ``edi.LOG_EPS``.

Two implementations: ``_crossings_numba`` (fast) and ``_crossings_reference`` (plain Python),
tested against each other.
"""

from __future__ import annotations

import math
from typing import Literal, cast, overload

import numba
import numpy as np

from edi import LOG_EPS, EventStream, seconds_to_us

__all__ = ["simulate_events", "MIN_C_FRACTION", "HOT_PIXEL_HZ"]

MIN_C_FRACTION = 0.25  # per-pixel thresholds are clipped to >= this fraction of c
HOT_PIXEL_HZ = 500.0  # default firing rate of a hot pixel
LOG_BLOCK_VALUES = 8_000_000  # simulate_events logs the renders this many values (64 MB) at a time


@numba.njit(cache=True)
def _crossings_numba(logi, times, c_pos, c_neg, refractory):  # pragma: no cover - jit
    s, npx = logi.shape
    # pass 1: an upper bound on the number of events (no refractory)
    count = 0
    for p in range(npx):
        ref = logi[0, p]
        for k in range(s - 1):
            b = logi[k + 1, p]
            while True:
                if b - ref >= c_pos[p]:
                    ref += c_pos[p]
                elif ref - b >= c_neg[p]:
                    ref -= c_neg[p]
                else:
                    break
                count += 1
    t_out = np.empty(count, np.float64)
    pix = np.empty(count, np.int64)
    pol = np.empty(count, np.int8)
    n = 0
    for p in range(npx):
        ref = logi[0, p]
        last = -np.inf
        for k in range(s - 1):
            a = logi[k, p]
            b = logi[k + 1, p]
            while True:
                if b - ref >= c_pos[p]:
                    target = ref + c_pos[p]
                    sgn = 1
                elif ref - b >= c_neg[p]:
                    target = ref - c_neg[p]
                    sgn = -1
                else:
                    break
                frac = (target - a) / (b - a)
                frac = min(1.0, max(0.0, frac))
                te = times[k] + frac * (times[k + 1] - times[k])
                ref = target
                if te - last >= refractory:
                    t_out[n] = te
                    pix[n] = p
                    pol[n] = sgn
                    n += 1
                    last = te
    return t_out[:n], pix[:n], pol[:n]


def _crossings_reference(logi, times, c_pos, c_neg, refractory):
    """Plain-Python twin of ``_crossings_numba`` (same outputs, same order)."""
    s, npx = logi.shape
    ts, px, ps = [], [], []
    for p in range(npx):
        ref = float(logi[0, p])
        last = -math.inf
        for k in range(s - 1):
            a, b = float(logi[k, p]), float(logi[k + 1, p])
            while True:
                if b - ref >= c_pos[p]:
                    target, sgn = ref + c_pos[p], 1
                elif ref - b >= c_neg[p]:
                    target, sgn = ref - c_neg[p], -1
                else:
                    break
                frac = min(1.0, max(0.0, (target - a) / (b - a)))
                te = times[k] + frac * (times[k + 1] - times[k])
                ref = target
                if te - last >= refractory:
                    ts.append(te)
                    px.append(p)
                    ps.append(sgn)
                    last = te
    return np.array(ts, np.float64), np.array(px, np.int64), np.array(ps, np.int8)


def _check(images, times, c, sigma_c, refractory, noise_hz, hot_pixels, eps, leak_hz=0.0):
    imgs = np.asarray(images)
    if imgs.ndim == 4:
        if imgs.shape[3] not in (1, 3):
            raise ValueError(f"images: expected [S, H, W] or [S, H, W, D] with D in (1, 3), got {imgs.shape}")
    elif imgs.ndim != 3:
        raise ValueError(f"images: expected [S, H, W] or [S, H, W, D], got shape {imgs.shape}")
    if imgs.shape[0] < 2:
        raise ValueError(f"images: need at least 2 renders, got {imgs.shape[0]}")
    if imgs.dtype.kind not in "fiu":
        raise ValueError(f"images: must be numeric, got {imgs.dtype}")
    lo, hi = (imgs.min(), imgs.max()) if imgs.size else (0, 0)  # NaN propagates: no [S, H, W] mask
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0:
        raise ValueError("images: must be finite, non-negative linear intensity")
    t = np.asarray(times, dtype=np.float64)
    if t.shape != (imgs.shape[0],):
        raise ValueError(f"times: expected shape ({imgs.shape[0]},), got {t.shape}")
    if not np.isfinite(t).all() or np.any(np.diff(t) <= 0):
        raise ValueError("times: must be finite and strictly increasing (seconds)")
    for name, v in (("c", c[0]), ("c", c[1]), ("eps", eps)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a positive finite number (or a pair of them for c), got {v!r}")
    for name, v in (("sigma_c", sigma_c), ("refractory", refractory), ("noise_hz", noise_hz), ("leak_hz", leak_hz)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: must be a finite number >= 0, got {v!r}")
    if int(hot_pixels) != hot_pixels or hot_pixels < 0:
        raise ValueError(f"hot_pixels: must be a non-negative integer, got {hot_pixels!r}")
    return imgs, t


@overload
def simulate_events(
    images: np.ndarray,
    times: np.ndarray,
    c: float | tuple[float, float] = 0.2,
    sigma_c: float = 0.03,
    refractory: float = 0.0,
    noise_hz: float = 0.0,
    hot_pixels: int = 0,
    seed: int = 0,
    eps: float | None = None,
    hot_pixel_hz: float = HOT_PIXEL_HZ,
    return_thresholds: Literal[False] = False,
    reference: bool = False,
    leak_hz: float = 0.0,
    cfa: str | None = None,
) -> EventStream: ...


@overload
def simulate_events(
    images: np.ndarray,
    times: np.ndarray,
    c: float | tuple[float, float] = 0.2,
    sigma_c: float = 0.03,
    refractory: float = 0.0,
    noise_hz: float = 0.0,
    hot_pixels: int = 0,
    seed: int = 0,
    eps: float | None = None,
    hot_pixel_hz: float = HOT_PIXEL_HZ,
    *,
    return_thresholds: Literal[True],
    reference: bool = False,
    leak_hz: float = 0.0,
    cfa: str | None = None,
) -> tuple[EventStream, np.ndarray, np.ndarray]: ...


def simulate_events(
    images: np.ndarray,  # [S, H, W] or [S, H, W, D] linear intensity
    times: np.ndarray,  # [S] seconds, increasing
    c: float | tuple[float, float] = 0.2,
    sigma_c: float = 0.03,
    refractory: float = 0.0,
    noise_hz: float = 0.0,
    hot_pixels: int = 0,
    seed: int = 0,
    eps: float | None = None,
    hot_pixel_hz: float = HOT_PIXEL_HZ,
    return_thresholds: bool = False,
    reference: bool = False,
    leak_hz: float = 0.0,
    cfa: str | None = None,
) -> EventStream | tuple[EventStream, np.ndarray, np.ndarray]:
    """Events fired by a DVS pixel array watching ``images`` at ``times``.

    Args:
        images: [S, H, W] or [S, H, W, D] linear intensity (D = 3 is averaged to grey first, unless ``cfa``).
        times: [S] seconds, strictly increasing. Events lie in [times[0], times[-1]].
        c: mean contrast threshold, natural-log units: a float, or a pair (c_pos, c_neg).
        sigma_c: per-pixel std of C+ and C-.
        refractory: seconds; events closer than this to the pixel's previous event are dropped.
        noise_hz: shot-noise events per pixel per second (random polarity, uniform times).
        leak_hz: leak events per pixel per second (positive polarity, uniform times).
        hot_pixels: number of random pixels firing +1 events at ``hot_pixel_hz``.
        seed: RNG seed for thresholds and noise.
        eps: the sensor's offset in log(I + eps); None means ``edi.LOG_EPS``.
        return_thresholds: also return (c_pos, c_neg), each [H, W].
        reference: use the plain-Python kernel (slow; for tests).
        cfa: a Bayer pattern of ``edi.cfa`` ("RGGB", ...): ``images`` are [S, H, W, 3] and each
            pixel fires on the log of its own channel (a colour DAVIS); None: grey or channel mean.

    Returns:
        EventStream (t in integer microseconds of ``times``' clock, sorted, inside the sensor),
        or (EventStream, c_pos [H, W], c_neg [H, W]) with ``return_thresholds``.
    """
    eps = LOG_EPS if eps is None else float(eps)
    try:
        if np.ndim(c) == 0:
            cp = cn = float(cast(float, c))  # np.ndim does not narrow the type
        else:
            pair = cast("tuple[float, float]", c)
            cp, cn = float(pair[0]), float(pair[1])
            if np.ndim(c) == 1 and len(pair) != 2:
                raise TypeError
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"c: must be a float or a pair (c_pos, c_neg), got {c!r}") from None
    imgs, t = _check(
        images, times, (cp, cn), float(sigma_c), float(refractory), float(noise_hz), hot_pixels, eps, float(leak_hz)
    )
    if cfa is not None:
        from edi.cfa import check_pattern, mosaic

        check_pattern(cfa)
        if imgs.ndim != 4 or imgs.shape[3] != 3:
            raise ValueError(
                f"images: a colour filter array (cfa={cfa!r}) needs [S, H, W, 3] renders, got {imgs.shape}"
            )
        imgs = mosaic(imgs, cfa)
    elif imgs.ndim == 4:
        imgs = imgs[..., 0] if imgs.shape[3] == 1 else imgs.mean(axis=3)  # one channel: a view, not a copy
    s, h, w = imgs.shape
    rng = np.random.default_rng(seed)
    c_pos = (
        np.maximum(cp + sigma_c * rng.standard_normal(h * w), MIN_C_FRACTION * cp)
        if sigma_c > 0
        else np.full(h * w, cp)
    )
    c_neg = (
        np.maximum(cn + sigma_c * rng.standard_normal(h * w), MIN_C_FRACTION * cn)
        if sigma_c > 0
        else np.full(h * w, cn)
    )
    kern = _crossings_reference if reference else _crossings_numba
    flat = imgs.reshape(s, h * w)
    parts_t, parts_pix, parts_p = [], [], []
    # Each pixel's crossings depend on that pixel alone: log(I + eps) in float64 a block of pixels at a
    # time (about LOG_BLOCK_VALUES values), never the whole [S, H * W] (8 bytes a value, 2 GB at 40
    # views of 346x260); the blocks' events, in pixel order, are what one pass over all pixels gives.
    step = max(1, LOG_BLOCK_VALUES // s)
    for p0 in range(0, h * w, step):
        logi = np.array(flat[:, p0 : p0 + step], dtype=np.float64)  # a contiguous copy, logged in place
        logi += eps
        np.log(logi, out=logi)
        te, pix, pol = kern(logi, t, c_pos[p0 : p0 + step], c_neg[p0 : p0 + step], float(refractory))
        parts_t.append(te.copy())  # not the kernel's upper-bound buffers
        parts_pix.append(pix + p0)
        parts_p.append(pol.copy())
    span = float(t[-1] - t[0])
    if noise_hz > 0:
        n = rng.poisson(noise_hz * span, size=h * w)
        npix = np.repeat(np.arange(h * w), n)
        parts_pix.append(npix)
        parts_t.append(t[0] + span * rng.random(len(npix)))
        parts_p.append(np.where(rng.random(len(npix)) < 0.5, 1, -1).astype(np.int8))
    if hot_pixels:
        hp = rng.choice(h * w, size=min(int(hot_pixels), h * w), replace=False)
        for p in hp:
            k = max(1, int(round(hot_pixel_hz * span)))
            parts_t.append(np.sort(t[0] + span * rng.random(k)))
            parts_pix.append(np.full(k, p, np.int64))
            parts_p.append(np.ones(k, np.int8))
    if leak_hz > 0:
        n = rng.poisson(leak_hz * span, size=h * w)
        parts_pix.append(np.repeat(np.arange(h * w), n))
        parts_t.append(t[0] + span * rng.random(int(n.sum())))
        parts_p.append(np.ones(int(n.sum()), np.int8))
    te = np.concatenate(parts_t)
    pix = np.concatenate(parts_pix)
    pol = np.concatenate(parts_p)
    del parts_t, parts_pix, parts_p
    t_us = seconds_to_us(te)
    del te
    order = np.argsort(t_us, kind="stable")
    pix = pix[order]
    ev = EventStream(t_us[order], (pix % w).astype(np.int32), (pix // w).astype(np.int32), pol[order], w, h)
    if return_thresholds:
        return ev, c_pos.reshape(h, w), c_neg.reshape(h, w)
    return ev
