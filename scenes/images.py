"""Frame files: 8/16-bit PNG (and lossless float32 .npy) to linear float32 [H, W, D] and back.

Convention: PNG values are linear intensity (no sRGB curve), ``v / 255`` or ``v / 65535``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import CaptureError

__all__ = ["read_image", "write_image", "quantize"]


def quantize(img: np.ndarray, bits: int = 8) -> np.ndarray:
    """Quantise linear [0, 1] intensity like an APS readout: round to ``2**bits - 1`` levels,
    back to float32 exactly as :func:`read_image` decodes it."""
    q = float(2**bits - 1)
    return (np.round(np.clip(img, 0.0, 1.0) * q).astype(np.float32) / np.float32(q)).astype(np.float32)


def _exact(img: np.ndarray, bits: int) -> np.ndarray | None:
    q = 2**bits - 1
    ints = np.round(img.astype(np.float64) * q)
    back = ints.astype(np.float32) / np.float32(q)
    if np.array_equal(back, img):
        return ints.astype(np.uint8 if bits == 8 else np.uint16)
    return None


def write_image(path: Path, img: np.ndarray) -> Path:
    """Write [H, W, D] float32 in [0, 1] losslessly; returns the path written, whose suffix is
    .png (8-bit when every value is k/255, 16-bit grey when k/65535) or .npy (anything else).
    ``path`` is given without caring for its suffix."""
    from PIL import Image

    path = Path(path)
    img = np.asarray(img, dtype=np.float32)
    d = img.shape[2]
    for bits in (8, 16):
        if bits == 16 and d != 1:  # Pillow cannot write 16-bit colour PNG
            break
        ints = _exact(img, bits)
        if ints is not None:
            out = path.with_suffix(".png")
            arr = ints[..., 0] if d == 1 else ints
            Image.fromarray(arr).save(out, format="PNG")
            return out
    out = path.with_suffix(".npy")
    np.save(out, img)
    return out


def _png_bit_depth(path: Path) -> tuple[int, int] | None:  # (bit depth, colour type)
    with open(path, "rb") as fh:
        head = fh.read(29)
    if head[:8] != b"\x89PNG\r\n\x1a\n" or len(head) < 26:
        return None
    return head[24], head[25]  # bit depth, colour type


def read_image(path: Path, field: str = "file") -> np.ndarray:
    """Read a frame as [H, W, D] float32 linear in [0, 1] (D = 1 grey, 3 colour; alpha dropped).
    Raises CaptureError naming the file and ``field`` when it cannot be read."""
    from PIL import Image

    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), field, "file not found")
    if path.suffix == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise CaptureError(str(path), field, f"unreadable .npy image ({exc})") from None
        if a.ndim == 2:
            a = a[..., None]
        if a.ndim != 3 or a.shape[2] not in (1, 3) or a.dtype.kind != "f":
            raise CaptureError(str(path), field, f"a .npy image must be float [H, W, 1|3], got {a.dtype} {a.shape}")
        a = a.astype(np.float32)
        if not np.isfinite(a).all() or a.min() < 0 or a.max() > 1:
            raise CaptureError(str(path), field, "a .npy image must be finite and in [0, 1]")
        return a
    info = _png_bit_depth(path) if path.suffix.lower() == ".png" else None
    if info is not None and info[0] == 16 and info[1] in (2, 6):
        raise CaptureError(str(path), field, "16-bit colour PNG is not supported (Pillow truncates it); "
                                             "use 8-bit PNG or a float32 .npy")
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            a = np.asarray(im)
    except Exception as exc:
        raise CaptureError(str(path), field, f"unreadable image ({type(exc).__name__}: {exc})") from None
    if mode in ("I;16", "I;16B", "I;16L", "I") and (info is None or info[0] == 16):
        out = a.astype(np.float32) / np.float32(65535)
        out = out[..., None]
    elif mode == "L":
        out = (a.astype(np.float32) / np.float32(255))[..., None]
    elif mode == "LA":
        out = (a[..., :1].astype(np.float32) / np.float32(255))
    elif mode in ("RGB", "RGBA"):
        out = a[..., :3].astype(np.float32) / np.float32(255)
    elif mode == "1":
        out = a.astype(np.float32)[..., None]
    else:
        raise CaptureError(str(path), field, f"unsupported image mode {mode!r}")
    return np.ascontiguousarray(out, dtype=np.float32)
