"""Seeded synthetic ground truth for EDI: a textured image under known motion.

An ideal event sensor watches a smooth random texture translate at constant velocity:
at every step of a fine time grid it compares log(I + LOG_EPS) with each pixel's
reference level and fires one event per crossed contrast step (c_pos up, c_neg down).
The blurry frame is the mean of the sharp images over the exposure (the same grid), so
the EDI model holds up to the quantisation of the events. Used by the tests and the
benchmark; small and fast (numpy, and one numba loop over the time grid: ``_fire``, checked
against its numpy twin ``_fire_reference``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numba
import numpy as np

from .cfa import check_pattern, demosaic, mosaic
from .errors import InputError
from .events import EventStream, seconds_to_us
from .model import LOG_EPS

__all__ = ["SyntheticSequence", "moving_texture"]


@dataclass
class SyntheticSequence:
    frames: np.ndarray  # [F, H, W, D] float64 blurry frames in [0, 1]
    exposures: np.ndarray  # [F, 2] seconds
    events: EventStream
    c: tuple[float, float]  # (c_pos, c_neg) of the simulated sensor
    velocity: tuple[float, float]  # px / s (x, y)
    texture: Texture
    cfa: str | None = None  # the Bayer pattern of a simulated colour DAVIS (``edi.cfa``), or None

    def sharp(self, t: float) -> np.ndarray:
        """[H, W, D] the sharp image at time t (seconds)."""
        return self.texture.render(t)

    def sharp_mosaic(self, t: float) -> np.ndarray:
        """[H, W] what each pixel of the colour DAVIS sees at time t (its own channel); needs ``cfa``."""
        if self.cfa is None:
            raise InputError("sharp_mosaic: the sequence has no cfa (moving_texture(cfa=...))")
        return mosaic(self.texture.render(t), self.cfa)


@dataclass
class Texture:
    height: int
    width: int
    channels: int
    freqs: np.ndarray  # [K, 2] cycles per pixel
    phases: np.ndarray  # [K, D]
    amps: np.ndarray  # [K]
    velocity: tuple[float, float]
    lo: float
    hi: float
    gain: float

    def render(self, t: float) -> np.ndarray:
        return self.render_many(np.array([t]))[0]

    def render_many(self, ts: np.ndarray) -> np.ndarray:
        """[T, H, W, D] the sharp images at the times ``ts`` (seconds). Each wave sin(a(x) + b(y))
        is split as sin a cos b + cos a sin b: one product over the waves instead of K H W sines."""
        ts = np.asarray(ts, np.float64)[:, None, None]
        u = np.arange(self.width) + 0.5 - self.velocity[0] * ts  # [T, 1, W]
        v = np.arange(self.height)[:, None] + 0.5 - self.velocity[1] * ts[..., None]  # [T, 1, H, 1]
        a = 2 * np.pi * self.freqs[:, 0, None] * u  # [T, K, W]
        b = 2 * np.pi * self.freqs[:, 1, None, None] * v + self.phases[:, None, :]  # [T, K, H, D]
        amps = self.amps[:, None, None]
        by_row = np.concatenate([amps * np.cos(b), amps * np.sin(b)], axis=1)  # [T, 2K, H, D]
        by_col = np.concatenate([np.sin(a), np.cos(a)], axis=1)  # [T, 2K, W]
        f = (by_row.transpose(0, 3, 2, 1) @ by_col[:, None]).transpose(0, 2, 3, 1)  # [T, D, H, W] -> [T, H, W, D]
        return self.lo + (self.hi - self.lo) / (1.0 + np.exp(-self.gain * f))


def moving_texture(
    height: int = 40,
    width: int = 56,
    num_frames: int = 1,
    exposure: float = 0.04,  # s
    period: float = 0.05,  # s between frame starts
    velocity: tuple[float, float] = (250.0, 60.0),  # px / s
    c: float | tuple[float, float] = 0.2,
    step_us: int = 50,
    channels: int = 1,
    seed: int = 0,
    lo: float = 0.05,
    hi: float = 0.9,
    gain: float = 3.0,
    sigma_c: float = 0.0,
    lead: float = 0.0,  # s
    cfa: str | None = None,
) -> SyntheticSequence:
    """A seeded sequence of ``num_frames`` blurry frames, their exposures and ideal events.

    ``sigma_c`` > 0 draws every pixel's C+ and C- independently around ``c`` (std sigma_c,
    at least c / 4), like a real sensor's mismatch; 0 gives every pixel exactly ``c``.
    ``lead`` is how long the sensor runs before the first exposure starts. With 0 every
    pixel's reference level is set at the first exposure's start, so the first frame sees
    fewer events than a camera that was already running would give it (its pixels all sit a
    whole threshold away from firing); a lead of a few frame periods spreads the pixels over
    their thresholds as in a running camera.

    ``cfa`` (a Bayer pattern of ``edi.cfa``, with ``channels=3``) simulates a colour DAVIS: each
    pixel's events fire on the log of its own channel (not the grey level), and the frames are the
    bilinear demosaic (``edi.cfa.demosaic``, the camera software's) of the blurry mosaic, so
    ``mosaic(frames, cfa)`` is the raw blurry mosaic exactly; ``sharp_mosaic(t)`` is the truth per pixel.
    """
    if cfa is not None:
        cfa = check_pattern(cfa)
        if channels != 3:
            raise InputError(f"moving_texture: cfa={cfa!r} needs channels=3, got channels={channels}")
    if not (np.isfinite(lead) and lead >= 0):
        raise InputError(f"lead must be a finite number of seconds >= 0, got {lead!r}")
    rng = np.random.default_rng(seed)
    K = 12
    radius = rng.uniform(0.03, 0.16, K)  # cycles per pixel: periods of 6 to 33 px
    ang = rng.uniform(0, np.pi, K)
    freqs = np.stack([radius * np.cos(ang), radius * np.sin(ang)], axis=1)
    phases = rng.uniform(0, 2 * np.pi, (K, channels))
    amps = rng.uniform(0.5, 1.0, K) / np.sqrt(K) * 2.0
    vx, vy = velocity
    tex = Texture(height, width, channels, freqs, phases, amps, (vx, vy), lo, hi, gain)
    if np.isscalar(c):
        c_pos = c_neg = float(cast(float, c))  # np.isscalar does not narrow the type
    else:
        pair = cast("tuple[float, float]", c)
        c_pos, c_neg = float(pair[0]), float(pair[1])
    c_pos_px = np.full((height, width), c_pos)
    c_neg_px = np.full((height, width), c_neg)
    if sigma_c > 0:
        c_pos_px = np.maximum(c_pos + sigma_c * rng.standard_normal((height, width)), c_pos / 4)
        c_neg_px = np.maximum(c_neg + sigma_c * rng.standard_normal((height, width)), c_neg / 4)

    t_end_us = seconds_to_us(lead + (num_frames - 1) * period + exposure)
    steps = np.arange(0, t_end_us + step_us, step_us, dtype=np.int64)

    def seen(img: np.ndarray) -> np.ndarray:  # [H, W, D] -> [H, W]: what a pixel's events see
        return img.mean(axis=-1) if cfa is None else mosaic(img, cfa)  # the grey level, or its own channel

    ref = np.log(seen(tex.render(0.0)) + LOG_EPS)
    images = np.concatenate([tex.render_many(chunk * 1e-6) for chunk in np.array_split(steps, len(steps) // 256 + 1)])
    lgs = np.log(seen(images) + LOG_EPS)  # [T, H, W]
    n_ups, n_dns = _fire(lgs, ref, c_pos_px, c_neg_px)
    ts, xs, ys, ps = [], [], [], []
    for n, pol in ((n_ups, 1), (n_dns, -1)):  # one step's up events, then its down events, each in (y, x) order
        jj, yy, xx = np.nonzero(n)
        reps = n[jj, yy, xx]
        xs.append(np.repeat(xx, reps))
        ys.append(np.repeat(yy, reps))
        ps.append(np.full(reps.sum(), pol, np.int8))
        ts.append(np.repeat(steps[jj], reps))
    t = np.concatenate(ts)
    if len(t):
        order = np.argsort(t, kind="stable")
        ev = EventStream(
            t[order], np.concatenate(xs)[order], np.concatenate(ys)[order], np.concatenate(ps)[order], width, height
        )
    else:
        ev = EventStream.empty(width, height)
    exposures = np.array([[lead + i * period, lead + i * period + exposure] for i in range(num_frames)])
    frames = []
    for t0, t1 in exposures:
        a, b = seconds_to_us(t0), seconds_to_us(t1)
        frames.append(np.mean(images[(a <= steps) & (steps < b)], axis=0))
    fr = np.stack(frames)
    if cfa is not None:  # what the camera software gives: the blurry mosaic, demosaiced
        fr = np.clip(demosaic(mosaic(fr, cfa), cfa), 0.0, 1.0)
    return SyntheticSequence(fr, exposures, ev, (c_pos, c_neg), (vx, vy), tex, cfa)


def _fire_reference(
    lgs: np.ndarray, ref: np.ndarray, c_pos_px: np.ndarray, c_neg_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """[T, H, W] x2 (int64): the up and down events of each pixel at each step of ``lgs`` [T, H, W]
    (log intensity), from the reference levels ``ref`` [H, W] at the grid's start: every crossed
    threshold fires, and the reference follows the pixel's own events. numpy, one step at a time."""
    n_ups, n_dns = np.zeros(lgs.shape, np.int64), np.zeros(lgs.shape, np.int64)
    for j in range(len(lgs)):
        d = lgs[j] - ref
        n_ups[j] = n_up = np.floor(np.maximum(d, 0) / c_pos_px)
        n_dns[j] = n_dn = np.floor(np.maximum(-d, 0) / c_neg_px)
        ref = ref + n_up * c_pos_px - n_dn * c_neg_px
    return n_ups, n_dns


def _fire(
    lgs: np.ndarray, ref: np.ndarray, c_pos_px: np.ndarray, c_neg_px: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``_fire_reference``'s counts, bit for bit (as int32: a step's counts are small), in one compiled pass
    over the grid (every pixel of a step, then the next step)."""
    T, H, W = lgs.shape
    shape = (H * W,)
    up, dn = _fire_numba(
        np.ascontiguousarray(lgs, np.float64).reshape(T, H * W),
        np.ascontiguousarray(ref, np.float64).reshape(shape),
        np.ascontiguousarray(c_pos_px, np.float64).reshape(shape),
        np.ascontiguousarray(c_neg_px, np.float64).reshape(shape),
    )
    return up.reshape(T, H, W), dn.reshape(T, H, W)


@numba.njit(cache=True, nogil=True)
def _fire_numba(lgs, ref, cp, cn):  # pragma: no cover - jit
    T, P = lgs.shape
    up = np.zeros((T, P), np.int32)  # counts of one step: small
    dn = np.zeros((T, P), np.int32)
    r = ref.copy()
    for j in range(T):  # along the grid, all pixels of a step in memory order
        for p in range(P):
            d = lgs[j, p] - r[p]
            n_up = np.floor(max(d, 0.0) / cp[p])  # the same operations, in the same order, as the reference
            n_dn = np.floor(max(-d, 0.0) / cn[p])
            up[j, p] = np.int32(n_up)
            dn[j, p] = np.int32(n_dn)
            r[p] = r[p] + n_up * cp[p] - n_dn * cn[p]
    return up, dn
