"""ROS1 bags of the rpg_dvs_ros driver: a fixture bag written here with rosbags' writer."""

import sys
from pathlib import Path

import numpy as np
import pytest

from scenes import CaptureError, load
from scenes.readers import detect_layout

rosbags = pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")

from scenes.rosbag import decode_event_array, dvs_typestore, exposure_window_us  # noqa: E402

H, W = 5, 7
T0_NS = 1_600_000_000_123_456_000  # epoch nanoseconds, whole microseconds like the driver
FRAME_STAMPS_US = [20_000, 60_000, 100_000]  # mid-exposure, relative to T0
EXPOSURES_US = [10_001, 8_000, 0]  # an odd one, and a sharp frame


def _time(store, ns):
    return store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _header(store, ns, seq=0):
    return store.types["std_msgs/msg/Header"](seq=seq, stamp=_time(store, ns), frame_id="davis")


def _events(seed=0, m=300):
    rng = np.random.default_rng(seed)
    t_us = np.sort(rng.integers(0, 120_000, m))
    # events on the window edges of frame 0: start is in, end is out
    s, e = FRAME_STAMPS_US[0] - EXPOSURES_US[0] // 2, FRAME_STAMPS_US[0] - EXPOSURES_US[0] // 2 + EXPOSURES_US[0]
    t_us = np.sort(np.concatenate([t_us, [s - 1, s, e - 1, e]]))
    return t_us, rng.integers(0, W, len(t_us)), rng.integers(0, H, len(t_us)), rng.integers(0, 2, len(t_us))


def write_bag(path: Path, exposure_topic=True, camera_info=True, encoding="mono8", seed=0, chunk=50):
    """A bag as the davis_ros_driver records it: /dvs/events (EventArray chunks), /dvs/image_raw,
    /dvs/exposure after each image, /dvs/camera_info."""
    from rosbags.rosbag1 import Writer

    store = dvs_typestore()
    Event, EventArray = store.types["dvs_msgs/msg/Event"], store.types["dvs_msgs/msg/EventArray"]
    Image, Int32 = store.types["sensor_msgs/msg/Image"], store.types["std_msgs/msg/Int32"]
    t_us, x, y, p = _events(seed)
    rng = np.random.default_rng(seed + 1)
    d = 3 if encoding in ("rgb8", "bgr8") else 1
    frames = rng.integers(0, 256, (len(FRAME_STAMPS_US), H, W, d)).astype(np.uint8)
    msgs = []  # (bag time ns, kind, message)
    for i in range(0, len(t_us), chunk):
        sl = slice(i, i + chunk)
        evs = [
            Event(x=int(a), y=int(b), ts=_time(store, T0_NS + int(t) * 1000), polarity=bool(c))
            for a, b, t, c in zip(x[sl], y[sl], t_us[sl], p[sl])
        ]
        ns = T0_NS + int(t_us[sl][0]) * 1000
        msgs.append((ns, "events", EventArray(header=_header(store, ns), height=H, width=W, events=evs)))
    for k, s in enumerate(FRAME_STAMPS_US):
        ns = T0_NS + s * 1000
        data = frames[k][..., ::-1] if encoding == "bgr8" else frames[k]
        msgs.append(
            (
                ns + 1,
                "image",
                Image(
                    header=_header(store, ns, k),
                    height=H,
                    width=W,
                    encoding=encoding,
                    is_bigendian=0,
                    step=W * d,
                    data=data.reshape(-1).copy(),
                ),
            )
        )
        if exposure_topic:
            msgs.append((ns + 2, "exposure", Int32(data=EXPOSURES_US[k])))
    if camera_info:
        info = store.types["sensor_msgs/msg/CameraInfo"](
            header=_header(store, T0_NS),
            height=H,
            width=W,
            distortion_model="plumb_bob",
            D=np.array([0.01, -0.002, 0.0, 0.0, 0.0]),
            K=np.array([6.0, 0, 3.2, 0, 6.5, 2.1, 0, 0, 1]),
            R=np.eye(3).reshape(-1),
            P=np.zeros(12),
            binning_x=0,
            binning_y=0,
            roi=store.types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )
        msgs.append((T0_NS, "camera_info", info))
    topics = {
        "events": ("/dvs/events", "dvs_msgs/msg/EventArray"),
        "image": ("/dvs/image_raw", "sensor_msgs/msg/Image"),
        "exposure": ("/dvs/exposure", "std_msgs/msg/Int32"),
        "camera_info": ("/dvs/camera_info", "sensor_msgs/msg/CameraInfo"),
    }
    with Writer(path) as writer:
        conns = {
            k: writer.add_connection(t, mt, typestore=store)
            for k, (t, mt) in topics.items()
            if any(m[1] == k for m in msgs)
        }
        for ns, kind, msg in sorted(msgs, key=lambda m: m[0]):
            writer.write(conns[kind], ns, store.serialize_ros1(msg, topics[kind][1]))
    return dict(t_us=t_us, x=x, y=y, p=p, frames=frames)


def test_bag_loads_events_frames_exposures_and_calibration(tmp_path):
    truth = write_bag(tmp_path / "rec.bag")
    assert detect_layout(tmp_path / "rec.bag") == "rosbag1"
    cap = load(tmp_path / "rec.bag", undistort=False)
    np.testing.assert_array_equal(cap.frames, truth["frames"].astype(np.float32) / np.float32(255))
    first = min(FRAME_STAMPS_US[0] - EXPOSURES_US[0] // 2, int(truth["t_us"][0]))
    assert cap.events.t0 == T0_NS // 1000 + first
    np.testing.assert_array_equal(cap.events.t, truth["t_us"] - first)
    np.testing.assert_array_equal(cap.events.x, truth["x"])
    np.testing.assert_array_equal(cap.events.y, truth["y"])
    np.testing.assert_array_equal(cap.events.p, np.where(truth["p"] > 0, 1, -1))
    np.testing.assert_allclose(cap.K, [[6.0, 0, 3.7], [0, 6.5, 2.6], [0, 0, 1]])  # +0.5 px: our pixel centres
    np.testing.assert_array_equal(cap.distortion, [0.01, -0.002, 0, 0, 0])
    assert cap.c2w is None and cap.meta["exposure_source"] == "/dvs/exposure"
    assert load(tmp_path / "rec.bag").meta["undistorted"] is True


def test_image_stamp_is_mid_exposure(tmp_path):
    truth = write_bag(tmp_path / "rec.bag")
    cap = load(tmp_path / "rec.bag", undistort=False)
    t0 = cap.events.t0 - T0_NS // 1000
    for k, (s, e) in enumerate(zip(FRAME_STAMPS_US, EXPOSURES_US)):
        start = s - e // 2
        np.testing.assert_allclose(cap.exposures[k], [(start - t0) * 1e-6, (start + e - t0) * 1e-6], atol=1e-12)
        a, b = np.round(cap.exposures[k] * 1e6).astype(np.int64) + t0
        assert (a + b) - 2 * s in (0, 1)  # the stamp is the middle (half a microsecond off for an odd exposure)
    # the window of frame 0 holds exactly the events in [start, start + e): the start in, the end out
    s, e = FRAME_STAMPS_US[0] - EXPOSURES_US[0] // 2, EXPOSURES_US[0]
    inside = int(np.count_nonzero((truth["t_us"] >= s) & (truth["t_us"] < s + e)))
    assert len(cap.events.slice_time(*cap.exposures[0])) == inside
    assert np.count_nonzero(truth["t_us"] == s) >= 1 and np.count_nonzero(truth["t_us"] == s + e) >= 1
    np.testing.assert_array_equal(exposure_window_us(np.array([100]), np.array([7])), [[97, 104]])


def test_events_decoded_with_numpy_match_rosbags_deserialiser(tmp_path):
    from rosbags.rosbag1 import Reader

    write_bag(tmp_path / "rec.bag")
    store = dvs_typestore()
    with Reader(tmp_path / "rec.bag") as reader:
        conn = next(c for c in reader.connections if c.topic == "/dvs/events")
        for _, _, raw in reader.messages(connections=[conn]):
            arr, w, h = decode_event_array(raw)
            msg = store.deserialize_ros1(raw, conn.msgtype)
            assert (w, h) == (msg.width, msg.height) == (W, H)
            assert [(e.x, e.y, e.ts.sec, e.ts.nanosec, e.polarity) for e in msg.events] == [
                (int(a["x"]), int(a["y"]), int(a["sec"]), int(a["nsec"]), bool(a["p"])) for a in arr
            ]


def test_bgr_colour_frames(tmp_path):
    truth = write_bag(tmp_path / "rec.bag", encoding="bgr8")
    cap = load(tmp_path / "rec.bag", undistort=False)
    np.testing.assert_array_equal(cap.frames, truth["frames"].astype(np.float32) / np.float32(255))


def test_without_exposure_topic_the_exposure_must_be_given(tmp_path):
    write_bag(tmp_path / "rec.bag", exposure_topic=False, camera_info=False)
    with pytest.raises(CaptureError, match=r"rec\.bag.*exposure.*--exposure-us"):
        load(tmp_path / "rec.bag")
    cap = load(tmp_path / "rec.bag", exposure_us=4000)
    np.testing.assert_allclose(np.diff(cap.exposures, axis=1), 0.004)
    assert cap.meta["K_guessed"] and cap.meta["exposure_source"] == "exposure_us argument"
    with pytest.raises(CaptureError, match="exposure_us"):
        load(tmp_path / "rec.bag", exposure_us=-3)


def test_truncated_bag_names_the_file(tmp_path):
    write_bag(tmp_path / "rec.bag")
    data = (tmp_path / "rec.bag").read_bytes()
    (tmp_path / "cut.bag").write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match=r"cut\.bag.*unreadable ROS bag"):
        load(tmp_path / "cut.bag")


def test_missing_rosbags_says_how_to_install(tmp_path, monkeypatch):
    write_bag(tmp_path / "rec.bag")
    for mod in ("rosbags", "rosbags.rosbag1", "rosbags.typesys"):
        monkeypatch.setitem(sys.modules, mod, None)
    with pytest.raises(CaptureError, match=r"rec\.bag.*rosbags.*pip install 'ebad\[ros\]'"):
        load(tmp_path / "rec.bag")
