"""Compressed .npz event files (``np.savez_compressed``) are decompressed block by block into the
compact stream (``edi.io._NpzStream``), never a whole member at once."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest

from edi.errors import CorruptFileError
from edi.io import _npz_member, _NpzStream, read_events
from tests.edi._helpers import run_python

M = 3000  # a few blocks of a small CHUNK


@pytest.fixture(autouse=True)
def small_chunk(monkeypatch):
    import edi.events

    monkeypatch.setattr(edi.events, "CHUNK", 512)


def _fields(t_dtype, xy_dtype, p_kind: str, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 40, M)) + 1_600_000_000_000_000
    if np.dtype(t_dtype).kind == "f":
        t = (t - t[0]) * 1e-6 + 0.25  # seconds
    p = rng.integers(0, 2, M)
    return {
        "t": t.astype(t_dtype),
        "x": rng.integers(0, 346, M).astype(xy_dtype),
        "y": rng.integers(0, 260, M).astype(xy_dtype),
        "p": p.astype(bool) if p_kind == "bool" else (2 * p - 1).astype(np.int8),
    }


@pytest.mark.parametrize(
    "t_dtype, xy_dtype, p_kind",
    [
        (np.int64, np.int64, "bool"),
        (np.uint64, np.uint16, "pm1"),
        (np.float64, np.float32, "pm1"),
        (">i8", ">i2", "bool"),
    ],
)
def test_compressed_read_equals_np_load(tmp_path, t_dtype, xy_dtype, p_kind):
    f = _fields(t_dtype, xy_dtype, p_kind)
    np.savez_compressed(tmp_path / "c.npz", **f)
    np.savez(tmp_path / "u.npz", **f)
    with np.load(tmp_path / "c.npz") as z:  # every member streamed, read forward, backward and past its end
        for k in "txyp":
            s = _npz_member(tmp_path / "c.npz", k)
            assert isinstance(s, _NpzStream) and s.dtype == z[k].dtype and len(s) == M
            for a, b in [(0, 700), (700, 1400), (5, 9), (2990, 4000), (0, M)]:
                np.testing.assert_array_equal(s[a:b], z[k][a:b])
            assert s[-1] == z[k][-1] and s[17] == z[k][17]
            s.close()
    comp = read_events(tmp_path / "c.npz", width=346, height=260)
    ref = read_events(tmp_path / "u.npz", width=346, height=260)  # memory-mapped: the same conversion
    for k in "txyp":
        np.testing.assert_array_equal(getattr(comp, k), getattr(ref, k))
        assert getattr(comp, k).dtype == getattr(ref, k).dtype
    assert comp.t0 == ref.t0
    # the size from the coordinates and the time unit inferred: from the streamed summary
    c2, unit, _ = read_events(tmp_path / "c.npz", return_unit=True)
    r2, unit_ref, _ = read_events(tmp_path / "u.npz", return_unit=True)
    assert (unit, c2.width, c2.height, c2.t0) == (unit_ref, r2.width, r2.height, r2.t0)
    np.testing.assert_array_equal(c2.t, r2.t)


def _member_bytes(arr: np.ndarray, header: dict) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    buf.write(np.ascontiguousarray(arr).tobytes())
    return buf.getvalue()


def _write_zip(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for k, v in members.items():
            zf.writestr(k + ".npy", v)


def test_fortran_order_column_is_read_and_a_matrix_left_to_numpy(tmp_path):
    f = _fields(np.int64, np.int64, "bool")
    members = {}
    for k, v in f.items():  # [M, 1] columns declared Fortran-ordered: the same memory as C order
        members[k] = _member_bytes(v, {"descr": v.dtype.str, "fortran_order": True, "shape": (M, 1)})
    _write_zip(tmp_path / "f.npz", members)
    ev = read_events(tmp_path / "f.npz", width=346, height=260)
    np.testing.assert_array_equal(ev.x, f["x"])
    np.testing.assert_array_equal(ev.t, f["t"] - f["t"][0])
    # a Fortran [M, 4] matrix is no plain field: numpy reads it (the single-array [t, x, y, p] layout)
    mat = np.asfortranarray(np.stack([f["t"], f["x"], f["y"], f["p"]], 1))
    np.savez_compressed(tmp_path / "m.npz", events=mat)
    assert _npz_member(tmp_path / "m.npz", "events") is None
    np.testing.assert_array_equal(read_events(tmp_path / "m.npz", width=346, height=260).y, f["y"])


def test_truncated_or_corrupt_member_names_the_file_and_field(tmp_path):
    f = _fields(np.int64, np.int64, "bool")
    members = {k: _member_bytes(v, {"descr": v.dtype.str, "fortran_order": False, "shape": (M,)}) for k, v in f.items()}
    x = f["x"]  # x declares M values and stores M - 100
    members["x"] = _member_bytes(x[:-100], {"descr": x.dtype.str, "fortran_order": False, "shape": (M,)})
    _write_zip(tmp_path / "short.npz", members)
    with pytest.raises(CorruptFileError) as exc:
        read_events(tmp_path / "short.npz", width=346, height=260)
    msg = str(exc.value)
    assert msg.startswith(f"{tmp_path / 'short.npz'}: events field 'x'") and "truncated" in msg and "2900 stored" in msg
    assert "\n" not in msg
    # damaged deflate data inside the t member (the zip directory intact)
    np.savez_compressed(tmp_path / "bad.npz", **f)
    raw = bytearray((tmp_path / "bad.npz").read_bytes())
    with zipfile.ZipFile(tmp_path / "bad.npz") as zf:
        info = zf.getinfo("t.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    mid = start + info.compress_size * 2 // 3  # past what the .npy header's read decompresses
    for i in range(mid, mid + 60):
        raw[i] ^= 0x5A
    (tmp_path / "bad.npz").write_bytes(bytes(raw))
    with pytest.raises(CorruptFileError, match=r"bad\.npz: events field 't' of the \.npz is corrupt"):
        read_events(tmp_path / "bad.npz", width=346, height=260, t_unit="us")


_PEAK = """
import sys
import numpy as np
from edi.io import read_events
read_events(sys.argv[2])  # the reader's own imports (scipy's) before the baseline
open("/proc/self/clear_refs", "w").write("5")  # the peak (VmHWM) from now on
base = status("VmRSS")
ev = read_events(sys.argv[1])
print((status("VmHWM") - base) * 1024, ev.nbytes(), len(ev))
"""


@pytest.mark.slow
def test_compressed_read_peak_memory_is_about_the_compact_stream(tmp_path):
    # 2M events as int64 fields: 64 MB decompressed whole, 18 MB stored compactly. Read whole per
    # field (before) the peak grew by >= 80 MB; streamed it stays near the stored arrays.
    n = 2_000_000
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.integers(0, 3, n))
    xy = rng.integers(0, 200, (2, n))
    np.savez_compressed(tmp_path / "big.npz", t=t, x=xy[0], y=xy[1], p=rng.integers(0, 2, n), width=200, height=200)
    np.savez_compressed(tmp_path / "small.npz", t=t[:10], x=xy[0, :10], y=xy[1, :10], p=np.ones(10, int))
    del t, xy
    grew, stored, count = (int(v) for v in run_python(_PEAK, str(tmp_path / "big.npz"), str(tmp_path / "small.npz")))
    assert count == n and stored == 9 * n
    assert grew < stored + 20 * 2**20, (grew / 2**20, stored / 2**20)
