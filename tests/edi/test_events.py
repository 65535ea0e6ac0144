import numpy as np
import pytest

from edi import EventError, EventStream


def test_polarity_zero_one_is_stored_signed():
    ev = EventStream([0, 1, 2], [0, 1, 2], [0, 0, 1], [0, 1, 1], width=3, height=2)
    assert ev.p.tolist() == [-1, 1, 1]
    assert ev.t.dtype == np.int64


def test_raw_epoch_times_are_reduced_exactly():
    t = np.array([1_600_000_000_000_001, 1_600_000_000_000_003], dtype=np.int64)
    ev = EventStream(t, [0, 0], [0, 0], [1, 1], 1, 1, t0=1_600_000_000_000_000)
    assert ev.t.tolist() == [1, 3]


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(t=[0, 2, 1]), r"'t' is not sorted: index 2"),
        (dict(x=[0, 5, 0]), r"'x' is outside the sensor at index 1"),
        (dict(y=[-1, 0, 0]), r"'y' is outside the sensor at index 0"),
        (dict(p=[0, 2, 1]), r"'p' must be in"),
        (dict(t=[0.0, np.nan, 2.0]), r"'t' has a non-finite value at index 1"),
        (dict(x=[0, 1]), r"equal lengths"),
    ],
)
def test_bad_events_name_field_and_index(kw, match):
    args = dict(t=[0, 1, 2], x=[0, 1, 2], y=[0, 0, 1], p=[1, -1, 1])
    args.update(kw)
    with pytest.raises(EventError, match=match):
        EventStream(args["t"], args["x"], args["y"], args["p"], width=3, height=2)


def test_slice_and_counts():
    ev = EventStream([0, 10, 20, 30], [0, 1, 1, 0], [0, 0, 0, 0], [1, -1, -1, 1], 2, 1)
    w = ev.slice_time(5e-6, 30e-6)
    assert len(w) == 2 and w.t.tolist() == [10, 20]
    assert ev.count_image().tolist() == [[2, -2]]
    assert ev.count_image(-1).tolist() == [[0, 2]]
    assert len(ev.slice_time(1.0, 2.0)) == 0
