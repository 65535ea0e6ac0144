"""Compact event storage (issue 31): int32/uint16/int8 streams, block-wise checks, views, lazy reading."""

import tracemalloc

import numpy as np
import pytest

import edi.events as E
from edi import EventError, EventStream
from edi.io import read_events


def _stream(n: int, seed: int = 0, span_us: int = 60_000_000, w: int = 346, h: int = 260):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, span_us, n)).astype(np.int64)
    return t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n)


def test_stored_dtypes_are_compact_and_widen_when_needed():
    t, x, y, p = _stream(100)
    ev = EventStream(t, x, y, p, 346, 260)
    assert (ev.t.dtype, ev.x.dtype, ev.y.dtype, ev.p.dtype) == (np.int32, np.uint16, np.uint16, np.int8)
    assert ev.nbytes() == 9 * 100
    assert ev.t.tolist() == t.tolist() and ev.p.tolist() == np.where(p > 0, 1, -1).tolist()
    long = EventStream([0, 2**30], [0, 0], [0, 0], [1, 1], 1, 1)  # 17.9 minutes: int64
    assert long.t.dtype == np.int64 and long.t.tolist() == [0, 2**30]
    assert EventStream([-(2**30), 2**30 - 1], [0, 0], [0, 0], [1, 1], 1, 1).t.dtype == np.int32
    wide = EventStream([0], [70_000], [0], [1], 70_001, 1)
    assert wide.x.dtype == np.int32 and wide.y.dtype == np.uint16 and wide.x.tolist() == [70_000]


def test_block_wise_checks_match_whole_stream(monkeypatch):
    monkeypatch.setattr(E, "CHUNK", 4)
    t, x, y, p = _stream(37, seed=1)
    small = EventStream(t, x, y, p, 346, 260)
    monkeypatch.setattr(E, "CHUNK", 1 << 17)
    big = EventStream(t, x, y, p, 346, 260)
    for k in "txyp":
        assert np.array_equal(getattr(small, k), getattr(big, k))
    monkeypatch.setattr(E, "CHUNK", 4)
    t2 = t.copy()
    t2[8] = t2[7] - 1  # the first event of the third block is earlier than the last of the second
    with pytest.raises(EventError, match=r"'t' is not sorted: index 8 "):
        EventStream(t2, x, y, p, 346, 260)
    x2 = x.copy()
    x2[13] = 346
    with pytest.raises(EventError, match=r"'x' is outside the sensor at index 13: 346 not in \[0, 346\)"):
        EventStream(t, x2, y, p, 346, 260)
    p2 = p.copy()
    p2[:] = 1
    p2[2], p2[30] = 0, -1  # {0, 1} in the first block, -1 in the eighth: neither convention
    with pytest.raises(EventError, match=r"'p' must be in .*index 30"):
        EventStream(t, x, y, p2, 346, 260)


def test_windows_are_views_and_search_copies_nothing():
    t, x, y, p = _stream(1_000_000, seed=2)
    ev = EventStream(t, x, y, p, 346, 260)
    i0, i1 = ev.window(10.0, 10.05)
    win = ev[i0:i1]
    assert len(win) == int(((t >= 10_000_000) & (t < 10_050_000)).sum()) > 0
    assert all(np.shares_memory(getattr(win, k), getattr(ev, k)) for k in "txyp")
    assert ev.index_range(2**40, 2**41) == (len(ev), len(ev)) and ev.index_range(-(2**40), 0) == (0, 0)
    tracemalloc.start()
    for _ in range(10):
        ev.window(10.0, 10.05)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 100_000  # a search in another dtype would cast the 4 MB of times (8 MB as int64)


@pytest.mark.parametrize("kind", ["npz", "npz_compressed", "h5"])
def test_reading_converts_block_wise(tmp_path, kind):
    n = 300_000
    t, x, y, p = _stream(n, seed=3)
    t = t + 1_600_000_000_000_000  # raw epoch microseconds
    path = tmp_path / ("ev.h5" if kind == "h5" else "ev.npz")
    fields = dict(t=t, x=x.astype(np.int64), y=y.astype(np.int64), p=p.astype(np.int64))  # 32 bytes an event
    if kind == "npz":
        np.savez(path, **fields)
    elif kind == "npz_compressed":
        np.savez_compressed(path, **fields)
    else:
        h5py = pytest.importorskip("h5py")
        with h5py.File(path, "w") as f:
            for k, v in fields.items():
                f.create_dataset(f"events/{k}", data=v)
    tracemalloc.start()
    ev = read_events(path, width=346, height=260)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert ev.t0 == int(t.min()) and ev.t.dtype == np.int32
    assert (
        np.array_equal(ev.t, t - t.min()) and np.array_equal(ev.x, x) and np.array_equal(ev.p, np.where(p > 0, 1, -1))
    )
    # the stored stream (9 bytes an event) and blocks of CHUNK events; a compressed member is decompressed
    # whole (32 bytes an event), a stored one mapped, an HDF5 dataset read per block (reading every field
    # whole and converting took over 80 bytes an event)
    limit = 9 * n + (32 * n if kind == "npz_compressed" else 0) + 6e6
    assert peak < limit, f"{kind}: {peak / 1e6:.1f} MB"
