"""Readers for event files and AEDAT4 recordings.

Formats (by extension):
  * ``.npz`` / ``.h5`` / ``.hdf5``: arrays x, y, t, p at the root or under ``events/``
    (EvDeblurNeRF, E-NeRF layouts; ``polarity``/``pol`` and ``ts``/``timestamp`` accepted).
  * ``.txt``: the Event Camera Dataset's ``events.txt``, lines ``t x y p`` (t in seconds).
  * ``.mat``: MATLAB, an ``events`` array N x 4 ``[t, x, y, p]`` (ni-joint layout), or
    separate x, y, t, p variables.
  * ``.aedat4``: through the ``aedat`` package (``pip install aedat``, or the project's
    ``[aedat]`` extra); ``dv-processing`` is used when ``aedat`` is missing. The header (the
    streams, and the Bayer filter of a colour DAVIS) is read here, without either package.

The time unit is given (``t_unit`` in "s", "ms", "us", "ns") or inferred from the magnitude
and the span of the timestamps together (``infer_time_unit``), logged at INFO and returned by
``read_events(..., return_unit=True)``; what cannot be told apart raises ``EventError``
asking for ``t_unit``. Times are converted to int64 microseconds by ``to_us`` (nearest,
ties to even, as ``seconds_to_us``). Raw epoch times (above 1e12 us, ~11.6 days) are made
relative by subtracting the first event's time in int64 (kept as ``EventStream.t0``).
A file that cannot be parsed (truncated, not the format its extension says) raises
``EventError`` naming the file and what is wrong.
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast, overload

import numpy as np

from .errors import CorruptFileError
from .events import EventError, EventStream

__all__ = ["read_events", "read_aedat4", "read_aedat4_info", "AedatRecording", "infer_time_unit", "DV_COLOR_FILTER"]

log = logging.getLogger(__name__)

#: microseconds per unit
UNITS_US = {"s": 10**6, "ms": 10**3, "us": 1, "ns": 10**-3}
_EPOCH_US = 10**12  # converted times above this (~11.6 days) are raw epoch timestamps
#: integer timestamps at or above this are absolute clock readings (read against the epoch)
ABSOLUTE_MIN = 1e11
#: plausible dates of an absolute clock reading, seconds since 1970 (1990 .. 2100)
EPOCH_RANGE_S = (6.3e8, 4.1e9)
#: relative integer timestamps spanning less than this are microseconds (< 1000 s) ...
SPAN_US_MAX = 1e9
#: ... from this span up (2.8 hours in us, 10 s in ns) nanoseconds; in between refused
SPAN_NS_MIN = 1e10

_ALIASES = {
    "t": ("t", "ts", "timestamp", "timestamps", "time", "times"),
    "x": ("x", "xs"),
    "y": ("y", "ys"),
    "p": ("p", "polarity", "polarities", "pol", "ps"),
}


def infer_time_unit(t: np.ndarray) -> tuple[str, str]:
    """(unit, reason) for raw timestamps t [M], from their magnitude and span together.

    * non-integer floats: seconds;
    * integers (or whole floats) from ``ABSOLUTE_MIN`` (1e11) up are absolute clock readings:
      the unit is the one that dates the first event between 1990 and 2100 since the epoch
      (1.7e18 is nanoseconds, 1.7e15 microseconds, 1.7e12 milliseconds), whatever the span;
    * smaller integers are relative: a span below ``SPAN_US_MAX`` (1e9) is microseconds
      (under 1000 s), from ``SPAN_NS_MIN`` (1e10; 10 s in ns, 2.8 hours in us) nanoseconds;

    anything else (an absolute reading that dates to no plausible year in any unit, a
    relative span from 1e9 to 1e10: 17 minutes to 2.8 hours in us, or 1 to 10 s in ns) raises
    ``EventError`` asking for ``t_unit``.
    """
    if len(t) == 0:
        return "us", "no events (defaulting to microseconds)"
    if t.dtype.kind == "f":
        finite = t[np.isfinite(t)]
        if finite.size and np.any(finite != np.round(finite)):
            return "s", "non-integer timestamps are seconds"
    elif t.dtype.kind not in "iu":
        raise EventError(f"field 't' must be numeric, got dtype {t.dtype}")
    t_min, t_max = float(np.min(t)), float(np.max(t))
    span = t_max - t_min
    if t_min >= ABSOLUTE_MIN:
        for unit in ("ns", "us", "ms"):
            sec = t_min * UNITS_US[unit] * 1e-6
            if EPOCH_RANGE_S[0] <= sec <= EPOCH_RANGE_S[1]:
                year = 1970 + sec / 31_557_600
                return unit, (
                    f"integer timestamps from {t_min:.4g}: {unit} since 1970 date them to {year:.0f} "
                    f"(span {span * UNITS_US[unit] * 1e-6:.4g} s)"
                )
        raise EventError(
            f"cannot tell the time unit: timestamps from {t_min:.4g} are no date between 1990 and 2100 in s, ms, "
            f"us or ns since 1970; give t_unit (ebad deblur --t-unit)"
        )
    if span >= SPAN_NS_MIN:
        return (
            "ns",
            f"relative integer timestamps spanning {span:.4g} (>= {SPAN_NS_MIN:.0e}: {span * 1e-9:.4g} s in ns)",
        )
    if span < SPAN_US_MAX:
        return "us", f"relative integer timestamps spanning {span:.4g} (< {SPAN_US_MAX:.0e}: {span * 1e-6:.4g} s in us)"
    raise EventError(
        f"cannot tell the time unit: relative integer timestamps spanning {span:.4g} could be {span * 1e-6:.4g} s "
        f"in microseconds or {span * 1e-9:.4g} s in nanoseconds; give t_unit (ebad deblur --t-unit)"
    )


def to_us(t: np.ndarray, unit: str, name: str = "t") -> np.ndarray:
    """Raw times [M] in ``unit`` -> int64 microseconds, to the nearest, ties to even.

    Integers are converted in exact integer arithmetic (ns: divided by 1000 with that
    rounding); floats through float64, which must hold the result exactly (< 2^53 us)."""
    if unit not in UNITS_US:
        raise EventError(f"{name}: t_unit must be one of {sorted(UNITS_US)}, got {unit!r}")
    if t.dtype.kind == "f":
        if not np.isfinite(t).all():
            i = int(np.flatnonzero(~np.isfinite(t))[0])
            raise EventError(f"{name}: field 't' has a non-finite value at index {i}")
        us = np.rint(t.astype(np.float64) * UNITS_US[unit])
        if len(us) and np.abs(us).max() > 2**53:
            raise EventError(f"{name}: float times too large for exact microseconds; store them as int64")
        return us.astype(np.int64)
    if t.dtype.kind not in "iu":
        raise EventError(f"{name}: field 't' must be numeric, got dtype {t.dtype}")
    ti = t.astype(np.int64)
    if unit != "ns":
        return ti * int(UNITS_US[unit])
    q, r = np.divmod(ti, 1000)
    return q + ((r > 500) | ((r == 500) & (q % 2 == 1)))


def _pick(keys: set[str], field: str, path: str) -> str:
    for a in _ALIASES[field]:
        if a in keys:
            return a
    raise EventError(
        f"{path}: no events field '{field}' (looked for {', '.join(_ALIASES[field])}; found {sorted(keys)})"
    )


class _Lazy:
    """A 1-D field read block by block: ``raw`` (an ndarray, a memory map of an .npz member, an
    h5py dataset) with ``fn`` applied to each block read (the time unit's conversion)."""

    ndim = 1

    def __init__(self, raw, fn: Callable[[np.ndarray], np.ndarray] | None = None, dtype=None) -> None:
        self.raw, self.fn = raw, fn
        self.shape = (int(raw.shape[0]),)
        self.dtype = np.dtype(dtype if dtype is not None else raw.dtype)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, sl):
        if not isinstance(sl, slice):  # one value, for a message: the raw one
            return self.raw[sl]
        a = np.asarray(self.raw[sl])
        return self.fn(a) if self.fn is not None else a

    def blocks(self):
        from .events import CHUNK

        for s in range(0, len(self), CHUNK):
            yield self[s : s + CHUNK]

    def _ends(self) -> np.ndarray | None:
        """[min, max] through ``fn`` (monotonic) from a streamed field's one-pass summary, else None."""
        s = self.raw.summary() if isinstance(self.raw, _NpzStream) else {}
        if "min" not in s or "nonfinite" in s:  # a non-finite value: the blocks' conversion names it
            return None
        ends = np.array([s["min"], s["max"]], self.raw.dtype)
        return self.fn(ends) if self.fn is not None else ends

    def min(self):
        ends = self._ends()
        return ends[0] if ends is not None else min(b.min() for b in self.blocks())

    def max(self):
        ends = self._ends()
        return ends[1] if ends is not None else max(b.max() for b in self.blocks())


def _npy_header(f) -> tuple[tuple[int, ...], bool, np.dtype] | None:
    """(shape, fortran_order, dtype) of the .npy array whose header starts at f's position (left at
    its data), or None for a header version this reader does not stream (numpy's ``np.load`` reads it)."""
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(f)
    return None


def _flat_length(shape: tuple[int, ...], fortran: bool, dtype: np.dtype) -> int | None:
    """The length of a plain array of ``shape`` read as one field (a vector, or [M, 1, ...]: its memory
    order then makes no difference), or None when it is not one (numpy reads it whole instead)."""
    if dtype.hasobject or len(shape) > 1 and shape[1:] != (1,) * (len(shape) - 1):
        return None
    if fortran and sum(n != 1 for n in shape) > 1:  # pragma: no cover - excluded by the shapes above
        return None
    return int(np.prod(shape)) if shape else 1


class _NpzStream:
    """A field of a compressed (deflated) .npz member, decompressed block by block as it is read:
    ``self[a:b]`` reads values a .. b - 1 (forward from the last read, else from the start again), so
    a pass over the field holds one block, never the whole member. The last block read and the one
    that ended a pass are kept (its last value, for ``EventStream``'s dtype choice, costs no new
    pass). A truncated or corrupt member raises ``CorruptFileError`` naming the file and the field."""

    ndim = 1
    SKIP = 1 << 20  # bytes decompressed at a time when skipping forward (zipfile's own seek takes 16 MB)

    def __init__(self, path: Path, name: str, offset: int, n: int, dtype: np.dtype) -> None:
        self.path, self.name, self.offset, self.dtype, self.shape = path, name, offset, dtype, (n,)
        self._zf: Any = None
        self._f: Any = None
        self._pos = 0  # the next value the open member yields
        self._kept: dict[str, tuple[int, np.ndarray]] = {}  # "last" and "tail" blocks: (first index, values)
        self._summary: dict[str, Any] | None = None

    def __len__(self) -> int:
        return self.shape[0]

    def _bad(self, what: str) -> CorruptFileError:
        self.close()
        return CorruptFileError(f"{self.path}: events field '{self.name}' of the .npz is {what}")

    def __getitem__(self, sl):
        if not isinstance(sl, slice):  # one value, for a message
            i = int(sl) + len(self) if int(sl) < 0 else int(sl)
            return self[i : i + 1][0]
        a, b, step = sl.indices(len(self))
        if step != 1:
            raise IndexError("a streamed .npz field is read in steps of 1")
        b = max(a, b)
        for s0, blk in self._kept.values():
            if s0 <= a and b <= s0 + len(blk):
                return blk[a - s0 : b - s0]
        out = np.frombuffer(self._read(a, b), self.dtype)
        self._kept["last"] = (a, out)
        if b == len(self):
            self._kept["tail"] = (a, out)
        return out

    def _read(self, a: int, b: int) -> bytes:
        """The bytes of values a .. b - 1, from the open member (reopened to go back)."""
        import zipfile
        import zlib

        size = self.dtype.itemsize
        try:
            if self._f is None or a < self._pos:
                self.close()
                self._zf = zipfile.ZipFile(self.path)
                self._f = self._zf.open(self.name + ".npy")
                self._f.read(self.offset)  # the .npy header
                self._pos = 0
            skip = (a - self._pos) * size
            while skip > 0:
                got = len(self._f.read(min(skip, self.SKIP)))
                if got == 0:
                    break
                skip -= got
            buf = self._f.read((b - a) * size) if skip == 0 else b""
        except (OSError, EOFError, zlib.error, zipfile.BadZipFile) as exc:
            raise self._bad(f"corrupt ({type(exc).__name__}: {exc})") from None
        if len(buf) != (b - a) * size:
            stored = a + len(buf) // size if skip == 0 else a - skip // size
            raise self._bad(f"truncated: {len(self)} values declared, {stored} stored")
        self._pos = b
        return buf

    def summary(self) -> dict[str, Any]:
        """The field's minimum and maximum (of its finite values), and its first non-integer and first
        non-finite value where it has one (float times), from one pass, kept; empty when the field is
        empty or not numeric."""
        if self._summary is not None:
            return self._summary
        s: dict[str, Any] = {}
        if self.dtype.kind not in "iuf":
            self._summary = s
            return s
        from .events import CHUNK

        for a in range(0, len(self), CHUNK):
            b = self[a : a + CHUNK]
            fin = np.isfinite(b) if b.dtype.kind == "f" else None
            vals = b if fin is None else b[fin]
            if len(vals):
                lo, hi = vals.min(), vals.max()
                s["min"], s["max"] = min(s.get("min", lo), lo), max(s.get("max", hi), hi)
            if fin is not None:
                frac = vals[vals != np.round(vals)]
                if len(frac):
                    s.setdefault("frac", frac[0])
                if not fin.all():
                    s.setdefault("nonfinite", b[~fin][0])
        self._summary = s
        return s

    def close(self) -> None:
        for h in (self._f, self._zf):
            if h is not None:
                h.close()
        self._f = self._zf = None


def _npz_member(path: Path, name: str) -> np.ndarray | _NpzStream | None:
    """An .npz member's array read as it is used, never copied whole: a read-only memory map when it is
    stored uncompressed (``np.savez``), an ``_NpzStream`` when deflated (``np.savez_compressed``); None
    when it is not a plain field (``np.load`` reads it)."""
    import zipfile

    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(name + ".npy")
        if info.compress_type != zipfile.ZIP_STORED:
            with zf.open(info) as f:
                header = _npy_header(f)
                offset = f.tell()
            n = None if header is None else _flat_length(*header)
            return None if header is None or n is None else _NpzStream(path, name, offset, n, header[2])
    with open(path, "rb") as f:
        f.seek(info.header_offset)
        local = f.read(30)
        if local[:4] != b"PK\x03\x04":
            return None
        n_name, n_extra = struct.unpack("<HH", local[26:30])
        f.seek(info.header_offset + 30 + n_name + n_extra)
        header = _npy_header(f)
        offset = f.tell()
    n = None if header is None else _flat_length(*header)
    if header is None or n is None:
        return None
    if n == 0:
        return np.zeros(0, header[2])
    return np.memmap(path, dtype=header[2], mode="r", offset=offset, shape=(n,))


def _load_arrays(path: Path) -> dict[str, Any]:
    """The arrays of an event file; a file its parser cannot read raises EventError naming it."""
    import zipfile
    import zlib

    from scipy.io.matlab import MatReadError

    kind = {".npz": "NumPy .npz", ".h5": "HDF5", ".hdf5": "HDF5", ".mat": "MATLAB .mat", ".txt": "text"}
    ext = path.suffix.lower()
    if ext not in kind:
        raise EventError(f"{path}: unknown event file type {ext!r} (use .npz, .h5, .txt, .mat or .aedat4)")
    try:
        return _parse_arrays(path, ext)
    except FileNotFoundError:
        raise
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error, MatReadError, ValueError, KeyError) as exc:
        if isinstance(exc, EventError):
            raise
        raise CorruptFileError(f"{path}: not a readable {kind[ext]} file ({type(exc).__name__}: {exc})") from exc


def _parse_arrays(path: Path, ext: str) -> dict[str, Any]:
    if ext == ".npz":
        with np.load(path, allow_pickle=False) as z:
            keys = list(z.keys())
            if not any(k in keys for k in _ALIASES["x"]) and any(k.startswith("events/") for k in keys):
                return {k.split("/", 1)[1]: z[k] for k in keys if k.startswith("events/")}
            if len(keys) == 1 and z[keys[0]].ndim == 2 and z[keys[0]].shape[1] == 4:
                a = z[keys[0]]
                return {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "p": a[:, 3]}
            fields = {n for f in "txyp" for n in _ALIASES[f]}
            out: dict[str, Any] = {}
            for k in keys:  # the event fields mapped (np.savez) or streamed (np.savez_compressed), else read whole
                member = _npz_member(path, k) if k in fields else None
                out[k] = member if member is not None else z[k]
            return out
    if ext in (".h5", ".hdf5"):
        import h5py

        f = h5py.File(path, "r")  # kept open: its event datasets are read block by block (closed with the file)
        grp = f["events"] if "events" in f and isinstance(f["events"], h5py.Group) else f
        fields = {n for fl in "txyp" for n in _ALIASES[fl]}
        out = {
            k: (grp[k] if k in fields and grp[k].ndim == 1 else grp[k][()])
            for k in grp.keys()
            if isinstance(grp[k], h5py.Dataset)
        }
        if "events" in f and isinstance(f["events"], h5py.Dataset) and f["events"].ndim == 2:
            a = f["events"][()]
            out = {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "p": a[:, 3]}
        return out
    if ext == ".mat":
        from scipy.io import loadmat

        try:
            raw = loadmat(path)
        except IndexError as exc:  # scipy's parser indexes past the end of a garbage header
            raise CorruptFileError(f"{path}: not a readable MATLAB .mat file (IndexError: {exc})") from exc
        m = {k: v for k, v in raw.items() if not k.startswith("__")}
        if "events" in m and m["events"].ndim == 2 and m["events"].shape[1] == 4:
            a = m["events"]
            return {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "p": a[:, 3]}
        return {k: np.asarray(v).reshape(-1) for k, v in m.items()}
    if ext == ".txt":
        a = np.loadtxt(path, dtype=np.float64, ndmin=2)
        if a.size == 0:
            return {k: np.zeros(0) for k in "txyp"}
        if a.shape[1] < 4:
            raise EventError(f"{path}: expected lines 't x y p', got {a.shape[1]} columns")
        return {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "p": a[:, 3]}
    raise AssertionError(ext)  # _load_arrays checked the extension


@overload
def read_events(
    path: str | Path,
    t_unit: str | None = None,
    width: int | None = None,
    height: int | None = None,
    *,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
    return_unit: Literal[False] = False,
) -> EventStream: ...


@overload
def read_events(
    path: str | Path,
    t_unit: str | None = None,
    width: int | None = None,
    height: int | None = None,
    *,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
    return_unit: Literal[True],
) -> tuple[EventStream, str, str]: ...


@overload
def read_events(
    path: str | Path,
    t_unit: str | None = None,
    width: int | None = None,
    height: int | None = None,
    *,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
    return_unit: bool,
) -> EventStream | tuple[EventStream, str, str]: ...


def read_events(
    path: str | Path,
    t_unit: str | None = None,
    width: int | None = None,
    height: int | None = None,
    *,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
    return_unit: bool = False,
) -> EventStream | tuple[EventStream, str, str]:
    """Read an event file into an ``EventStream``.

    Args:
        path: .npz, .h5/.hdf5, .txt (t x y p, seconds), .mat or .aedat4.
        t_unit: "s", "ms", "us" or "ns"; None infers it (see ``infer_time_unit``) and logs it.
            ``.txt`` defaults to seconds; ``.aedat4`` is always microseconds.
        width, height: sensor size. When the file declares one (``width``/``height`` or
            ``sensor_size`` keys, an AEDAT4 stream) a different given size raises
            ``EventError`` naming both; without either the declared size is used, else
            max coordinate + 1 (logged as a warning).
        infer: without ``t_unit``, ``infer(t_raw) -> (unit, reason)`` tells the unit from the file's
            raw times [M] instead of ``infer_time_unit`` (a capture compares them with its frames).
        return_unit: return (events, unit, reason) instead.

    Raises:
        EventError: unreadable file, missing field, ambiguous time unit (give ``t_unit``),
            a given size that differs from the declared one, malformed events.
        FileNotFoundError: no such file.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"event file not found: {path}")
    if path.suffix.lower() == ".aedat4":
        ev = read_aedat4(path).events
        _check_declared(path, (ev.width, ev.height), width, height)
        return (ev, "us", "AEDAT4 timestamps are microseconds") if return_unit else ev
    arrs = _load_arrays(path)
    try:
        ev, unit, reason = _events_of(path, arrs, t_unit, width, height, infer)
    finally:
        _close(arrs)
    return (ev, unit, reason) if return_unit else ev


def _events_of(
    path: Path,
    arrs: dict[str, Any],
    t_unit: str | None,
    width: int | None,
    height: int | None,
    infer: Callable[[np.ndarray], tuple[str, str]] | None,
) -> tuple[EventStream, str, str]:
    """``read_events`` on an event file's arrays (``_load_arrays``) -> (events, unit, reason)."""
    keys = set(arrs)
    t_raw, x, y, p = (_field(arrs[_pick(keys, f, str(path))]) for f in "txyp")
    if t_unit is None:
        if path.suffix.lower() == ".txt":
            unit, reason = "s", "events.txt stores seconds"
        else:
            try:
                unit, reason = (infer or infer_time_unit)(_whole(t_raw))
            except CorruptFileError:  # names the file already (a streamed .npz member)
                raise
            except EventError as exc:
                raise EventError(f"{path}: {exc}") from None
        log.info("read_events %s: time unit %r (inferred: %s)", path, unit, reason)
    else:
        unit, reason = t_unit, "given"
    if unit not in UNITS_US:
        raise EventError(f"{path}: t_unit must be one of {sorted(UNITS_US)}, got {unit!r}")
    t_us = _Lazy(t_raw.raw, lambda a: to_us(a, unit, str(path)), np.int64)
    t_min = int(t_us.min()) if len(t_us) else 0
    t0 = t_min if t_min > _EPOCH_US else 0
    w_f = next((int(np.asarray(arrs[k]).reshape(-1)[0]) for k in ("width", "sensor_width") if k in arrs), None)
    h_f = next((int(np.asarray(arrs[k]).reshape(-1)[0]) for k in ("height", "sensor_height") if k in arrs), None)
    if "sensor_size" in arrs:
        ss = np.asarray(arrs["sensor_size"]).reshape(-1)
        h_f, w_f = int(ss[0]), int(ss[1])  # (H, W) as in E-NeRF / tonic
    if w_f is not None and h_f is not None:
        _check_declared(path, (w_f, h_f), width, height)
    if width is None or height is None:
        if w_f is None or h_f is None:
            w_f = int(x.max()) + 1 if len(x) else 1
            h_f = int(y.max()) + 1 if len(y) else 1
            log.warning("read_events %s: no sensor size in the file; using %dx%d from the coordinates", path, w_f, h_f)
        width = width if width is not None else w_f
        height = height if height is not None else h_f
    try:
        ev = EventStream(t_us, x, y, p, int(width), int(height), t0=t0)  # type: ignore[arg-type]  # read per block
    except CorruptFileError:  # names the file already (a streamed .npz member)
        raise
    except EventError as exc:
        raise EventError(f"{path}: {exc}") from exc
    return ev, unit, reason


def _close(arrs: dict[str, Any]) -> None:
    """Close what an event file's fields kept open: an HDF5 file (for its datasets), streamed .npz members."""
    for v in arrs.values():
        if isinstance(v, _NpzStream):
            v.close()
    for v in arrs.values():
        if type(v).__module__.startswith("h5py"):
            cast(Any, v).file.close()
            break


def _field(a) -> _Lazy:
    """An event field, flattened (a 2-D [M, 1] array) and read block by block."""
    if isinstance(a, np.ndarray):
        a = a.reshape(-1)
    elif getattr(a, "ndim", 1) != 1:
        a = np.asarray(a[()]).reshape(-1)
    return _Lazy(a)


def _whole(f: _Lazy) -> np.ndarray:
    """A field as one array (a memory map or an array as read; an h5py dataset read whole), for the
    time unit's inference. A field streamed from a compressed .npz gives, without holding it whole,
    the values a unit is inferred from (``_NpzStream.summary``: minimum, maximum, first non-integer
    and first non-finite value)."""
    if isinstance(f.raw, np.ndarray):
        return f.raw
    if not isinstance(f.raw, _NpzStream):
        return np.asarray(f.raw[()])
    s = f.raw.summary()
    return np.array(list(s.values()), f.dtype) if s else np.zeros(min(len(f), 1), f.dtype)


def _check_declared(path: Path, declared: tuple[int, int], width: int | None, height: int | None) -> None:
    """A given sensor size must match the one the file declares."""
    w, h = declared
    if (width is not None and int(width) != w) or (height is not None and int(height) != h):
        raise EventError(
            f"{path}: the file declares a {w}x{h} (WxH) sensor but {width}x{height} was given "
            "(the frame's size): the events do not belong to this frame"
        )


@dataclass
class AedatRecording:
    """An AEDAT4 recording: events and APS frames on one clock (microseconds from ``t0``)."""

    events: EventStream  # t relative to t0
    frames: np.ndarray  # [F, H, W, D] float32 linear [0, 1]
    exposures: np.ndarray  # [F, 2] float64 seconds (exposure begin, end) relative to t0
    t0: int  # us, the raw timestamp subtracted
    # the sensor's Bayer pattern (``edi.cfa``, the events' = the frames' pixel grid) as DV recorded
    # it (``DV_COLOR_FILTER``), or None: DV recorded none (a grey DAVIS)
    cfa: str | None = None


AEDAT4_MAGIC = b"#!AER-DAT4.0\r\n"
# DV's DAVIS module (dv-runtime modules/davis) writes a colour DAVIS's filter on the events
# stream's info node as the int attribute ``colorFilter`` = libcaer's ``apsColorFilter`` - 1:
# 0 RGBG, 1 GRGB, 2 GBGR, 3 BGRG. libcaer names the filters clockwise from pixel (0, 0)
# (frame_utils.c ``colorKeys``: RGBG is R at (0, 0), G at (1, 0), B at (1, 1), G at (0, 1)); in
# edi.cfa's order of pixels (0, 0), (1, 0), (0, 1), (1, 1) they are:
DV_COLOR_FILTER = {0: "RGGB", 1: "GRBG", 2: "GBRG", 3: "BGGR"}
_IOHEADER_INFO_FIELD = 2  # IOHeader table: compression, dataTablePosition, infoNode (a string)


def _aedat4_info_xml(path: Path) -> str:
    """The ``infoNode`` XML of an AEDAT4 file's IOHeader (a size-prefixed flatbuffer after the
    magic line), every offset checked against the header's size, so that a damaged header is a
    CorruptFileError here and never reaches the decoder (which panics on one)."""

    def bad(what: str) -> CorruptFileError:
        return CorruptFileError(f"{path}: damaged AEDAT4 header ({what})")

    with open(path, "rb") as fh:
        head = fh.read(len(AEDAT4_MAGIC) + 4)
        if not head.startswith(AEDAT4_MAGIC):
            raise CorruptFileError(f"{path}: not an AEDAT4 file (no '#!AER-DAT4.0' line)")
        if len(head) < len(AEDAT4_MAGIC) + 4:
            raise bad("the file ends inside it")
        (size,) = struct.unpack_from("<I", head, len(AEDAT4_MAGIC))
        fb = fh.read(size) if size <= 1 << 24 else b""
    if len(fb) != size or size < 12:
        raise bad(f"it says {size} bytes; the file holds {len(fb)} of them")

    def u32(off: int, fmt: str = "<I") -> int:
        n = struct.calcsize(fmt)
        if off < 0 or off + n > size:
            raise bad(f"offset {off} outside its {size} bytes")
        return int(struct.unpack_from(fmt, fb, off)[0])

    if fb[4:8] != b"IOHE":
        raise bad(f"file identifier {bytes(fb[4:8])!r}, expected b'IOHE'")
    table = u32(0)
    vtable = table - u32(table, "<i")
    vt_size, table_size = u32(vtable, "<H"), u32(vtable + 2, "<H")
    if vt_size < 4 + 2 * (_IOHEADER_INFO_FIELD + 1) or vtable + vt_size > size or table + table_size > size:
        raise bad(f"its table ({table_size} bytes at {table}, vtable {vt_size} at {vtable}) does not fit {size} bytes")
    field = u32(vtable + 4 + 2 * _IOHEADER_INFO_FIELD, "<H")
    if field == 0:
        raise bad("no info node")
    string = table + field + u32(table + field)
    length = u32(string)
    if string + 4 + length > size:
        raise bad(f"info node of {length} bytes runs past its {size} bytes")
    try:
        return fb[string + 4 : string + 4 + length].decode("utf-8")
    except UnicodeDecodeError:
        raise bad("info node is not text") from None


def read_aedat4_info(path: str | Path) -> dict[str, dict[str, str]]:
    """The streams an AEDAT4 file declares, read from its header alone: per stream id, its
    ``typeIdentifier`` (``EVTS``, ``FRME``, ...), ``originalOutputName`` and the attributes of its
    ``info`` node (``sizeX``, ``sizeY``, ``colorFilter``, ...), all as strings.

    Raises:
        CorruptFileError: naming the file: not AEDAT4, or a damaged header.
    """
    path = Path(path)
    text = _aedat4_info_xml(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise CorruptFileError(f"{path}: damaged AEDAT4 header (info node: {exc})") from None
    streams: dict[str, dict[str, str]] = {}
    for node in root.iter("node"):
        if node.get("path", "").rstrip("/").rsplit("/", 2)[-2:-1] != ["outInfo"]:
            continue  # only /.../outInfo/<id>/
        attrs = {a.get("key", ""): a.text or "" for a in node.findall("attr")}
        info = node.find("node[@name='info']")
        if info is not None:
            attrs.update({a.get("key", ""): a.text or "" for a in info.findall("attr")})
        streams[node.get("name", "")] = attrs
    return streams


def _aedat4_cfa(streams: dict[str, dict[str, str]], path: Path) -> str | None:
    """The Bayer pattern DV recorded on the (first) events stream, or None."""
    ev = next((s for s in streams.values() if s.get("typeIdentifier") == "EVTS"), None)
    if ev is None or "colorFilter" not in ev:
        return None
    value = ev["colorFilter"].strip()
    if not value.lstrip("-").isdigit() or int(value) not in DV_COLOR_FILTER:
        raise CorruptFileError(
            f"{path}: events stream info colorFilter is {value!r}; DV writes 0..3 ({DV_COLOR_FILTER})"
        )
    return DV_COLOR_FILTER[int(value)]


def _is_panic(exc: BaseException) -> bool:
    """A Rust panic raised through pyo3 (``pyo3_runtime.PanicException``, a BaseException)."""
    return type(exc).__name__ == "PanicException"


@contextlib.contextmanager
def _native_stderr_held() -> Iterator[list[bool]]:
    """Hold what native code writes to file descriptor 2 (a Rust panic's message and backtrace)
    while the block runs; it is written out afterwards unless the block put False in the list."""
    keep: list[bool] = [True]
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no real fd 2 (embedded, captured): nothing to hold
        yield keep
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield keep
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            if keep[0]:
                tmp.seek(0)
                held = tmp.read()
                if held:
                    sys.stderr.write(held.decode("utf-8", "replace"))


_MISSING = (
    "reading .aedat4 needs the 'aedat' package: pip install aedat "
    "(or pip install 'ebad[aedat]'); dv-processing also works: pip install dv-processing"
)


def _frame_pixels(px: np.ndarray, fmt: str) -> np.ndarray:
    a = np.asarray(px)
    scale = 255.0 if a.dtype == np.uint8 else 65535.0 if a.dtype == np.uint16 else 1.0
    a = a.astype(np.float32) / np.float32(scale)
    if a.ndim == 2:
        return a[..., None]
    if fmt.upper().startswith("BGR"):
        a = a[..., [2, 1, 0]]
    return a[..., :3] if a.shape[-1] >= 3 else a


def _sensor_size(streams: dict, path: Path) -> tuple[int, int]:
    """(width, height) of an AEDAT4 file's event stream, else of its frame stream."""
    size = next(((s["width"], s["height"]) for s in streams.values() if s.get("type") == "events"), None)
    if size is None:
        size = next(((s["width"], s["height"]) for s in streams.values() if s.get("type") == "frame"), None)
    if size is None:
        raise EventError(f"{path}: no events or frame stream")
    return size


def read_aedat4(path: str | Path) -> AedatRecording:
    """Read events and frames of an AEDAT4 file (``aedat``, else ``dv-processing``).

    The header is read here first (``read_aedat4_info``): a damaged one is a CorruptFileError
    before the decoder sees it, and the colour filter DV records for a colour DAVIS becomes
    ``AedatRecording.cfa`` (``DV_COLOR_FILTER``). A decoder that panics on a damaged packet
    (a Rust panic, not an Exception) is a one-line CorruptFileError too; its own message to
    stderr is dropped.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"AEDAT4 file not found: {path}")
    try:
        import aedat
    except ImportError:
        try:
            import dv_processing as dv  # noqa: F401
        except ImportError:
            raise ImportError(_MISSING) from None
        return _read_aedat4_dv(path)
    cfa = _aedat4_cfa(read_aedat4_info(path), path)
    ev_chunks: list[np.ndarray] = []
    frames: list[np.ndarray] = []
    exps: list[tuple[int, int]] = []
    with _native_stderr_held() as keep:
        try:
            dec = aedat.Decoder(str(path))
            streams = dec.id_to_stream()
        except BaseException as exc:
            if not (_is_panic(exc) or isinstance(exc, (OSError, RuntimeError, ValueError))):
                raise
            keep[0] = False
            raise CorruptFileError(
                f"{path}: not a readable AEDAT4 file ({type(exc).__name__}: {str(exc).splitlines()[0]})"
            ) from None
        try:
            for pk in dec:
                if "events" in pk:
                    ev_chunks.append(pk["events"])
                elif "frame" in pk:
                    fr = pk["frame"]
                    frames.append(_frame_pixels(fr["pixels"], fr.get("format", "L")))
                    exps.append((int(fr["exposure_begin_t"]), int(fr["exposure_end_t"])))
        except BaseException as exc:  # "failed to fill whole buffer" on a truncated file; a panic on a damaged one
            if not (_is_panic(exc) or isinstance(exc, (OSError, RuntimeError))):
                raise
            keep[0] = False
            raise CorruptFileError(
                f"{path}: truncated or corrupt AEDAT4 file after {len(ev_chunks)} event and "
                f"{len(frames)} frame packets ({type(exc).__name__}: {str(exc).splitlines()[0]})"
            ) from None
    size = _sensor_size(streams, path)
    evs = np.concatenate(ev_chunks) if ev_chunks else None
    t_raw = evs["t"].astype(np.int64) if evs is not None else np.zeros(0, np.int64)
    candidates = [int(t_raw[0])] if len(t_raw) else []
    if exps:
        candidates.append(min(e[0] for e in exps))
    t0 = min(candidates) if candidates else 0
    if evs is not None:
        order = np.argsort(t_raw, kind="stable")  # packets may interleave slightly
        names = evs.dtype.names
        assert names is not None  # a structured array: its fields "t", "x", "y" were read above
        pol = evs[names[3]]
        events = EventStream(
            t_raw[order], evs["x"][order], evs["y"][order], pol[order].astype(np.int8), size[0], size[1], t0=t0
        )
    else:
        events = EventStream.empty(size[0], size[1])
    if frames:
        fr_arr = np.stack(frames).astype(np.float32)
        ex = (np.asarray(exps, dtype=np.int64) - t0).astype(np.float64) * 1e-6
    else:
        fr_arr = np.zeros((0, size[1], size[0], 1), np.float32)
        ex = np.zeros((0, 2))
    return AedatRecording(events, fr_arr, ex, t0, cfa)


def _read_aedat4_dv(path: Path) -> AedatRecording:  # pragma: no cover - needs dv-processing
    import dv_processing as dv

    cfa = _aedat4_cfa(read_aedat4_info(path), path)

    rec = dv.io.MonoCameraRecording(str(path))
    evs, frames, exps = [], [], []
    while rec.isRunning():
        batch = rec.getNextEventBatch() if rec.isEventStreamAvailable() else None
        if batch is not None:
            evs.append(batch.numpy())
        fr = rec.getNextFrame() if rec.isFrameStreamAvailable() else None
        if fr is not None:
            frames.append(_frame_pixels(fr.image, "BGR" if fr.image.ndim == 3 else "L"))
            begin = int(fr.timestamp)
            exps.append((begin, begin + int(fr.exposure.total_seconds() * 1e6)))
        if batch is None and fr is None:
            break
    w, h = rec.getEventResolution()
    a = np.concatenate(evs) if evs else None
    t_raw = a["timestamp"].astype(np.int64) if a is not None else np.zeros(0, np.int64)
    t0 = min([int(t_raw[0])] if len(t_raw) else [] + [e[0] for e in exps] or [0])
    events = (
        EventStream(t_raw, a["x"], a["y"], a["polarity"], w, h, t0=t0) if a is not None else EventStream.empty(w, h)
    )
    ex = (np.asarray(exps, np.int64) - t0) * 1e-6 if exps else np.zeros((0, 2))
    fr_arr = np.stack(frames) if frames else np.zeros((0, h, w, 1), np.float32)
    return AedatRecording(events, fr_arr, ex, t0, cfa)
