"""Event streams: validated, sorted DAVIS-style polarity events.

Convention: ``t`` is int64 microseconds from the start of the capture, ``x`` and ``y``
are pixel indices (column, row), ``p`` is stored as int8 in {-1, +1}. Raw epoch
timestamps (AEDAT4 gives ~1.6e15 us) are reduced by ``t0`` in integer arithmetic
before anything becomes a float.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from .errors import EventError

__all__ = ["EventStream", "EventError", "seconds_to_us", "events_in_window", "coord_dtype", "time_dtype"]


def _to_numpy(a: Any, name: str) -> np.ndarray:
    if hasattr(a, "detach"):  # torch tensor
        a = a.detach().cpu().numpy()
    if not isinstance(a, np.ndarray) and getattr(a, "ndim", None) == 1 and hasattr(a, "dtype"):
        return a  # a field read block by block (an h5py dataset, ``edi.io``'s lazy fields): sliced per CHUNK below
    try:
        arr = np.asarray(a)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise EventError(f"events field '{name}' cannot be converted to an array: {exc}") from exc
    if arr.ndim != 1:
        raise EventError(f"events field '{name}' must be 1-D, got shape {tuple(arr.shape)}")
    return arr


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


#: events converted and checked per block of this many (bounds the temporaries of a large stream)
CHUNK = 1 << 17
#: stored times are int32 when every relative time lies in [-T32, T32) (spans to 2^31 us stay exact in int32
#: arithmetic; 2^30 us is 17.9 minutes), else int64
T32 = 1 << 30


def _blocks(n: int):
    for a in range(0, n, CHUNK):
        yield a, min(n, a + CHUNK)


def coord_dtype(size: int) -> np.dtype:
    """The stored dtype of pixel indices on a sensor side of ``size`` pixels: uint16 when it fits."""
    return np.dtype(np.uint16) if size <= 1 << 16 else np.dtype(np.int32)


def time_dtype(first: int, last: int) -> np.dtype:
    """The stored dtype of relative times from ``first`` to ``last`` us: int32 when they fit, else int64."""
    return np.dtype(np.int32) if -T32 <= first and last < T32 else np.dtype(np.int64)


def _t_block(a: np.ndarray, t0: int) -> np.ndarray:
    """Raw times (float whole microseconds or integers) of one block -> int64 us relative to t0."""
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            raise EventError(f"events field 't' has a non-finite value at index {_first_bad(bad)}")
        if len(a) and np.abs(a).max() > 2**52:
            raise EventError("events field 't' is a float too large to hold exact microseconds; pass int64")
        out = np.round(a).astype(np.int64)
    elif a.dtype.kind in "iub":
        out = a.astype(np.int64)
    else:
        raise EventError(f"events field 't' must be numeric, got dtype {a.dtype}")
    if t0:
        out -= np.int64(t0)
    return out


def _coords_into(a: np.ndarray, out: np.ndarray, name: str, lim: int) -> None:
    """Pixel indices a [M] checked (whole numbers inside [0, lim)) and written into ``out``, per block."""
    if a.dtype.kind not in "iubf":
        raise EventError(f"events field '{name}' must be numeric, got dtype {a.dtype}")
    for s, e in _blocks(len(a)):
        b = a[s:e]
        if b.dtype.kind == "f":
            bad = ~np.isfinite(b)
            if bad.any():
                raise EventError(f"events field '{name}' has a non-finite value at index {s + _first_bad(bad)}")
            frac = b != np.round(b)
            if frac.any():
                i = _first_bad(frac)
                raise EventError(f"events field '{name}' must hold integer pixel indices; index {s + i} is {b[i]!r}")
        bad = (b < 0) | (b >= lim)
        if bad.any():
            i = _first_bad(bad)
            raise EventError(
                f"events field '{name}' is outside the sensor at index {s + i}: {int(b[i])} not in [0, {lim})"
            )
        out[s:e] = b


def _polarity_into(a: np.ndarray, out: np.ndarray) -> None:
    """Polarities a [M] in {0, 1} or {-1, +1} (bool: {0, 1}) written into ``out`` as int8 {-1, +1}."""
    if a.dtype.kind not in "iubf":
        raise EventError(f"events field 'p' must be numeric, got dtype {a.dtype}")
    any_neg = any_zero = False
    for s, e in _blocks(len(a)):
        b = a[s:e].view(np.int8) if a.dtype == bool else a[s:e]
        if b.dtype.kind == "f" and not (b == np.round(b)).all():
            bad = b != np.round(b)
        elif len(b) and (b.min() < -1 or b.max() > 1):
            bad = (b < -1) | (b > 1)
        else:
            bad = None
        if bad is not None:
            i = s + _first_bad(bad)
            raise EventError(f"events field 'p' must be in {{0, 1}} or {{-1, +1}}; index {i} is {a[i]!r}")
        out[s:e] = b
        any_neg = any_neg or bool(len(b) and out[s:e].min() < 0)
        any_zero = any_zero or np.count_nonzero(out[s:e]) < e - s
    if any_neg and any_zero:
        i = _first_bad(out == -1)
        raise EventError(f"events field 'p' must be in {{0, 1}} or {{-1, +1}}; index {i} is {a[i]!r}")
    if any_zero:  # {0, 1} -> {-1, +1}
        for s, e in _blocks(len(out)):
            blk = out[s:e]
            blk *= 2
            blk -= 1


@dataclass(frozen=True, eq=False)
class EventStream:
    """A sorted stream of M polarity events on a ``width`` x ``height`` sensor.

    Args:
        t: [M] integer microseconds (float arrays are accepted when they hold whole microseconds).
        x: [M] column indices in [0, width).
        y: [M] row indices in [0, height).
        p: [M] polarities, {0, 1} or {-1, +1}; stored as {-1, +1}.
        width, height: sensor size in pixels.
        t0: microseconds subtracted from ``t`` (int64, exact) before storing; use it for raw
            epoch timestamps. The stored ``t`` is relative; ``t0`` is kept for reference.

    Storage (9 bytes an event where 17 were): ``t`` int32 when every relative time lies in
    [-2^30, 2^30) us (``time_dtype``; 17.9 minutes), else int64; ``x``/``y`` uint16 (int32 on a
    sensor side above 65536, ``coord_dtype``); ``p`` int8. Inputs are converted and checked per
    block of ``CHUNK`` events, so no full-length temporary is made beyond the stored arrays.
    Slicing (``events[i0:i1]``, ``window``) gives views, not copies.

    Raises:
        EventError: unequal lengths, unsorted or non-finite times, events outside the sensor,
            polarities outside {0, 1} / {-1, +1}. The message names the field and the first
            offending index.
    """

    t: np.ndarray  # [M] int32 (or int64) us
    x: np.ndarray  # [M] uint16 (or int32)
    y: np.ndarray  # [M] uint16 (or int32)
    p: np.ndarray  # [M] int8 in {-1, +1}
    width: int
    height: int
    t0: int = 0
    _checked: bool = field(default=False, repr=False)

    def __init__(
        self,
        t: npt.ArrayLike,
        x: npt.ArrayLike,
        y: npt.ArrayLike,
        p: npt.ArrayLike,  # [M] each
        width: int,
        height: int,
        t0: int = 0,
    ) -> None:
        if int(width) <= 0 or int(height) <= 0:
            raise EventError(f"sensor size must be positive, got width={width}, height={height}")
        t_a, x_a, y_a, p_a = (_to_numpy(a, n) for a, n in ((t, "t"), (x, "x"), (y, "y"), (p, "p")))
        lens = {"t": len(t_a), "x": len(x_a), "y": len(y_a), "p": len(p_a)}
        if len(set(lens.values())) != 1:
            raise EventError(f"events fields must have equal lengths, got {lens}")
        M = len(t_a)
        t0 = int(t0)
        # times: exact integer microseconds, sorted; the stored dtype from the first and last (sorted) times
        try:
            ends = _t_block(np.concatenate([t_a[0:1], t_a[M - 1 : M]]), t0) if M else None
        except EventError:  # the block loop below names the offending index
            ends = None
        t_i = np.empty(M, np.int64 if ends is None else time_dtype(int(ends[0]), int(ends[-1])))
        prev: int | None = None
        for s, e in _blocks(M):
            b = _t_block(t_a[s:e], t0)
            dec = np.flatnonzero(b[1:] < b[:-1])
            if prev is not None and b[0] < prev:
                i = s
                raise EventError(
                    f"events field 't' is not sorted: index {i} ({b[0]}) comes before index {i - 1} ({prev})"
                )
            if dec.size:
                i = int(dec[0]) + 1
                raise EventError(
                    f"events field 't' is not sorted: index {s + i} ({b[i]}) comes before "
                    f"index {s + i - 1} ({b[i - 1]})"
                )
            t_i[s:e] = b
            prev = int(b[-1])
        x_i = np.empty(M, coord_dtype(int(width)))
        y_i = np.empty(M, coord_dtype(int(height)))
        _coords_into(x_a, x_i, "x", int(width))
        _coords_into(y_a, y_i, "y", int(height))
        p_i = np.empty(M, np.int8)
        _polarity_into(p_a, p_i)
        object.__setattr__(self, "t", t_i)
        object.__setattr__(self, "x", x_i)
        object.__setattr__(self, "y", y_i)
        object.__setattr__(self, "p", p_i)
        object.__setattr__(self, "width", int(width))
        object.__setattr__(self, "height", int(height))
        object.__setattr__(self, "t0", t0)
        object.__setattr__(self, "_checked", True)

    @classmethod
    def empty(cls, width: int, height: int) -> EventStream:
        z = np.zeros(0, np.int64)
        return cls(z, z, z, z, width, height)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        """Span from the first to the last event, seconds."""
        return 0.0 if len(self) == 0 else float(self.t[-1] - self.t[0]) * 1e-6

    def index_range(self, t_start_us: int, t_end_us: int) -> tuple[int, int]:
        """Indices [i0, i1) of events with t_start_us <= t < t_end_us; O(log M)."""
        i0 = int(np.searchsorted(self.t, self._as_t(t_start_us), side="left"))
        i1 = int(np.searchsorted(self.t, self._as_t(t_end_us), side="left"))
        return i0, max(i0, i1)

    def _as_t(self, t_us: int) -> np.integer:
        """A time in the stored dtype, clamped to its range (a search with another dtype would cast the
        whole array)."""
        info = np.iinfo(self.t.dtype)
        return self.t.dtype.type(min(max(int(t_us), info.min), info.max))

    def nbytes(self) -> int:
        """Bytes held by the stored arrays."""
        return int(self.t.nbytes + self.x.nbytes + self.y.nbytes + self.p.nbytes)

    def window(self, t_start: float, t_end: float) -> tuple[int, int]:
        """Index bounds [i0, i1) of the events of the exposure window [t_start, t_end) in
        seconds: the project's one window rule (see ``events_in_window``)."""
        return self.index_range(seconds_to_us(t_start), seconds_to_us(t_end))

    def slice_time(self, t_start: float, t_end: float) -> EventStream:
        """Events with t_start <= t < t_end, both in seconds (relative to the stream's t0)."""
        i0, i1 = self.window(t_start, t_end)
        return self[i0:i1]

    def __getitem__(self, sl: slice) -> EventStream:
        if not isinstance(sl, slice):
            raise TypeError("EventStream supports slicing by index ranges only")
        out = object.__new__(EventStream)
        for name in ("t", "x", "y", "p"):
            object.__setattr__(out, name, getattr(self, name)[sl])
        for name in ("width", "height", "t0", "_checked"):
            object.__setattr__(out, name, getattr(self, name))
        return out

    def count_image(self, polarity: int | None = None) -> np.ndarray:
        """[H, W] int64 event counts: signed (polarity None), or of one polarity (+1 or -1)."""
        if polarity is None:
            w = self.p.astype(np.int64)
        elif polarity in (1, -1):
            w = (self.p == polarity).astype(np.int64)
        else:
            from .errors import InputError

            raise InputError(f"polarity must be None, +1 or -1, got {polarity!r}")
        flat = np.bincount(self.y.astype(np.int64) * self.width + self.x, weights=w, minlength=self.width * self.height)
        return flat.astype(np.int64).reshape(self.height, self.width)

    def times_s(self) -> np.ndarray:
        """[M] float64 seconds (relative times, so float64 is exact to well below 1 us)."""
        return self.t.astype(np.float64) * 1e-6


def seconds_to_us(t: Any) -> Any:
    """Seconds -> integer microseconds: the project's one conversion.

    Rounding: to the nearest microsecond, an exact half to the even neighbour (``np.rint``),
    after multiplying by 1e6 in float64; so 0.0400004 s -> 40000 us and 0.0400006 s ->
    40001 us, and a time written as k * 1e-6 s comes back as k. A float gives an ``int``,
    an array an int64 array of the same shape. Non-finite values raise ``InputError``.
    """
    a = np.asarray(t, dtype=np.float64)
    if not np.isfinite(a).all():
        from .errors import InputError

        raise InputError(f"seconds_to_us: times must be finite, got {t!r}")
    us = np.rint(a * 1e6).astype(np.int64)
    return int(us) if us.ndim == 0 else us


def events_in_window(events: EventStream, t_start: float, t_end: float) -> tuple[int, int]:
    """Index bounds [i0, i1) of the events in the exposure window, by binary search.

    The project's one window rule: an event belongs to [t_start, t_end) (seconds, on the
    stream's clock) when ``seconds_to_us(t_start) <= t < seconds_to_us(t_end)``: an event at
    the start of an exposure is in, one at its end is out (and in the next window that
    starts there). ``events[i0:i1]`` is the window's stream; i1 == i0 when it is empty.
    """
    return events.window(t_start, t_end)
