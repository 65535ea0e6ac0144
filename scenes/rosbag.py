"""ROS1 bags of the rpg_dvs_ros DAVIS driver (the Event Camera Dataset and MVSEC originals).

Needs the pure-Python ``rosbags`` package (the ``ros`` extra: ``pip install 'ebad[ros]'``).

Topics (found by message type; where a type is on several topics the driver's name wins):

- ``dvs_msgs/EventArray`` (``/dvs/events``): decoded with numpy straight from the message
  bytes (13 bytes per event: uint16 x, uint16 y, uint32 sec, uint32 nsec, uint8 polarity).
- ``sensor_msgs/Image`` (``/dvs/image_raw``): mono8/mono16/rgb8/bgr8/rgb16/bgr16 frames, or
  raw Bayer mosaics ``bayer_rggb8`` etc. (8 or 16 bit): then ``Capture.cfa`` is the pattern the
  encoding names and the frames are 1-channel raw mosaics. The driver's ``rgb8`` frames of a
  colour DAVIS do not say which filter the sensor has: state it (``load(..., cfa=...)``).
- ``std_msgs/Int32`` (``/dvs/exposure``): the exposure in microseconds, published by the
  driver right after each image (matched in order); when the bag did not record it, pass
  ``exposure_us``.
- ``sensor_msgs/CameraInfo`` (``/dvs/camera_info``): K and plumb_bob distortion (k1 k2 p1 p2
  k3); the principal point moves by +0.5 px to our pixel-centre convention. Without it pass
  ``K``, or a 70-degree field of view is guessed (``meta['K_guessed']``).

Exposure window: the driver stamps an image with libcaer's frame timestamp, which is the
*middle* of the exposure, so a frame stamped ``s`` with exposure ``e`` microseconds covers
``[s - e // 2, s - e // 2 + e)``. Times are made relative to the earliest event or exposure
start (``EventStream.t0``, microseconds since the epoch); ROS times are whole nanoseconds, the
driver's are whole microseconds, and nanoseconds become microseconds by rounding to nearest.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from edi import EventStream

from .capture import Capture, frame_name, guess_K
from .errors import CaptureError

__all__ = [
    "load_rosbag",
    "dvs_typestore",
    "decode_event_array",
    "exposure_window_us",
    "ROS_INSTALL",
    "DVS_EVENT_MSG",
    "DVS_EVENT_ARRAY_MSG",
    "TOPICS",
    "BAYER_ENCODINGS",
]

ROS_INSTALL = "pip install 'ebad[ros]' (or: pip install 'rosbags>=0.9')"
TOPICS = {
    "events": "/dvs/events",
    "image": "/dvs/image_raw",
    "exposure": "/dvs/exposure",
    "camera_info": "/dvs/camera_info",
}
MSGTYPES = {
    "events": "dvs_msgs/msg/EventArray",
    "image": "sensor_msgs/msg/Image",
    "exposure": "std_msgs/msg/Int32",
    "camera_info": "sensor_msgs/msg/CameraInfo",
}
# rpg_dvs_ros/dvs_msgs/msg/*.msg
DVS_EVENT_MSG = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
DVS_EVENT_ARRAY_MSG = "Header header\nuint32 height\nuint32 width\nEvent[] events\n"
EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])  # 13 bytes, packed
NS_PER_US = 1000
IMAGE_ENCODINGS: dict[str, tuple[int, type[np.unsignedinteger], bool]] = {
    "mono8": (1, np.uint8, False),
    "mono16": (1, np.uint16, False),
    "rgb8": (3, np.uint8, False),
    "bgr8": (3, np.uint8, True),
    "rgb16": (3, np.uint16, False),
    "bgr16": (3, np.uint16, True),
}
# sensor_msgs/image_encodings.h: raw Bayer mosaics, the letters naming the filters row by row
# (bayer_rggb8: R G on the first row, G B on the second), so in edi.cfa's order of pixels
# (0, 0), (1, 0), (0, 1), (1, 1) the pattern is the letters as written
BAYER_ENCODINGS: dict[str, str] = {
    f"bayer_{p.lower()}{bits}": p for p in ("RGGB", "BGGR", "GBRG", "GRBG") for bits in (8, 16)
}
IMAGE_ENCODINGS.update({enc: (1, np.uint16 if enc.endswith("16") else np.uint8, False) for enc in BAYER_ENCODINGS})
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")


def _rosbags() -> tuple[Any, Any]:  # (rosbags.rosbag1, rosbags.typesys), or (None, None) without the extra
    try:
        import rosbags.rosbag1 as rosbag1
        import rosbags.typesys as typesys
    except ImportError:
        return None, None
    return rosbag1, typesys


def dvs_typestore() -> Any:  # a rosbags Typestore
    """A ROS1 (Noetic) rosbags typestore with ``dvs_msgs/msg/Event`` and ``EventArray`` registered."""
    _, typesys = _rosbags()
    if typesys is None:
        raise CaptureError(None, None, f"ROS bags need the 'rosbags' package: {ROS_INSTALL}")
    store = typesys.get_typestore(typesys.Stores.ROS1_NOETIC)
    types = {}
    types.update(typesys.get_types_from_msg(DVS_EVENT_MSG, "dvs_msgs/msg/Event"))
    types.update(typesys.get_types_from_msg(DVS_EVENT_ARRAY_MSG, "dvs_msgs/msg/EventArray"))
    store.register(types)
    return store


def decode_event_array(raw: bytes | memoryview) -> tuple[np.ndarray, int, int]:
    """One serialised ``dvs_msgs/EventArray`` -> (events [M] structured x, y, sec, nsec, p; width; height).

    ROS1 layout: header (uint32 seq, uint32 sec, uint32 nsec, uint32 length + frame_id), uint32
    height, uint32 width, uint32 count, then ``count`` packed 13-byte events.
    """
    buf = memoryview(raw)
    (n_id,) = struct.unpack_from("<I", buf, 12)
    pos = 16 + n_id
    height, width, count = struct.unpack_from("<III", buf, pos)
    pos += 12
    if len(buf) - pos != count * EVENT_DTYPE.itemsize:
        raise ValueError(f"EventArray says {count} events but holds {len(buf) - pos} bytes of them")
    return np.frombuffer(buf, dtype=EVENT_DTYPE, count=count, offset=pos), int(width), int(height)


def exposure_window_us(stamp_us: np.ndarray, exposure_us: np.ndarray) -> np.ndarray:  # [F], [F] -> [F, 2]
    """[start, end) in microseconds of frames stamped at mid-exposure (the driver's rule above)."""
    start = stamp_us - exposure_us // 2
    return np.stack([start, start + exposure_us], 1)


def _pick(connections: list, kind: str, path: Path) -> Any | None:
    found = [c for c in connections if c.msgtype == MSGTYPES[kind]]
    if kind == "exposure":
        found = [c for c in found if c.topic.rstrip("/").endswith("exposure")]
    if len(found) > 1:
        named = [c for c in found if c.topic == TOPICS[kind]]
        if len(named) != 1:
            raise CaptureError(
                str(path),
                kind,
                f"several {MSGTYPES[kind]} topics "
                f"({', '.join(sorted(c.topic for c in found))}) and none is {TOPICS[kind]}",
            )
        found = named
    return found[0] if found else None


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _ns_to_us(ns: np.ndarray) -> np.ndarray:
    return (np.asarray(ns, dtype=np.int64) + NS_PER_US // 2) // NS_PER_US


def _image(msg: Any, path: Path, k: int) -> np.ndarray:  # -> [H, W, D] float32
    enc = IMAGE_ENCODINGS.get(msg.encoding)
    if enc is None:
        raise CaptureError(
            str(path),
            f"image[{k}].encoding",
            f"{msg.encoding!r} is not supported (use one of {', '.join(IMAGE_ENCODINGS)})",
        )
    d, dtype, bgr = enc
    itemsize = np.dtype(dtype).itemsize
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * d * itemsize or len(data) < h * step:
        raise CaptureError(
            str(path), f"image[{k}].data", f"{len(data)} bytes for {w}x{h} {msg.encoding} with step {step}"
        )
    rows = data[: h * step].reshape(h, step)[:, : w * d * itemsize]
    order: Literal[">", "<"] = ">" if msg.is_bigendian else "<"
    a = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order) if itemsize > 1 else dtype).reshape(h, w, d)
    if bgr:
        a = a[..., ::-1]
    return (a.astype(np.float32) / np.float32(np.iinfo(dtype).max)).astype(np.float32)


@dataclass
class _BagMessages:
    """What ``load_rosbag`` reads from a bag, before any check across topics."""

    connections: dict[str, Any]  # kind -> the connection picked (None: the bag has no such topic)
    event_chunks: list[np.ndarray]  # per EventArray message: [M] EVENT_DTYPE
    sensor_size: tuple[int, int] | None  # (width, height) of the first EventArray
    images: list[np.ndarray]  # [H, W, D] float32 per image message
    encodings: list[str]  # per image message, its ``encoding``
    stamps_ns: list[int]  # per image, the header stamp
    exposures_us: list[int]  # per exposure message
    camera_info: Any | None  # the first CameraInfo message


def load_rosbag(path: str | os.PathLike, K: np.ndarray | None = None, exposure_us: int | None = None) -> Capture:
    """Read a rpg_dvs_ros ROS1 bag (module docstring) into a Capture without poses.

    Args:
        path: the .bag file.
        K: [3, 3] intrinsics when the bag has no camera_info (else a guess, ``meta['K_guessed']``).
        exposure_us: the APS exposure (microseconds) when the bag did not record ``/dvs/exposure``.

    Raises:
        CaptureError: ``rosbags`` missing (with the pip command), an unreadable bag, a missing
            topic, no exposure (neither ``/dvs/exposure`` nor ``exposure_us``), bad messages.
    """
    path = Path(path)
    rosbag1, _ = _rosbags()
    if rosbag1 is None:
        raise CaptureError(str(path), None, f"reading ROS bags needs the 'rosbags' package: {ROS_INSTALL}")
    if exposure_us is not None and (
        isinstance(exposure_us, bool) or not isinstance(exposure_us, (int, np.integer)) or exposure_us < 0
    ):
        raise CaptureError(
            str(path), "exposure_us", f"must be a non-negative integer (microseconds), got {exposure_us!r}"
        )
    bag = _read_bag(rosbag1, path)
    frames = _stack_images(bag, path)
    f, h, w, _ = frames.shape
    cfa = _bayer_pattern(bag, path)
    if bag.sensor_size is not None and bag.sensor_size != (w, h):
        raise CaptureError(
            str(path), "events", f"sensor {bag.sensor_size[0]}x{bag.sensor_size[1]} differs from the images' {w}x{h}"
        )
    meta: dict[str, Any] = {
        "source_layout": "rosbag1",
        "source": str(path),
        "exposure_rule": "image stamp = mid-exposure (libcaer); window [s - e//2, s - e//2 + e)",
    }
    if cfa is not None:
        meta["cfa_source"] = f"{bag.connections['image'].topic} encoding {bag.encodings[0]}"
    exp_us = _exposure_times_us(bag, exposure_us, f, path, meta)
    window_us = exposure_window_us(_ns_to_us(np.array(bag.stamps_ns, dtype=np.int64)), exp_us)
    events = _event_stream(bag.event_chunks, window_us, w, h, path)
    exposures = (window_us - events.t0).astype(np.float64) * 1e-6
    distortion = None
    if bag.camera_info is not None:
        meta["calibration"] = bag.connections["camera_info"].topic
        K, distortion = _calibration(bag.camera_info, w, h, path, meta["calibration"])
    elif K is None:
        K = guess_K(w, h)
        meta["K_guessed"] = True
    return Capture(
        frames=frames,
        exposures=exposures,
        events=events,
        K=np.asarray(K, dtype=np.float64),
        distortion=distortion,
        split=["train"] * f,
        names=[frame_name(i) for i in range(f)],
        meta=meta,
        cfa=cfa,
    )


def _bayer_pattern(bag: _BagMessages, path: Path) -> str | None:
    """The Bayer pattern the images' encoding states (``BAYER_ENCODINGS``: the frames are raw
    mosaics), or None; images of different encodings are refused."""
    encodings = sorted(set(bag.encodings))
    if len(encodings) > 1:
        raise CaptureError(str(path), "image.encoding", f"images differ in encoding: {', '.join(encodings)}")
    return BAYER_ENCODINGS.get(encodings[0]) if encodings else None


def _read_bag(rosbag1: Any, path: Path) -> _BagMessages:
    """Every message ``load_rosbag`` uses, by topic (``_pick``); a missing event or image topic and
    an unreadable bag raise CaptureError."""
    store = dvs_typestore()
    try:
        with rosbag1.Reader(path) as reader:
            conns = list(reader.connections)
            picked = {kind: _pick(conns, kind, path) for kind in MSGTYPES}
            for kind in ("events", "image"):
                if picked[kind] is None:
                    raise CaptureError(
                        str(path),
                        kind,
                        f"no {MSGTYPES[kind]} topic (expected {TOPICS[kind]}); "
                        f"topics: {', '.join(sorted({c.topic for c in conns}))}",
                    )
            bag = _BagMessages(picked, [], None, [], [], [], [], None)
            for _, _, raw in reader.messages(connections=[picked["events"]]):
                arr, w, h = decode_event_array(raw)
                bag.sensor_size = bag.sensor_size or (w, h)
                bag.event_chunks.append(arr)
            for k, (conn, _, raw) in enumerate(reader.messages(connections=[picked["image"]])):
                msg = store.deserialize_ros1(raw, conn.msgtype)
                bag.images.append(_image(msg, path, k))
                bag.encodings.append(str(msg.encoding))
                bag.stamps_ns.append(_stamp_ns(msg.header))
            if picked["exposure"] is not None:
                for conn, _, raw in reader.messages(connections=[picked["exposure"]]):
                    bag.exposures_us.append(int(store.deserialize_ros1(raw, conn.msgtype).data))
            if picked["camera_info"] is not None:
                for conn, _, raw in reader.messages(connections=[picked["camera_info"]]):
                    bag.camera_info = store.deserialize_ros1(raw, conn.msgtype)
                    break
    except CaptureError:
        raise
    except (rosbag1.ReaderError, OSError, ValueError, struct.error) as exc:
        raise CaptureError(str(path), None, f"unreadable ROS bag ({type(exc).__name__}: {exc})") from None
    return bag


def _stack_images(bag: _BagMessages, path: Path) -> np.ndarray:  # -> [F, H, W, D] float32
    """The image messages as frames, all of one size and channel count."""
    if not bag.images:
        raise CaptureError(str(path), "image", f"no messages on {bag.connections['image'].topic}")
    if len({im.shape for im in bag.images}) != 1:
        raise CaptureError(str(path), "image", "images differ in size or channels")
    return np.stack(bag.images)


def _exposure_times_us(
    bag: _BagMessages, exposure_us: int | None, f: int, path: Path, meta: dict[str, Any]
) -> np.ndarray:  # -> [F] int64
    """Each frame's exposure in microseconds: the bag's exposure messages (matched in order), else
    ``exposure_us``; ``meta['exposure_source']`` says which."""
    if bag.exposures_us:
        if len(bag.exposures_us) < f:
            raise CaptureError(str(path), "exposure", f"{len(bag.exposures_us)} exposure messages for {f} images")
        exp_us = np.asarray(bag.exposures_us[:f], dtype=np.int64)
        meta["exposure_source"] = bag.connections["exposure"].topic
    elif exposure_us is not None:
        exp_us = np.full(f, int(exposure_us), np.int64)
        meta["exposure_source"] = "exposure_us argument"
    else:
        raise CaptureError(
            str(path),
            "exposure",
            f"the bag has no {TOPICS['exposure']} topic: pass the APS exposure "
            "(exposure_us=..., on the command line --exposure-us)",
        )
    if np.any(exp_us < 0):
        raise CaptureError(str(path), "exposure", "negative exposure time")
    return exp_us


def _event_stream(chunks: list[np.ndarray], window_us: np.ndarray, w: int, h: int, path: Path) -> EventStream:
    """The decoded events as a stream whose t0 is the earliest event or exposure start (window_us [F, 2])."""
    ev = np.concatenate(chunks) if chunks else np.zeros(0, EVENT_DTYPE)
    t_us = _ns_to_us(ev["sec"].astype(np.int64) * 1_000_000_000 + ev["nsec"].astype(np.int64))
    t0 = int(min(window_us[:, 0].min(), t_us.min() if len(t_us) else window_us[:, 0].min()))
    order = np.argsort(t_us, kind="stable")  # messages are in order; guard against a reordered bag
    try:
        return EventStream(t_us[order], ev["x"][order], ev["y"][order], ev["p"][order].astype(np.int8), w, h, t0=t0)
    except ValueError as exc:
        raise CaptureError(str(path), "events", str(exc)) from None


def _calibration(
    info: Any, w: int, h: int, path: Path, topic: str = TOPICS["camera_info"]
) -> tuple[np.ndarray, np.ndarray | None]:
    """K [3, 3] (principal point moved to our pixel-centre convention) and distortion [5] or None
    from a CameraInfo message (of ``topic``, named in errors: ``/dvs/camera_info.K``); a non-finite
    K or D is refused here, as bad calibration, before anything is computed from it."""
    Kr = np.asarray(info.K, dtype=np.float64).reshape(3, 3)
    if (int(info.width), int(info.height)) != (w, h):
        raise CaptureError(str(path), topic, f"calibrated for {info.width}x{info.height}, images are {w}x{h}")
    if not np.isfinite(Kr).all():
        raise CaptureError(str(path), f"{topic}.K", f"has a non-finite entry: {Kr.reshape(-1).tolist()}")
    if Kr[0, 0] <= 0 or Kr[1, 1] <= 0:
        raise CaptureError(str(path), f"{topic}.K", f"focal lengths must be positive, got {Kr[0, 0]}, {Kr[1, 1]}")
    K = np.array([[Kr[0, 0], 0.0, Kr[0, 2] + 0.5], [0.0, Kr[1, 1], Kr[1, 2] + 0.5], [0.0, 0.0, 1.0]])
    D = np.asarray(info.D, dtype=np.float64)
    if not np.isfinite(D).all():
        raise CaptureError(str(path), f"{topic}.D", f"has a non-finite entry: {D.tolist()}")
    if len(D) and info.distortion_model not in DISTORTION_MODELS:
        raise CaptureError(
            str(path),
            f"{topic}.distortion_model",
            f"{info.distortion_model!r} is not supported (plumb_bob k1 k2 p1 p2 k3)",
        )
    if len(D) > 5 and np.any(D[5:] != 0):
        raise CaptureError(str(path), f"{topic}.D", "only k1 k2 p1 p2 k3 are supported; k4.. are not zero")
    distortion = None
    if np.any(D != 0):
        distortion = np.zeros(5)
        distortion[: min(5, len(D))] = D[:5]
    return K, distortion
