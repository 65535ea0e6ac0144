"""Image files: the one reader and the one writer of the project.

    read_image(path) -> float32 [H, W, D] in [0, 1]       # PNG 8/16-bit, JPEG, ..., float32 .npy
    write_image(path, img, bits=None | 8 | 16) -> Path    # None: lossless (PNG 8, PNG 16 or .npy)

Convention: PNG values are linear intensity (no sRGB curve), ``v / 255`` or ``v / 65535``.
D = 1 for grey, 3 for colour; an alpha channel is dropped; grey is never expanded to RGB.

Codecs: 16-bit PNGs (grey or colour, any filter type, interlaced or not) go through pypng, a
maintained pure-Python codec; everything else through Pillow. Pillow alone is not enough:
Pillow 13 opens a 16-bit RGB PNG as 8-bit "RGB" (the low byte dropped) and cannot write one.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np

from ._atomic import atomic_path  # re-exported: scenes.images.atomic_path
from .errors import CaptureError

__all__ = ["read_image", "write_image", "quantize", "write_png16", "read_png16", "atomic_path"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_BIT_DEPTH_OFFSET = 24  # IHDR: 8-byte signature, 4 length, 4 type, 4 width, 4 height, then bit depth
BITS = (8, 16)


def quantize(img: np.ndarray, bits: int = 8) -> np.ndarray:
    """Quantise linear [0, 1] intensity like an APS readout: round to ``2**bits - 1`` levels,
    back to float32 exactly as :func:`read_image` decodes it."""
    q = float(2**bits - 1)
    return (np.round(np.clip(img, 0.0, 1.0) * q).astype(np.float32) / np.float32(q)).astype(np.float32)


def _exact(img: np.ndarray, bits: int) -> np.ndarray | None:  # [H, W, D] ints, or None
    q = 2**bits - 1
    ints = np.round(img.astype(np.float64) * q)
    back = ints.astype(np.float32) / np.float32(q)
    if np.array_equal(back, img):
        return ints.astype(np.uint8 if bits == 8 else np.uint16)
    return None


def _write_png(path: Path, ints: np.ndarray) -> None:  # ints [H, W, D] uint8 | uint16
    h, w, d = ints.shape
    with atomic_path(path) as tmp:
        if ints.dtype == np.uint16:
            import png

            rows = ints.reshape(h, w * d).astype(">u2")  # PNG samples are big-endian
            with open(tmp, "wb") as fh:
                png.Writer(w, h, greyscale=d == 1, bitdepth=16).write_packed(fh, (bytearray(r.tobytes()) for r in rows))
        else:
            from PIL import Image

            Image.fromarray(ints[..., 0] if d == 1 else ints).save(tmp, format="PNG")


def write_image(
    path: str | os.PathLike,
    img: np.ndarray,  # [H, W, D] or [H, W], float in [0, 1]
    bits: int | None = None,
) -> Path:
    """Write linear [0, 1] intensity and return the path written.

    Args:
        path: the file; its suffix is replaced by the one written.
        img: [H, W, D] (D in 1, 3) or [H, W] float, finite.
        bits: 8 or 16 write a PNG of that depth, ``round(v * (2**bits - 1))`` after clipping to
            [0, 1]; None (default) writes losslessly: an 8-bit PNG when every value is k/255, a
            16-bit PNG when k/65535, else a float32 ``.npy``.

    The file appears atomically (written under a temporary name and renamed).

    Raises:
        ValueError: bad shape, non-finite values or ``bits`` not in (None, 8, 16).
    """
    path = Path(path)
    a = np.asarray(img)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"write_image {path}: img must be [H, W] or [H, W, 1|3], got shape {a.shape}")
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise ValueError(f"write_image {path}: img has non-finite values")
    if bits is not None:
        if bits not in BITS:
            raise ValueError(f"write_image {path}: bits must be 8, 16 or None, got {bits!r}")
        q = 2**bits - 1
        ints = np.round(np.clip(a.astype(np.float64), 0.0, 1.0) * q).astype(np.uint8 if bits == 8 else np.uint16)
        out = path.with_suffix(".png")
        _write_png(out, ints)
        return out
    for b in BITS:
        ints = _exact(a, b)
        if ints is not None:
            out = path.with_suffix(".png")
            _write_png(out, ints)
            return out
    out = path.with_suffix(".npy")
    with atomic_path(out) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, a)
    return out


def write_png16(path: str | os.PathLike, img: np.ndarray) -> Path:  # [H, W, D] or [H, W]
    """``write_image(path, img, bits=16)``: a 16-bit linear PNG, grey or RGB."""
    return write_image(path, img, bits=16)


def read_png16(path: str | os.PathLike) -> np.ndarray:  # -> [H, W, D] float32
    """Same as :func:`read_image` (kept for the callers that import this name)."""
    return read_image(path)


def _png_bit_depth(path: Path) -> int | None:
    with open(path, "rb") as fh:
        head = fh.read(PNG_BIT_DEPTH_OFFSET + 1)
    if head[:8] != PNG_SIGNATURE or len(head) <= PNG_BIT_DEPTH_OFFSET:
        return None
    return head[PNG_BIT_DEPTH_OFFSET]


def _read_png16(path: Path) -> np.ndarray:  # -> [H, W, D] float32
    import png

    w, h, rows, info = png.Reader(filename=str(path)).asDirect()
    planes = int(info["planes"])
    a = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows]).reshape(h, w, planes)
    if info.get("alpha"):
        a = a[..., :-1]
    return a.astype(np.float32) / np.float32(65535)


def _read_npy(path: Path, field: str) -> np.ndarray:
    try:
        a = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise CaptureError(str(path), field, f"unreadable .npy image ({type(exc).__name__}: {exc})") from None
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3) or a.dtype.kind != "f":
        raise CaptureError(str(path), field, f"a .npy image must be float [H, W, 1|3], got {a.dtype} {a.shape}")
    a = a.astype(np.float32)
    if not np.isfinite(a).all() or a.min() < 0 or a.max() > 1:
        raise CaptureError(str(path), field, "a .npy image must be finite and in [0, 1]")
    return a


def _read_pillow(path: Path, field: str) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        im.load()
        mode = im.mode
        a = np.asarray(im)
    if mode in ("I;16", "I;16B", "I;16L"):
        return (a.astype(np.float32) / np.float32(65535))[..., None]
    if mode == "L":
        return (a.astype(np.float32) / np.float32(255))[..., None]
    if mode == "LA":
        return a[..., :1].astype(np.float32) / np.float32(255)
    if mode in ("RGB", "RGBA"):
        return a[..., :3].astype(np.float32) / np.float32(255)
    if mode == "1":
        return a.astype(np.float32)[..., None]
    if mode == "P":
        with Image.open(path) as im:
            conv = im.convert("RGBA" if "transparency" in im.info else "RGB")
            return np.asarray(conv)[..., :3].astype(np.float32) / np.float32(255)
    raise CaptureError(str(path), field, f"unsupported image mode {mode!r} (use 8/16-bit grey or RGB)")


def read_image(path: str | os.PathLike, field: str = "file") -> np.ndarray:  # -> [H, W, D] float32
    """Read an image as linear float32 [H, W, D] in [0, 1] (D = 1 grey, 3 colour; alpha dropped).

    8-bit values are divided by 255, 16-bit by 65535; a float32 ``.npy`` is taken as it is.

    Raises:
        CaptureError: the file is missing, truncated, corrupt or of an unsupported kind; the
            message names the file and ``field``.
    """
    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), field, "file not found")
    if path.suffix.lower() == ".npy":
        return _read_npy(path, field)
    import png
    from PIL import Image

    decode_errors = (png.Error, OSError, EOFError, ValueError, SyntaxError, zlib.error, Image.DecompressionBombError)
    try:
        if _png_bit_depth(path) == 16:
            out = _read_png16(path)
        else:
            out = _read_pillow(path, field)
    except CaptureError:
        raise
    except decode_errors as exc:  # what the codecs raise on a truncated or corrupt file
        raise CaptureError(str(path), field, f"unreadable image ({type(exc).__name__}: {exc})") from None
    return np.ascontiguousarray(out, dtype=np.float32)
