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

__all__ = ["EventStream", "EventError", "seconds_to_us", "events_in_window"]


def _to_numpy(a: Any, name: str) -> np.ndarray:
    if hasattr(a, "detach"):  # torch tensor
        a = a.detach().cpu().numpy()
    try:
        arr = np.asarray(a)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise EventError(f"events field '{name}' cannot be converted to an array: {exc}") from exc
    if arr.ndim != 1:
        raise EventError(f"events field '{name}' must be 1-D, got shape {tuple(arr.shape)}")
    return arr


def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _as_int_coords(a: np.ndarray, name: str) -> np.ndarray:
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            raise EventError(f"events field '{name}' has a non-finite value at index {_first_bad(bad)}")
        frac = a != np.round(a)
        if frac.any():
            i = _first_bad(frac)
            raise EventError(f"events field '{name}' must hold integer pixel indices; index {i} is {a[i]!r}")
        return a.astype(np.int32)
    if a.dtype.kind not in "iub":
        raise EventError(f"events field '{name}' must be numeric, got dtype {a.dtype}")
    return a.astype(np.int32)


@dataclass(frozen=True, eq=False)
class EventStream:
    """A sorted stream of M polarity events on a ``width`` x ``height`` sensor.

    Args:
        t: [M] int64 microseconds (float arrays are accepted when they hold whole microseconds).
        x: [M] column indices in [0, width).
        y: [M] row indices in [0, height).
        p: [M] polarities, {0, 1} or {-1, +1}; stored as {-1, +1}.
        width, height: sensor size in pixels.
        t0: microseconds subtracted from ``t`` (int64, exact) before storing; use it for raw
            epoch timestamps. The stored ``t`` is relative; ``t0`` is kept for reference.

    Raises:
        EventError: unequal lengths, unsorted or non-finite times, events outside the sensor,
            polarities outside {0, 1} / {-1, +1}. The message names the field and the first
            offending index.
    """

    t: np.ndarray  # [M] int64 us
    x: np.ndarray  # [M] int32
    y: np.ndarray  # [M] int32
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
        # times: exact int64 microseconds
        if t_a.dtype.kind == "f":
            bad = ~np.isfinite(t_a)
            if bad.any():
                raise EventError(f"events field 't' has a non-finite value at index {_first_bad(bad)}")
            if len(t_a) and np.abs(t_a).max() > 2**52:
                raise EventError("events field 't' is a float too large to hold exact microseconds; pass int64")
            t_i = np.round(t_a).astype(np.int64)
        elif t_a.dtype.kind in "iu":
            t_i = t_a.astype(np.int64)
        else:
            raise EventError(f"events field 't' must be numeric, got dtype {t_a.dtype}")
        t_i = t_i - np.int64(t0)
        if len(t_i) > 1:
            dec = np.diff(t_i) < 0
            if dec.any():
                i = _first_bad(dec) + 1
                raise EventError(
                    f"events field 't' is not sorted: index {i} ({t_i[i]}) comes before index {i - 1} ({t_i[i - 1]})"
                )
        x_i = _as_int_coords(x_a, "x")
        y_i = _as_int_coords(y_a, "y")
        for arr, name, lim in ((x_i, "x", int(width)), (y_i, "y", int(height))):
            bad = (arr < 0) | (arr >= lim)
            if bad.any():
                i = _first_bad(bad)
                raise EventError(
                    f"events field '{name}' is outside the sensor at index {i}: {arr[i]} not in [0, {lim})"
                )
        if p_a.dtype == bool:
            p_a = p_a.astype(np.int8)
        p_f = np.asarray(p_a, dtype=np.float64)
        zero_one = np.isin(p_f, (0.0, 1.0))
        pm_one = np.isin(p_f, (-1.0, 1.0))
        if zero_one.all():
            p_i = np.where(p_f > 0, 1, -1).astype(np.int8)
        elif pm_one.all():
            p_i = p_f.astype(np.int8)
        else:
            i = _first_bad(~(zero_one | pm_one)) if (~(zero_one | pm_one)).any() else _first_bad(~zero_one)
            raise EventError(f"events field 'p' must be in {{0, 1}} or {{-1, +1}}; index {i} is {p_a[i]!r}")
        object.__setattr__(self, "t", t_i)
        object.__setattr__(self, "x", x_i)
        object.__setattr__(self, "y", y_i)
        object.__setattr__(self, "p", p_i)
        object.__setattr__(self, "width", int(width))
        object.__setattr__(self, "height", int(height))
        object.__setattr__(self, "t0", int(t0))
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
        i0 = int(np.searchsorted(self.t, np.int64(t_start_us), side="left"))
        i1 = int(np.searchsorted(self.t, np.int64(t_end_us), side="left"))
        return i0, max(i0, i1)

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
