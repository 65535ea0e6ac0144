import numpy as np
import pytest

from edi import EventError, EventStream


def test_polarity_zero_one_is_stored_signed():
    ev = EventStream([0, 1, 2], [0, 1, 2], [0, 0, 1], [0, 1, 1], width=3, height=2)
    assert ev.p.tolist() == [-1, 1, 1]
    assert ev.t.dtype == np.int32 and ev.x.dtype == ev.y.dtype == np.uint16 and ev.p.dtype == np.int8


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


def test_seconds_to_us_rounds_to_nearest_ties_to_even():
    from edi import InputError, seconds_to_us

    assert seconds_to_us(0.04) == 40_000 and isinstance(seconds_to_us(0.04), int)
    assert seconds_to_us(0.0400004) == 40_000 and seconds_to_us(0.0400006) == 40_001
    assert seconds_to_us(2.5e-6) == 2 and seconds_to_us(3.5e-6) == 4  # ties to even
    assert seconds_to_us(-1.2e-6) == -1
    ks = np.arange(0, 10**7, 9973)
    np.testing.assert_array_equal(seconds_to_us(ks * 1e-6), ks)  # k * 1e-6 s comes back as k
    assert seconds_to_us(np.array([[0.1, 0.2]])).dtype == np.int64
    with pytest.raises(InputError, match="finite"):
        seconds_to_us(float("nan"))


def test_window_rule_at_the_boundaries():
    from edi import events_in_window

    ev = EventStream([10, 20, 20, 30, 40], [0] * 5, [0] * 5, [1] * 5, 1, 1)
    assert events_in_window(ev, 20e-6, 30e-6) == (1, 3)  # both events at t_start in, the one at t_end out
    assert events_in_window(ev, 30e-6, 40e-6) == (3, 4)  # ... and in the next window
    assert events_in_window(ev, 20e-6, 20e-6) == (1, 1)  # empty window
    assert events_in_window(ev, 41e-6, 99e-6) == (5, 5)
    assert ev.window(20e-6, 30e-6) == (1, 3)
    assert len(ev.slice_time(20e-6, 30e-6)) == 2
    # adjacent windows partition the stream
    edges = [0.0, 15e-6, 20e-6, 30e-6, 45e-6]
    counts = [np.subtract(*events_in_window(ev, a, b)[::-1]) for a, b in zip(edges[:-1], edges[1:])]
    assert counts == [1, 0, 2, 2]
