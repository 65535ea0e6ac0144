"""The colour filter array (Bayer mosaic) of a colour DAVIS: which channel each pixel sees.

On a colour DAVIS every pixel sits behind one filter of a 2x2 Bayer pattern: its APS value is
that one channel, and its events fire on the log of that one channel (DESIGN.md). A pattern is
four letters naming the filters of pixels (x=0, y=0), (1, 0), (0, 1), (1, 1) of the sensor's own
pixel grid, e.g. ``"RGGB"``. Channels are numbered R = 0, G = 1, B = 2, the order of an RGB image.

- ``channel_map(pattern, height, width)`` -> [H, W] int64: the channel of every pixel.
- ``mosaic(rgb, pattern)`` -> [..., H, W]: each pixel keeps its own channel (numpy or torch).
- ``demosaic(raw, pattern)`` -> [..., H, W, 3]: bilinear interpolation, the common camera-software
  demosaic; a pixel's own channel is kept exactly, so ``mosaic(demosaic(raw)) == raw``.
- ``transform_pattern(pattern, width, height, flip_x, flip_y, x0, y0)``: the pattern of frames
  flipped and/or cropped from the sensor's grid (a crop at an odd offset, or a flip of an odd
  size, moves which filter sits at (0, 0)).
"""

from __future__ import annotations

from typing import Any, Literal, TypeAlias

import numpy as np

from .errors import InputError

__all__ = ["CFA_PATTERNS", "CfaPattern", "channel_map", "check_pattern", "demosaic", "mosaic", "transform_pattern"]

CfaPattern: TypeAlias = Literal["RGGB", "BGGR", "GRBG", "GBRG"]
CFA_PATTERNS: tuple[CfaPattern, ...] = ("RGGB", "BGGR", "GRBG", "GBRG")
_INDEX = {"R": 0, "G": 1, "B": 2}

# bilinear demosaic as normalised convolution: R and B from their 2 or 4 nearest samples, G from its 4
_K_RB = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]])
_K_G = np.array([[0.0, 1.0, 0.0], [1.0, 4.0, 1.0], [0.0, 1.0, 0.0]])


def check_pattern(pattern: object, where: str = "cfa") -> CfaPattern:
    """``pattern`` as a ``CfaPattern``; anything else raises ``InputError`` naming ``where``."""
    if isinstance(pattern, str) and pattern.upper() in CFA_PATTERNS:
        return pattern.upper()  # type: ignore[return-value]
    raise InputError(f"{where}: {pattern!r} is not a Bayer pattern; expected one of {', '.join(CFA_PATTERNS)}")


def channel_map(pattern: str, height: int, width: int) -> np.ndarray:  # -> [H, W] int64 in {0, 1, 2}
    """The channel (R = 0, G = 1, B = 2) each pixel of an H x W sensor sees."""
    p = check_pattern(pattern)
    cell = np.array([[_INDEX[p[0]], _INDEX[p[1]]], [_INDEX[p[2]], _INDEX[p[3]]]], np.int64)  # [y, x]
    return np.tile(cell, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def mosaic(rgb: Any, pattern: str) -> Any:  # [..., H, W, 3] -> [..., H, W]
    """Each pixel's own channel of an RGB image (what the sensor records); numpy in numpy out,
    torch in torch out (differentiable)."""
    if rgb.shape[-1] != 3:
        raise InputError(f"mosaic: expected an RGB image [..., H, W, 3], got shape {tuple(rgb.shape)}")
    H, W = int(rgb.shape[-3]), int(rgb.shape[-2])
    idx = channel_map(pattern, H, W)
    if isinstance(rgb, np.ndarray):
        sel = np.broadcast_to(idx[..., None], rgb.shape[:-1] + (1,))
        return np.take_along_axis(rgb, sel, axis=-1)[..., 0]
    import torch

    sel_t = torch.from_numpy(idx).to(rgb.device)[..., None].expand(*rgb.shape[:-1], 1)
    return torch.gather(rgb, -1, sel_t)[..., 0]


def _conv3(x: np.ndarray, k: np.ndarray) -> np.ndarray:  # [..., H, W] zero-padded 3x3 correlation
    p = np.pad(x, [(0, 0)] * (x.ndim - 2) + [(1, 1), (1, 1)])
    H, W = x.shape[-2:]
    out = np.zeros_like(x)
    for dy in range(3):
        for dx in range(3):
            if k[dy, dx]:
                out += k[dy, dx] * p[..., dy : dy + H, dx : dx + W]
    return out


def demosaic(raw: np.ndarray, pattern: str) -> np.ndarray:  # [..., H, W] -> [..., H, W, 3]
    """Bilinear demosaic of a raw mosaic (float64 inside, the input's float dtype out).

    Each channel is the normalised 3x3 average of the pixels that carry it, so a pixel's own
    channel is its raw value exactly and borders average only the samples inside the image."""
    a = np.asarray(raw)
    if a.ndim < 2:
        raise InputError(f"demosaic: expected a raw mosaic [..., H, W], got shape {a.shape}")
    H, W = a.shape[-2:]
    idx = channel_map(pattern, H, W)
    x = a.astype(np.float64)
    out = np.empty(a.shape + (3,), np.float64)
    for c, k in ((0, _K_RB), (1, _K_G), (2, _K_RB)):
        m = (idx == c).astype(np.float64)
        out[..., c] = _conv3(x * m, k) / _conv3(np.broadcast_to(m, x.shape).copy(), k)
    dtype = a.dtype if np.issubdtype(a.dtype, np.floating) else np.float64
    return out.astype(dtype)


def transform_pattern(
    pattern: str, width: int, height: int, flip_x: bool = False, flip_y: bool = False, x0: int = 0, y0: int = 0
) -> CfaPattern:
    """The pattern of frames made from a ``width`` x ``height`` sensor image by flipping it
    (left-right ``flip_x``, up-down ``flip_y``) and then cropping from pixel (``x0``, ``y0``)."""
    p = check_pattern(pattern)
    cell = [[p[0], p[1]], [p[2], p[3]]]  # [y][x]

    def at(x: int, y: int) -> str:  # the filter of output pixel (x, y)
        sx = width - 1 - (x + x0) if flip_x else x + x0
        sy = height - 1 - (y + y0) if flip_y else y + y0
        return cell[sy % 2][sx % 2]

    return check_pattern(at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1))
