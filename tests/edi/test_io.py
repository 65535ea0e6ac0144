"""Event readers: npz / h5 / txt / mat layouts, time units, epoch times, AEDAT4."""

import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from scipy.io import savemat

from edi import EventError, infer_time_unit, read_aedat4, read_events

T_US = np.array([10, 20, 35, 50], dtype=np.int64)
X = np.array([0, 3, 1, 2])
Y = np.array([1, 0, 2, 2])
P = np.array([1, 0, 0, 1])


def check(ev, t_us=T_US, w=4, h=3):
    assert ev.t.tolist() == t_us.tolist() and ev.x.tolist() == X.tolist() and ev.y.tolist() == Y.tolist()
    assert ev.p.tolist() == [1, -1, -1, 1] and (ev.width, ev.height) == (w, h)


def test_npz_root_and_events_group(tmp_path):
    np.savez(tmp_path / "a.npz", x=X, y=Y, t=T_US, p=P, width=4, height=3)
    check(read_events(tmp_path / "a.npz"))
    np.savez(tmp_path / "b.npz", **{"events/x": X, "events/y": Y, "events/t": T_US, "events/p": P})
    check(read_events(tmp_path / "b.npz", width=4, height=3))


def test_h5_group_and_nanoseconds(tmp_path):
    with h5py.File(tmp_path / "e.h5", "w") as f:
        g = f.create_group("events")
        g["x"], g["y"], g["p"] = X, Y, P
        g["t"] = T_US * 1000  # nanoseconds, unit given
    ev, unit, _ = read_events(tmp_path / "e.h5", t_unit="ns", width=4, height=3, return_unit=True)
    check(ev)
    assert unit == "ns"


def test_txt_seconds_and_mat(tmp_path):
    lines = "\n".join(f"{t * 1e-6:.6f} {x} {y} {p}" for t, x, y, p in zip(T_US, X, Y, P))
    (tmp_path / "events.txt").write_text(lines + "\n")
    ev, unit, _ = read_events(tmp_path / "events.txt", width=4, height=3, return_unit=True)
    check(ev)
    assert unit == "s"
    savemat(tmp_path / "e.mat", {"events": np.stack([T_US, X, Y, P], axis=1)})
    check(read_events(tmp_path / "e.mat"))  # size from the coordinates (logged)


def test_epoch_microseconds_made_relative_exactly(tmp_path):
    base = 1_589_163_147_364_965
    np.savez(tmp_path / "a.npz", x=X, y=Y, t=T_US + base, p=P)
    ev = read_events(tmp_path / "a.npz", width=4, height=3)
    assert ev.t0 == base + 10 and ev.t.tolist() == (T_US - 10).tolist()


def test_infer_time_unit():
    assert infer_time_unit(np.array([0.1, 0.2]))[0] == "s"
    assert infer_time_unit(np.array([0, 5 * 10**10]))[0] == "ns"
    assert infer_time_unit(np.array([0, 10**6]))[0] == "us"


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        read_events(tmp_path / "nope.npz")
    (tmp_path / "a.csv").write_text("1,2,3,4\n")
    with pytest.raises(EventError, match="unknown event file type"):
        read_events(tmp_path / "a.csv")
    np.savez(tmp_path / "b.npz", x=X, y=Y, p=P)
    with pytest.raises(EventError, match="no events field 't'"):
        read_events(tmp_path / "b.npz")
    np.savez(tmp_path / "c.npz", x=X, y=Y, t=T_US[::-1], p=P)
    with pytest.raises(EventError, match=r"c.npz: events field 't' is not sorted"):
        read_events(tmp_path / "c.npz", width=4, height=3)
    np.savez(tmp_path / "d.npz", x=X, y=Y, t=T_US, p=P)
    with pytest.raises(EventError, match="'x' is outside the sensor"):
        read_events(tmp_path / "d.npz", width=2, height=3)
    with pytest.raises(EventError, match="t_unit must be one of"):
        read_events(tmp_path / "d.npz", t_unit="days")


def test_aedat4_missing_package_says_what_to_install(tmp_path, monkeypatch):
    f = tmp_path / "x.aedat4"
    f.write_bytes(b"")
    monkeypatch.setitem(sys.modules, "aedat", None)
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    with pytest.raises(ImportError, match="pip install aedat"):
        read_aedat4(f)


# --- time units from magnitude and span (issue 13, row 2) -------------------------------------

EPOCH_NS = 1_700_000_000_000_000_000  # Nov 2023 in ns since 1970


@pytest.mark.parametrize(
    "t, unit",
    [
        (EPOCH_NS + np.arange(0, 5 * 10**9, 10**6), "ns"),  # epoch ns spanning 5 s (read as us before)
        (EPOCH_NS // 1000 + np.arange(0, 5 * 10**6, 10**3), "us"),  # epoch us
        (EPOCH_NS // 10**6 + np.arange(0, 5000), "ms"),  # epoch ms
        (np.arange(0, 10**6, 100), "us"),  # relative, 1 s in us
        (np.arange(0, 5 * 10**10, 10**7), "ns"),  # relative, 50 s in ns
        (np.array([0.5, 1.25]), "s"),
    ],
)
def test_time_unit_from_magnitude_and_span(t, unit):
    got, reason = infer_time_unit(np.asarray(t))
    assert got == unit, reason


@pytest.mark.parametrize(
    "t, match",
    [
        (np.arange(0, 5 * 10**9, 10**6), r"could be 4999 s in microseconds or 4.999 s in nanoseconds"),
        (np.array([10**13, 10**13 + 5]), "no date between 1990 and 2100"),
    ],
)
def test_ambiguous_time_units_are_refused_unless_given(tmp_path, t, match):
    np.savez(tmp_path / "a.npz", x=np.zeros(len(t), int), y=np.zeros(len(t), int), t=t, p=np.ones(len(t), int))
    with pytest.raises(EventError, match=match) as exc:
        read_events(tmp_path / "a.npz", width=1, height=1)
    assert "a.npz" in str(exc.value) and "t_unit" in str(exc.value)
    ev, unit, reason = read_events(tmp_path / "a.npz", t_unit="us", width=1, height=1, return_unit=True)
    assert unit == "us" and reason == "given" and len(ev) == len(t)


def test_epoch_nanoseconds_keep_their_duration(tmp_path):
    t = EPOCH_NS + np.array([0, 1_000_000, 4_000_000_000])  # 0, 1 ms, 4 s
    np.savez(tmp_path / "a.npz", x=[0, 0, 0], y=[0, 0, 0], t=t, p=[1, 1, 1])
    ev, unit, _ = read_events(tmp_path / "a.npz", width=1, height=1, return_unit=True)
    assert unit == "ns" and ev.t.tolist() == [0, 1000, 4_000_000] and ev.t0 == EPOCH_NS // 1000


def test_nanoseconds_round_to_nearest_microsecond_ties_to_even():
    from edi.io import to_us

    t = np.array([1499, 1500, 1501, 2500, 2501, -1500])
    assert to_us(t, "ns").tolist() == [1, 2, 2, 2, 3, -2]
    assert to_us(np.array([0.0000015, 1.25]), "s").tolist() == [2, 1_250_000]


# --- corrupt files (issue 13, row 9) and declared sizes (row 6) --------------------------------


@pytest.mark.parametrize("ext, kind", [(".npz", "NumPy .npz"), (".h5", "HDF5"), (".mat", "MATLAB .mat")])
@pytest.mark.parametrize("content", ["garbage", "truncated"])
def test_corrupt_event_files_raise_one_event_error(tmp_path, ext, kind, content):
    good = tmp_path / f"good{ext}"
    if ext == ".npz":
        np.savez(good, x=X, y=Y, t=T_US, p=P)
    elif ext == ".h5":
        with h5py.File(good, "w") as f:
            f["x"], f["y"], f["t"], f["p"] = X, Y, T_US, P
    else:
        savemat(good, {"events": np.stack([T_US, X, Y, P], axis=1)})
    data = good.read_bytes()
    bad = tmp_path / f"bad{ext}"
    bad.write_bytes(b"not an event file " * 8 if content == "garbage" else data[: len(data) // 2])
    with pytest.raises(EventError, match=rf"bad{ext}: not a readable {kind} file") as exc:
        read_events(bad, width=4, height=3)
    assert "\n" not in str(exc.value)


def test_given_size_must_match_the_declared_one(tmp_path):
    np.savez(tmp_path / "a.npz", x=X, y=Y, t=T_US, p=P, width=4, height=3)
    check(read_events(tmp_path / "a.npz", width=4, height=3))
    with pytest.raises(EventError, match=r"a.npz: the file declares a 4x3 \(WxH\) sensor but 5x3 was given"):
        read_events(tmp_path / "a.npz", width=5, height=3)
    np.savez(tmp_path / "b.npz", x=X, y=Y, t=T_US, p=P)  # no declared size: the given one is used
    check(read_events(tmp_path / "b.npz", width=6, height=5), w=6, h=5)


STREET = Path(__file__).parents[2].parent / "shared" / "data" / "davis346_street" / "davis346_street.aedat4"


@pytest.mark.skipif(not STREET.exists(), reason=f"real data not found: {STREET}")
def test_truncated_aedat4_raises_one_event_error(tmp_path):
    pytest.importorskip("aedat")
    data = STREET.read_bytes()
    bad = tmp_path / "cut.aedat4"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(EventError, match=r"cut.aedat4: truncated or corrupt AEDAT4 file"):
        read_aedat4(bad)
