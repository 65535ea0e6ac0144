"""Colour DAVIS captures read and stated (issue 29 section 1), and bad calibration in ROS bags."""

from pathlib import Path

import numpy as np
import pytest

from scenes import CaptureError, load

H, W = 4, 6
T0_NS = 1_600_000_000_000_000_000
STAMPS_US = [20_000, 60_000]
EXPOSURE_US = 8_000


def write_bag(path: Path, encoding="mono8", K=(6.0, 0, 3.2, 0, 6.5, 2.1, 0, 0, 1), D=(0.0,) * 5, seed=0):
    """A small rpg_dvs_ros bag: events, images of ``encoding``, exposures and a CameraInfo with ``K``, ``D``."""
    pytest.importorskip("rosbags", reason="the 'ros' extra (rosbags) is not installed")
    from rosbags.rosbag1 import Writer

    from scenes.rosbag import dvs_typestore

    store = dvs_typestore()

    def stamp(ns):
        return store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def header(ns):
        return store.types["std_msgs/msg/Header"](seq=0, stamp=stamp(ns), frame_id="davis")

    rng = np.random.default_rng(seed)
    t_us = np.sort(rng.integers(0, 80_000, 40))
    Event = store.types["dvs_msgs/msg/Event"]
    evs = [
        Event(x=int(x), y=int(y), ts=stamp(T0_NS + int(t) * 1000), polarity=bool(p))
        for x, y, t, p in zip(rng.integers(0, W, 40), rng.integers(0, H, 40), t_us, rng.integers(0, 2, 40))
    ]
    d = 3 if encoding.startswith(("rgb", "bgr")) else 1
    frames = rng.integers(0, 256, (len(STAMPS_US), H, W, d)).astype(np.uint8)
    msgs = [
        (T0_NS, "events", store.types["dvs_msgs/msg/EventArray"](header=header(T0_NS), height=H, width=W, events=evs))
    ]
    for k, s in enumerate(STAMPS_US):
        ns = T0_NS + s * 1000
        img = store.types["sensor_msgs/msg/Image"](
            header=header(ns), height=H, width=W, encoding=encoding, is_bigendian=0, step=W * d,
            data=frames[k].reshape(-1).copy(),
        )  # fmt: skip
        msgs += [(ns + 1, "image", img), (ns + 2, "exposure", store.types["std_msgs/msg/Int32"](data=EXPOSURE_US))]
    roi = store.types["sensor_msgs/msg/RegionOfInterest"]
    info = store.types["sensor_msgs/msg/CameraInfo"](
        header=header(T0_NS), height=H, width=W, distortion_model="plumb_bob", D=np.array(D, float),
        K=np.array(K, float), R=np.eye(3).reshape(-1), P=np.zeros(12), binning_x=0, binning_y=0,
        roi=roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )  # fmt: skip
    msgs.append((T0_NS, "camera_info", info))
    topics = {
        "events": ("/dvs/events", "dvs_msgs/msg/EventArray"),
        "image": ("/dvs/image_raw", "sensor_msgs/msg/Image"),
        "exposure": ("/dvs/exposure", "std_msgs/msg/Int32"),
        "camera_info": ("/dvs/camera_info", "sensor_msgs/msg/CameraInfo"),
    }
    with Writer(path) as writer:
        conns = {k: writer.add_connection(t, mt, typestore=store) for k, (t, mt) in topics.items()}
        for ns, kind, msg in sorted(msgs, key=lambda m: m[0]):
            writer.write(conns[kind], ns, store.serialize_ros1(msg, topics[kind][1]))
    return frames


# ----------------------------------------------------------------------------- issue 32: bad calibration


@pytest.mark.parametrize("where", [0, 2, 4])  # fx, cx, fy
def test_bag_with_nan_in_camera_info_K_is_a_bad_K_not_bad_frames(tmp_path, where):
    K = [6.0, 0, 3.2, 0, 6.5, 2.1, 0, 0, 1]
    K[where] = float("nan")
    write_bag(tmp_path / "rec.bag", K=K)
    with pytest.raises(CaptureError, match=r"rec\.bag: field '/dvs/camera_info\.K': has a non-finite entry") as e:
        load(tmp_path / "rec.bag")
    assert "frames" not in str(e.value) and "\n" not in str(e.value)


def test_bag_with_inf_in_camera_info_D_is_a_bad_D(tmp_path):
    write_bag(tmp_path / "rec.bag", D=(0.01, float("inf"), 0, 0, 0))
    with pytest.raises(CaptureError, match=r"field '/dvs/camera_info\.D': has a non-finite entry"):
        load(tmp_path / "rec.bag")
