"""Frame files: 8/16-bit PNG (and lossless float32 .npy) to linear float32 [H, W, D] and back.

Convention: PNG values are linear intensity (no sRGB curve), ``v / 255`` or ``v / 65535``.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from .errors import CaptureError

__all__ = ["read_image", "write_image", "quantize", "write_png16", "read_png16"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_png16(path: str | Path, img: np.ndarray) -> Path:  # [H, W, D] or [H, W], D in {1, 3}
    """Write linear [0, 1] intensity as a 16-bit grey or RGB PNG, ``round(v * 65535)``.

    A tiny encoder (zlib, filter 0 on every row) because Pillow cannot write 16-bit colour."""
    a = np.asarray(img, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"image must be [H, W] or [H, W, 1|3], got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"image for {path} has non-finite values")
    H, W, D = a.shape
    q = np.round(np.clip(a, 0, 1) * 65535).astype(">u2")
    raw = b"".join(b"\x00" + q[y].tobytes() for y in range(H))
    colour_type = 0 if D == 1 else 2
    png = (_PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 16, colour_type, 0, 0, 0))
           + _chunk(b"IDAT", zlib.compress(raw, 6)) + _chunk(b"IEND", b""))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)
    return path


def _decode_png16(data: bytes) -> np.ndarray | None:  # -> [H, W, D] uint16, or None
    """Decode a non-interlaced 16-bit grey/RGB PNG whose rows all use filter 0 (what
    ``write_png16`` writes); None for anything else."""
    if data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR" or len(data) < 33:
        return None
    if not (data[24] == 16 and data[25] in (0, 2) and data[28] == 0):
        return None
    W, H = struct.unpack(">II", data[16:24])
    D = 1 if data[25] == 0 else 3
    pos, idat = 8, b""
    while pos + 8 <= len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        if data[pos + 4:pos + 8] == b"IDAT":
            idat += data[pos + 8:pos + 8 + n]
        pos += 12 + n
    try:
        raw = zlib.decompress(idat)
    except zlib.error:
        return None
    stride = 1 + W * D * 2
    if len(raw) != H * stride or any(raw[y * stride] != 0 for y in range(H)):
        return None
    rows = np.frombuffer(raw, dtype=np.uint8).reshape(H, stride)[:, 1:]
    return np.ascontiguousarray(rows).view(">u2").reshape(H, W, D).astype(np.uint16)


def read_png16(path: str | Path) -> np.ndarray:  # -> [H, W, D] float32
    """Read a PNG as float32 [H, W, D] in [0, 1]: ``write_png16``'s output, or anything
    :func:`read_image` reads."""
    path = Path(path)
    q = _decode_png16(path.read_bytes()) if path.is_file() else None
    if q is not None:
        return q.astype(np.float32) / np.float32(65535)
    return read_image(path)


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
    .png (8-bit when every value is k/255, 16-bit when k/65535) or .npy (anything else).
    ``path`` is given without caring for its suffix."""
    from PIL import Image

    path = Path(path)
    img = np.asarray(img, dtype=np.float32)
    d = img.shape[2]
    for bits in (8, 16):
        ints = _exact(img, bits)
        if ints is not None:
            out = path.with_suffix(".png")
            if bits == 16 and d != 1:  # Pillow cannot write 16-bit colour PNG
                return write_png16(out, ints.astype(np.float64) / 65535.0)
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
        q = _decode_png16(path.read_bytes())
        if q is None:
            raise CaptureError(str(path), field, "only 16-bit colour PNGs written by ebad (unfiltered rows, no "
                                                 "alpha) are supported (Pillow truncates them); use 8-bit PNG "
                                                 "or a float32 .npy")
        return q.astype(np.float32) / np.float32(65535)
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
