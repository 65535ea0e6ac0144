"""OpenCV radial-tangential (k1 k2 p1 p2 k3) distortion: undistort frames and events on load.

Convention: pixel coordinates with the top-left pixel centre at (0.5, 0.5) (pixel index j
covers [j, j + 1)); the undistorted capture keeps the same K.

Undistorted frames keep the input's quantisation: frames recorded at 8 bits (every value k/255)
come out at 8 bits, 16-bit frames at 16 bits (:func:`input_bits`), so ``scenes.save`` writes them
as PNG of that depth; only frames of neither kind (float renders) stay float.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from edi import EventStream

from .images import quantize

__all__ = ["distort_normalized", "undistort_normalized", "undistort_frames", "undistort_events", "input_bits"]


def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """[..., 2] ideal normalised coordinates -> distorted normalised coordinates."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_normalized(xy_d: np.ndarray, dist: np.ndarray, iters: int = 20) -> np.ndarray:
    """[..., 2] distorted normalised coordinates -> ideal ones (fixed-point iteration, as OpenCV)."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    xd, yd = xy_d[..., 0], xy_d[..., 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(iters):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return np.stack([x, y], axis=-1)


def input_bits(frames: np.ndarray) -> int | None:  # [F, H, W, D] float in [0, 1]
    """8 when every value is exactly k/255 (as ``scenes.read_image`` decodes an 8-bit file), 16 when
    k/65535, else None (float values no PNG holds)."""
    a = np.asarray(frames, dtype=np.float32)
    for bits in (8, 16):
        q = np.float32(2**bits - 1)
        ints = np.round(a.astype(np.float64) * float(q))
        if np.array_equal(ints.astype(np.float32) / q, a):
            return bits
    return None


def undistort_frames(
    frames: np.ndarray,  # [F, H, W, D]
    K: np.ndarray,
    dist: np.ndarray,
    cfa: str | None = None,
) -> np.ndarray:
    """Resample distorted frames onto the ideal pinhole grid with the same K (bilinear,
    border pixels that map outside the sensor take the nearest edge value). [F, H, W, D].

    The result is quantised as the input was (:func:`input_bits`): 8-bit frames stay 8-bit,
    16-bit frames 16-bit, so a converted capture's frames are PNG files.

    ``cfa`` (an ``edi.cfa`` pattern) with one-channel frames: the frames are raw Bayer mosaics,
    resampled as colour (bilinear demosaic, undistort each channel, take each pixel's own channel
    again), never by mixing the neighbouring pixels of other colours."""
    bits = input_bits(frames)
    f, h, w, d = frames.shape
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    xy = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], -1)
    xyd = distort_normalized(xy, dist)
    src_u = xyd[..., 0] * K[0, 0] + K[0, 2] - 0.5  # array index space
    src_v = xyd[..., 1] * K[1, 1] + K[1, 2] - 0.5

    def resample(a: np.ndarray) -> np.ndarray:  # [F, H, W, C]
        res = np.empty_like(a)
        for i in range(a.shape[0]):
            for c in range(a.shape[3]):
                res[i, :, :, c] = ndimage.map_coordinates(a[i, :, :, c], [src_v, src_u], order=1, mode="nearest")
        return res

    if cfa is not None and d == 1:
        from edi.cfa import check_pattern, demosaic, mosaic

        pattern = check_pattern(cfa)
        rgb = demosaic(np.asarray(frames, dtype=np.float32)[..., 0], pattern)
        out = np.asarray(mosaic(resample(rgb), pattern))[..., None]
    else:
        out = resample(frames)
    out = np.clip(out, 0.0, 1.0).astype(np.float32)
    return out if bits is None else quantize(out, bits)


def undistort_events(ev: EventStream, K: np.ndarray, dist: np.ndarray) -> tuple[EventStream, int]:
    """Move each event to the ideal pixel containing its undistorted pixel centre; events that
    leave the sensor are dropped. Returns (events, number dropped)."""
    w, h = ev.width, ev.height
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    xyd = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], -1)
    xy = undistort_normalized(xyd, dist)
    nu = np.floor(xy[..., 0] * K[0, 0] + K[0, 2]).astype(np.int64)
    nv = np.floor(xy[..., 1] * K[1, 1] + K[1, 2]).astype(np.int64)
    ex, ey = nu[ev.y, ev.x], nv[ev.y, ev.x]
    keep = (ex >= 0) & (ex < w) & (ey >= 0) & (ey < h)
    out = EventStream(ev.t[keep], ex[keep], ey[keep], ev.p[keep], w, h)
    object.__setattr__(out, "t0", ev.t0)
    return out, int((~keep).sum())
