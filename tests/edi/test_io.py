"""Event readers: npz / h5 / txt / mat layouts, time units, epoch times, AEDAT4."""
import sys

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
    with pytest.raises(ValueError, match="unknown event file type"):
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
    with pytest.raises(ValueError, match="t_unit must be one of"):
        read_events(tmp_path / "d.npz", t_unit="days")


def test_aedat4_missing_package_says_what_to_install(tmp_path, monkeypatch):
    f = tmp_path / "x.aedat4"
    f.write_bytes(b"")
    monkeypatch.setitem(sys.modules, "aedat", None)
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    with pytest.raises(ImportError, match="pip install aedat"):
        read_aedat4(f)
