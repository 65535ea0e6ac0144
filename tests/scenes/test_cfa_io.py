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


# ----------------------------------------------------------------------------- AEDAT4 from a colour DAVIS


def fake_dv_recording(tmp_path, monkeypatch, color_filter="0", rgb=True, n_frames=2):
    """An AEDAT4 file whose header is DV's (``colorFilter`` on the events stream) and whose packets
    come from a stand-in decoder: events and frames (demosaiced RGB, or DV's "Original" raw mosaics)."""
    aedat = pytest.importorskip("aedat")
    from tests.edi.test_aedat4_header import aedat4_header, dv_xml

    rng = np.random.default_rng(3)

    class Decoder:
        def __init__(self, path):
            pass

        def id_to_stream(self):
            return {0: {"type": "events", "width": W, "height": H}, 1: {"type": "frame", "width": W, "height": H}}

        def __iter__(self):
            ev = np.zeros(20, [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("on", "?")])
            ev["t"] = 1_000_000 + np.arange(20) * 1000
            ev["x"], ev["y"], ev["on"] = rng.integers(0, W, 20), rng.integers(0, H, 20), rng.integers(0, 2, 20)
            yield {"stream_id": 0, "events": ev}
            for k in range(n_frames):
                px = rng.integers(0, 256, (H, W, 3) if rgb else (H, W)).astype(np.uint8)
                t = 1_000_000 + 8000 * k
                fr = {"pixels": px, "format": "RGB" if rgb else "L", "exposure_begin_t": t, "exposure_end_t": t + 4000}
                yield {"stream_id": 1, "frame": fr}

    monkeypatch.setattr(aedat, "Decoder", Decoder)
    f = tmp_path / "rec.aedat4"
    f.write_bytes(aedat4_header(dv_xml(color_filter)))
    return f


@pytest.mark.parametrize("rgb", [True, False])
def test_aedat4_of_a_colour_davis_states_its_filter(tmp_path, monkeypatch, rgb):
    f = fake_dv_recording(tmp_path, monkeypatch, color_filter="3", rgb=rgb)
    cap = load(f)
    assert cap.cfa == "BGGR" and cap.channels == (3 if rgb else 1)
    assert cap.raw_mosaic is (not rgb)
    assert "colorFilter" in cap.meta["cfa_source"]


def test_aedat4_of_a_grey_davis_has_no_filter(tmp_path, monkeypatch):
    cap = load(fake_dv_recording(tmp_path, monkeypatch, color_filter=None, rgb=False))
    assert cap.cfa is None and not cap.raw_mosaic


def test_cfa_stated_by_hand(tmp_path, monkeypatch):
    grey = fake_dv_recording(tmp_path, monkeypatch, color_filter=None, rgb=True)
    cap = load(grey, cfa="grbg")
    assert cap.cfa == "GRBG" and cap.meta["cfa_source"] == "stated by hand"
    with pytest.raises(CaptureError, match=r"field 'cfa': 'RGBG' is not a Bayer pattern"):
        load(grey, cfa="RGBG")


def test_cfa_stated_against_the_recorded_one(tmp_path, monkeypatch):
    f = fake_dv_recording(tmp_path, monkeypatch, color_filter="0", rgb=True)
    assert load(f, cfa="RGGB").cfa == "RGGB"  # agrees: kept
    with pytest.raises(CaptureError, match=r"rec\.aedat4: field 'cfa': stated BGGR but the capture records RGGB"):
        load(f, cfa="BGGR")
    cap = load(f, cfa="none")  # events taken as luminance on purpose
    assert cap.cfa is None and cap.meta["cfa_dropped"] == "RGGB"


# ----------------------------------------------------------------------------- ROS bags of raw Bayer images


@pytest.mark.parametrize("encoding,pattern", [("bayer_rggb8", "RGGB"), ("bayer_gbrg8", "GBRG")])
def test_bag_of_bayer_images_is_a_raw_mosaic_capture(tmp_path, encoding, pattern):
    frames = write_bag(tmp_path / "rec.bag", encoding=encoding)
    cap = load(tmp_path / "rec.bag", undistort=False)
    assert cap.cfa == pattern and cap.raw_mosaic and cap.frames.shape == (2, H, W, 1)
    np.testing.assert_array_equal(cap.frames, frames.astype(np.float32) / np.float32(255))
    assert cap.meta["cfa_source"] == f"/dvs/image_raw encoding {encoding}"


def test_bag_of_mono_images_has_no_filter(tmp_path):
    write_bag(tmp_path / "rec.bag", encoding="mono8")
    assert load(tmp_path / "rec.bag", undistort=False).cfa is None


# ----------------------------------------------------------------------------- scenes.convert --cfa


def test_convert_cfa_states_the_filter_of_rgb_frames(tmp_path, capsys):
    import json

    from scenes.convert import main

    write_bag(tmp_path / "rec.bag", encoding="rgb8")  # the driver's demosaiced frames: no pattern recorded
    assert main([str(tmp_path / "rec.bag"), "--out", str(tmp_path / "cap"), "--cfa", "RGGB"]) == 0
    assert json.loads((tmp_path / "cap" / "capture.json").read_text())["cfa"] == "RGGB"
    assert "colour filter: RGGB (stated by hand); frames are demosaiced RGB" in capsys.readouterr().out
    assert load(tmp_path / "cap").cfa == "RGGB"


def test_convert_cfa_that_disagrees_with_the_file_is_one_line(tmp_path, capsys):
    from scenes.convert import main

    write_bag(tmp_path / "rec.bag", encoding="bayer_grbg8")
    assert main([str(tmp_path / "rec.bag"), "--out", str(tmp_path / "cap"), "--cfa", "RGGB"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "field 'cfa': stated RGGB but the capture records GRBG" in err
    assert main([str(tmp_path / "rec.bag"), "--out", str(tmp_path / "cap"), "--cfa", "RGB"]) == 2
    assert "field 'cfa': 'RGB' is not a Bayer pattern" in capsys.readouterr().err
    assert not (tmp_path / "cap").exists()
    assert main([str(tmp_path / "rec.bag"), "--out", str(tmp_path / "cap")]) == 0
    assert "colour filter: GRBG (/dvs/image_raw encoding bayer_grbg8); frames are raw Bayer mosaics" in (
        capsys.readouterr().out
    )


# ----------------------------------------------------------------------------- Capture checks with cfa


def _capture(d=1, fw=W, fh=H, ew=W, eh=H, cfa="RGGB"):
    from edi import EventStream
    from scenes import Capture

    frames = np.full((1, fh, fw, d), 0.5, np.float32)
    K = np.array([[5.0, 0, fw / 2], [0, 5.0, fh / 2], [0, 0, 1]])
    return Capture(frames, np.array([[0.0, 0.01]]), EventStream.empty(ew, eh), K, cfa=cfa)


def test_capture_with_cfa_takes_rgb_or_raw_frames():
    assert _capture(d=3).validate().cfa == "RGGB" and not _capture(d=3).raw_mosaic
    assert _capture(d=1).validate().raw_mosaic
    assert _capture(d=1, cfa="bggr").validate().cfa == "BGGR"  # normalised


def test_raw_frame_of_another_size_than_the_events_sensor_is_named():
    with pytest.raises(
        CaptureError, match=r"cap\.json: field 'frames': raw Bayer mosaics of 4x4 under cfa RGGB, .*6x4"
    ):
        _capture(d=1, fw=4).validate("cap.json")
    with pytest.raises(CaptureError, match=r"field 'cfa': demosaiced RGB frames of 6x2 under cfa RGGB, .*6x4"):
        _capture(d=3, fh=2).validate()


def test_cfa_pattern_must_fit_the_frames():
    with pytest.raises(CaptureError, match=r"field 'cfa': a 2x2 Bayer pattern needs frames of at least 2x2, got 6x1"):
        _capture(d=3, fh=1, eh=1).validate()
    with pytest.raises(CaptureError, match=r"field 'cfa': 'RGBG' is not a Bayer pattern"):
        _capture(cfa="RGBG").validate()


# ----------------------------------------------------------------------------- undistortion keeps the filter


def test_undistort_on_load_keeps_each_event_on_its_own_channel_and_raw_frames_a_mosaic(tmp_path):
    from edi import EventStream
    from edi.cfa import channel_map, mosaic
    from scenes import Capture, save
    from scenes.undistort import undistort_normalized

    h, w = 16, 24
    K = np.array([[20.0, 0, 12.0], [0, 20.0, 8.0], [0, 0, 1]])
    d = np.array([-0.3, 0.05, 0.001, -0.002, 0.0])
    yy, xx = np.mgrid[0:h, 0:w]
    t = np.arange(h * w, dtype=np.int64)  # one event per pixel, told apart by its time
    ev = EventStream(t, xx.ravel(), yy.ravel(), np.ones(h * w, np.int8), w, h)
    colour = np.broadcast_to(np.array([0.8, 0.5, 0.2], np.float32), (1, h, w, 3))
    raw = mosaic(colour, "GRBG")[..., None]  # [1, H, W, 1]
    cap = Capture(raw, np.array([[0.0, 0.01]]), ev, K, distortion=d, cfa="GRBG")
    save(cap, tmp_path / "cap")
    out = load(tmp_path / "cap")
    chan = channel_map("GRBG", h, w)
    assert out.cfa == "GRBG" and out.raw_mosaic and out.meta["undistorted"]
    # raw frames stay a mosaic: every pixel holds its own channel's value
    np.testing.assert_allclose(out.frames[0, ..., 0], np.array([0.8, 0.5, 0.2])[chan], atol=1e-6)
    # each event lands on a pixel of the channel it fired on, next to its undistorted centre
    src = out.events.t  # the source pixel index of each kept event
    assert len(src) > 0.8 * h * w
    np.testing.assert_array_equal(chan[out.events.y, out.events.x], chan.ravel()[src])
    c = np.stack([(xx.ravel()[src] + 0.5 - K[0, 2]) / 20.0, (yy.ravel()[src] + 0.5 - K[1, 2]) / 20.0], -1)
    ideal = undistort_normalized(c, d) * 20.0 + K[[0, 1], [2, 2]]
    dist = np.hypot(out.events.x + 0.5 - ideal[:, 0], out.events.y + 0.5 - ideal[:, 1])
    interior = (ideal[:, 0] > 2) & (ideal[:, 0] < w - 2) & (ideal[:, 1] > 2) & (ideal[:, 1] < h - 2)
    assert dist[interior].max() <= np.sqrt(2) + 1e-9 and dist.max() <= np.sqrt(5) + 1e-9  # further at a border


# ----------------------------------------------------------------------------- Ev-DeblurNeRF CDAVIS layout


def write_cdavis(root: Path, n_events=200, seed=0, sharp_last=False):
    """A CDAVIS folder as Ev-DeblurNeRF ships it: undistorted RGB images_1/, timestamps.npz,
    poses_bounds.npy, events.h5 (x, y, t, p at the root; x, y rectified floats) and ev_map.npz."""
    import h5py
    from PIL import Image

    h, w = 6, 8
    rng = np.random.default_rng(seed)
    (root / "images_1").mkdir(parents=True)
    rows = []
    for i in range(3 if sharp_last else 2):
        c = np.eye(4)
        c[:3, 3] = [0.1 * i, 0, 0]
        r = np.stack([c[:3, 1], c[:3, 0], -c[:3, 2]], 1)
        m = np.concatenate([r, c[:3, 3:4], np.array([[h], [w], [7.0]])], 1)
        rows.append(np.concatenate([m.ravel(), [0.5, 20.0]]))
        img = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
        Image.fromarray(img).save(root / "images_1" / f"{i:02d}.png")
    np.save(root / "poses_bounds.npy", np.array(rows))
    start, end = [1000, 30000] + [55000] * sharp_last, [21000, 50000] + [55000] * sharp_last
    np.savez(root / "images_1" / "timestamps.npz", timestamps_start=start, timestamps_end=end)
    yy, xx = np.mgrid[0:h, 0:w]
    inv_x = (xx + 0.4 * np.sin(yy) - 0.2).astype(np.float32)  # rectified coordinates of each sensor pixel
    inv_y = (yy + 0.3 * np.cos(xx) + 0.1).astype(np.float32)
    np.savez(root / "ev_map.npz", inv_mapx=inv_x, inv_mapy=inv_y)
    src = rng.integers(0, h * w, n_events)  # each event's sensor pixel
    with h5py.File(root / "events.h5", "w") as f:
        f["x"], f["y"] = inv_x.ravel()[src], inv_y.ravel()[src]
        f["t"] = np.sort(rng.integers(0, 60000, n_events))
        f["p"] = rng.integers(0, 2, n_events)
    return src, inv_x, inv_y


def test_cdavis_events_land_on_their_own_filter(tmp_path):
    from edi.cfa import channel_map

    src, inv_x, inv_y = write_cdavis(tmp_path / "c")
    cap = load(tmp_path / "c")
    assert cap.cfa == "RGGB" and cap.channels == 3 and not cap.raw_mosaic
    assert cap.meta["events_dropped_rectified"] == len(src) - len(cap.events)
    chan = channel_map("RGGB", 6, 8)
    u, v = inv_x.ravel()[src] + 0.5, inv_y.ravel()[src] + 0.5  # our pixel coordinates
    inside = (u >= 0) & (u < 8) & (v >= 0) & (v < 6)
    kept = src[inside]  # events stay in order; those rectified off the grid are dropped
    assert 0 < (~inside).sum() < 20 and len(cap.events) == len(kept)
    np.testing.assert_array_equal(chan[cap.events.y, cap.events.x], chan.ravel()[kept])
    dist = np.hypot(cap.events.x - inv_x.ravel()[kept], cap.events.y - inv_y.ravel()[kept])
    assert dist.max() <= np.sqrt(5) + 1e-6


def test_cdavis_event_off_the_map_is_named(tmp_path):
    import h5py

    write_cdavis(tmp_path / "c")
    with h5py.File(tmp_path / "c" / "events.h5", "r+") as f:
        x = f["x"][:]
        x[3] += 0.01
        f["x"][...] = x
    with pytest.raises(CaptureError, match=r"events\.h5: field 'x': 1 events sit where no sensor pixel"):
        load(tmp_path / "c")


# ----------------------------------------------------------------------------- EBAD-NeRF / E2NeRF real-world


def test_ebad_nerf_colour_frames_say_the_filter_is_not_recorded_and_take_one_stated(tmp_path, capsys):
    from scenes.convert import main
    from scenes.e2nerf import CFA_NOTE
    from tests.scenes.test_e2nerf import write_ebad_nerf

    write_ebad_nerf(tmp_path / "scene", novel=False)
    cap = load(tmp_path / "scene")
    assert cap.cfa is None and cap.meta["cfa_note"] == CFA_NOTE  # not recorded: not guessed
    assert load(tmp_path / "scene", cfa="RGGB").cfa == "RGGB"
    assert main([str(tmp_path / "scene"), "--out", str(tmp_path / "out")]) == 0
    assert "colour filter: none (colour frames, but the layout records no colour filter" in capsys.readouterr().out


def test_cdavis_sharp_images_are_the_test_views(tmp_path):
    write_cdavis(tmp_path / "c", sharp_last=True)
    cap = load(tmp_path / "c")
    assert cap.names == ["00", "01"] and [v.name for v in cap.test_views] == ["02"]
    v = cap.test_views[0]
    assert v.image is not None and v.image.shape == (6, 8, 3) and v.c2w is not None
    assert v.t == pytest.approx(cap.exposures[0, 0] + 0.054)  # its own (sharp) time on the events' clock
    assert cap.meta["held_out_frames"] == ["02"]
