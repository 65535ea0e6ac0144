"""ebad-capture/1: lossless round trip, atomic writes, errors that name the file and the field."""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import scenes.format as fmt
from edi import EventStream
from scenes import Capture, CaptureError, TestView, load, save
from scenes.images import quantize
from scenes.synth import look_at


def _capture(rgb=False, quantised=True, seed=0, f=3, h=12, w=16):
    rng = np.random.default_rng(seed)
    d = 3 if rgb else 1
    frames = rng.uniform(0, 1, (f, h, w, d)).astype(np.float32)
    if quantised:
        frames = quantize(frames)
    m = 400
    ev = EventStream(
        np.sort(rng.integers(0, 300_000, m)), rng.integers(0, w, m), rng.integers(0, h, m), rng.integers(0, 2, m), w, h
    )
    object.__setattr__(ev, "t0", 1_600_000_000_000_000)
    c2w = np.stack(
        [look_at(rng.normal(size=3), np.array([0.0, 0.0, 4.0]) + rng.normal(size=3) * 0.1) for _ in range(f)]
    )
    exps = np.stack([np.arange(f) * 0.1 + 0.01, np.arange(f) * 0.1 + 0.0437], 1)
    exps[1, 1] = exps[1, 0]  # one sharp frame
    tv = [
        TestView(
            "held_0",
            0.123456789,
            c2w[0] @ look_at(np.zeros(3), np.array([0.1, 0, 1.0])),
            rng.uniform(0, 1, (h, w, d)).astype(np.float32),
        ),
        TestView("held_1", 0.2, c2w[1], None),
    ]
    K = np.array([[20.5, 0, 8.1], [0, 21.25, 6.3], [0, 0, 1.0]])
    return Capture(
        frames=frames,
        exposures=exps,
        events=ev,
        K=K,
        distortion=np.array([0.1, -0.01, 1e-3, 2e-4, 0.0]),
        c2w=c2w,
        split=["train", "test", "train"][:f],
        test_views=tv,
        names=[f"f{i}" for i in range(f)],
        meta={"c": 0.2, "note": "x", "arr": np.arange(3)},
    )


def _assert_same(a: Capture, b: Capture, meta=True):
    np.testing.assert_array_equal(a.frames, b.frames)
    assert a.frames.dtype == b.frames.dtype == np.float32
    np.testing.assert_array_equal(a.exposures, b.exposures)
    for k in "txyp":
        np.testing.assert_array_equal(getattr(a.events, k), getattr(b.events, k))
    assert (a.events.width, a.events.height, a.events.t0) == (b.events.width, b.events.height, b.events.t0)
    np.testing.assert_array_equal(a.K, b.K)
    np.testing.assert_array_equal(a.distortion, b.distortion)
    np.testing.assert_array_equal(a.c2w, b.c2w)
    assert a.split == b.split and a.names == b.names
    assert len(a.test_views) == len(b.test_views)
    for x, y in zip(a.test_views, b.test_views):
        assert x.name == y.name and x.t == y.t
        np.testing.assert_array_equal(x.c2w, y.c2w)
        if x.image is None:
            assert y.image is None
        else:
            np.testing.assert_array_equal(x.image, y.image)
    if meta:
        assert b.meta == {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in a.meta.items()}


@pytest.mark.parametrize("rgb, quantised", [(False, True), (True, True), (False, False), (True, False)])
def test_save_load_round_trip_is_lossless(tmp_path, rgb, quantised):
    cap = _capture(rgb=rgb, quantised=quantised)
    save(cap, tmp_path / "cap")
    back = load(tmp_path / "cap", undistort=False)
    _assert_same(cap, back)
    again = tmp_path / "again"
    save(back, again)
    _assert_same(back, load(again, undistort=False))
    files = sorted(p.suffix for p in (tmp_path / "cap" / "frames").iterdir())
    assert set(files) == ({".png"} if quantised else {".npy"})


def test_sixteen_bit_grey_png_is_used_when_exact(tmp_path):
    cap = _capture()
    cap.frames = (
        np.round(cap.frames * 0 + np.random.default_rng(0).uniform(0, 1, cap.frames.shape) * 65535).astype(np.float32)
        / np.float32(65535)
    ).astype(np.float32)
    save(cap, tmp_path / "c")
    png = next((tmp_path / "c" / "frames").iterdir())
    assert png.suffix == ".png" and Image.open(png).mode.startswith("I")
    _assert_same(cap, load(tmp_path / "c", undistort=False))


def test_load_undistorts_by_default(tmp_path):
    cap = _capture()
    save(cap, tmp_path / "c")
    back = load(tmp_path / "c")
    assert back.distortion is None and back.meta["undistorted"] is True
    assert back.frames.shape == cap.frames.shape
    assert not np.array_equal(back.frames, cap.frames)


def _leftovers(parent: Path, name: str):
    return [p.name for p in parent.iterdir() if p.name.startswith(f".{name}.")]


def test_save_invalid_capture_writes_nothing(tmp_path):
    cap = _capture()
    cap.c2w[1, 0, 0] = 2.0
    with pytest.raises(CaptureError, match=r"frames\[1\]\.c2w.*rigid"):
        save(cap, tmp_path / "bad")
    assert not (tmp_path / "bad").exists() and not _leftovers(tmp_path, "bad")


def test_save_failing_midway_leaves_nothing(tmp_path, monkeypatch):
    cap = _capture()
    calls = []

    def boom(path, img):
        calls.append(path)
        if len(calls) == 2:
            raise OSError("disk full")
        return real(path, img)

    real = fmt.write_image
    monkeypatch.setattr(fmt, "write_image", boom)
    with pytest.raises(OSError, match="disk full"):
        save(cap, tmp_path / "cap")
    assert not (tmp_path / "cap").exists() and not _leftovers(tmp_path, "cap")


def test_save_refuses_to_clobber_unless_asked(tmp_path):
    cap = _capture()
    save(cap, tmp_path / "c")
    with pytest.raises(CaptureError, match="already exists"):
        save(cap, tmp_path / "c")
    cap2 = _capture(seed=1)
    save(cap2, tmp_path / "c", overwrite=True)
    _assert_same(cap2, load(tmp_path / "c", undistort=False))
    assert not _leftovers(tmp_path, "c")


@pytest.fixture
def saved(tmp_path):
    save(_capture(), tmp_path / "c")
    root = tmp_path / "c"
    return root, json.loads((root / "capture.json").read_text())


def _rewrite(root, doc):
    (root / "capture.json").write_text(json.dumps(doc))


def test_missing_t_end_names_file_and_field(saved):
    root, doc = saved
    del doc["frames"][2]["t_end"]
    _rewrite(root, doc)
    with pytest.raises(CaptureError) as e:
        load(root)
    assert "capture.json" in str(e.value) and "frames[2].t_end" in str(e.value) and "missing" in str(e.value)
    assert e.value.field == "frames[2].t_end"


def test_frame_of_wrong_size_names_file_and_field(saved):
    root, doc = saved
    Image.fromarray(np.zeros((5, 7), np.uint8)).save(root / doc["frames"][1]["file"])
    with pytest.raises(CaptureError, match=r"f1\.png.*frames\[1\]\.file.*7x5"):
        load(root)


def test_unreadable_image_names_file_and_field(saved):
    root, doc = saved
    (root / doc["frames"][0]["file"]).write_bytes(b"not a png")
    with pytest.raises(CaptureError, match=r"f0\.png.*frames\[0\]\.file.*unreadable"):
        load(root)


def test_missing_image_names_file(saved):
    root, doc = saved
    (root / doc["frames"][0]["file"]).unlink()
    with pytest.raises(CaptureError, match=r"f0\.png.*not found"):
        load(root)


def _rewrite_events(root, **over):
    z = dict(np.load(root / "events.npz"))
    z.update(over)
    np.savez(root / "events.npz", **z)


def test_events_outside_sensor_name_file_and_field(saved):
    root, _ = saved
    z = dict(np.load(root / "events.npz"))
    x = z["x"].astype(np.int32)
    x[7] = 16
    _rewrite_events(root, x=x)
    with pytest.raises(CaptureError, match=r"events\.npz.*'x' is outside the sensor at index 7"):
        load(root)


def test_unsorted_events_name_file_and_field(saved):
    root, _ = saved
    z = dict(np.load(root / "events.npz"))
    t = z["t"].copy()
    t[10], t[11] = t[11] + 5, t[10]
    _rewrite_events(root, t=t)
    with pytest.raises(CaptureError, match=r"events\.npz.*'t' is not sorted"):
        load(root)


def test_non_finite_event_time(saved):
    root, doc = saved
    z = dict(np.load(root / "events.npz"))
    t = z["t"].astype(np.float64)
    t[3] = np.nan
    _rewrite_events(root, t=t)
    with pytest.raises(CaptureError, match=r"events\.npz.*non-finite"):
        load(root)


def test_pose_not_rigid_names_field(saved):
    root, doc = saved
    doc["frames"][0]["c2w"][0][0] = 1.5
    _rewrite(root, doc)
    with pytest.raises(CaptureError, match=r"capture\.json.*frames\[0\]\.c2w.*rigid"):
        load(root)


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d.pop("format"), "format"),
        (lambda d: d.update(format="other/2"), "format"),
        (lambda d: d["intrinsics"].pop("fy"), "intrinsics.fy"),
        (lambda d: d.update(width=-3), "width"),
        (lambda d: d["frames"][1].update(t_start="soon"), r"frames\[1\]\.t_start"),
        (lambda d: d["frames"][1].update(t_end=-1.0), r"frames\[1\]\.t_end"),
        (lambda d: d["frames"][2].pop("c2w"), r"frames\[2\]\.c2w"),
        (lambda d: d["events"].update(t_unit="fortnights"), r"events\.t_unit"),
        (lambda d: d["test_views"][0].pop("t"), r"test_views\[0\]\.t"),
        (lambda d: d.update(distortion=[1, 2]), "distortion"),
        # wrong types (issue 13 row 9): the field and what is wrong
        (lambda d: d["frames"][0].update(t_start="0.1"), r"frames\[0\]\.t_start.*must be a number, got '0.1'"),
        (lambda d: d.update(width="16"), "width.*positive integer"),
        (lambda d: d["frames"][1].update(file=3), r"frames\[1\]\.file.*string"),
        (lambda d: d["events"].update(file=["events.npz"]), r"events\.file.*string"),
        (lambda d: d.update(meta=[1, 2]), "meta.*object"),
        (lambda d: d.update(test_views={"a": 1}), "test_views.*list"),
        (lambda d: d["frames"][0].update(c2w="identity"), r"frames\[0\]\.c2w.*4x4"),
        (lambda d: d["intrinsics"].update(fx=None), r"intrinsics\.fx.*number"),
    ],
)
def test_bad_json_fields(saved, edit, field):
    root, doc = saved
    edit(doc)
    _rewrite(root, doc)
    with pytest.raises(CaptureError, match=rf"capture\.json.*{field}"):
        load(root)


def test_event_time_units_are_converted(saved):
    root, doc = saved
    z = dict(np.load(root / "events.npz"))
    ref = z["t"].copy()
    _rewrite_events(root, t=z["t"].astype(np.float64) * 1e-6)
    doc["events"]["t_unit"] = "s"
    _rewrite(root, doc)
    np.testing.assert_array_equal(load(root).events.t, ref)


def test_unknown_layout_and_missing_path(tmp_path):
    with pytest.raises(CaptureError, match="no such file"):
        load(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CaptureError, match="layout not recognised"):
        load(tmp_path / "empty")


def test_capture_validate_catches_bad_in_memory_fields():
    cap = _capture()
    cap.frames = cap.frames.astype(np.float64)
    with pytest.raises(CaptureError, match="frames.*float32"):
        cap.validate()
    cap = _capture()
    cap.exposures = cap.exposures[:2]
    with pytest.raises(CaptureError, match="exposures"):
        cap.validate()
    cap = _capture()
    cap.K = np.eye(3) * -1
    with pytest.raises(CaptureError, match="K"):
        cap.validate()


def test_h5_events_in_seconds_are_read(saved):
    import h5py

    root, doc = saved
    z = dict(np.load(root / "events.npz"))
    with h5py.File(root / "ev.h5", "w") as hf:
        g = hf.create_group("events")
        g["t"] = z["t"].astype(np.float64) * 1e-6
        g["x"], g["y"] = z["x"], z["y"]
        g["p"] = (z["p"] > 0).astype(np.uint8)  # {0, 1} polarities
    doc["events"] = {"file": "ev.h5", "t_unit": "s"}
    _rewrite(root, doc)
    cap = load(root)
    np.testing.assert_array_equal(cap.events.t, z["t"])
    np.testing.assert_array_equal(cap.events.p, z["p"])


def test_missing_event_array_names_file_and_field(saved):
    root, _ = saved
    z = dict(np.load(root / "events.npz"))
    del z["p"]
    np.savez(root / "events.npz", **z)
    with pytest.raises(CaptureError, match=r"events\.npz.*no events field 'p'"):
        load(root)


def test_sixteen_bit_colour_png_round_trips(tmp_path):
    """16-bit colour frames are written as 16-bit RGB PNG (our own encoder: Pillow truncates
    them) and read back exactly."""
    cap = _capture(rgb=True)
    cap.frames = quantize(np.random.default_rng(1).uniform(0, 1, cap.frames.shape).astype(np.float32), bits=16)
    save(cap, tmp_path / "c")
    pngs = sorted((tmp_path / "c" / "frames").iterdir())
    assert {p.suffix for p in pngs} == {".png"}
    head = pngs[0].read_bytes()[:29]
    assert head[24] == 16 and head[25] == 2  # 16 bits per sample, RGB
    np.testing.assert_array_equal(load(tmp_path / "c", undistort=False).frames, cap.frames)


# ---------------------------------------------------------------- near-rigid poses (issue 13 row 10)


@pytest.mark.parametrize("decimals", [4, 5])
def test_poses_rounded_to_a_few_decimals_load_re_orthonormalised(saved, decimals):
    root, doc = saved
    for fr in doc["frames"]:
        fr["c2w"] = np.round(np.array(fr["c2w"]), decimals).tolist()
    _rewrite(root, doc)
    rounded = np.array([fr["c2w"] for fr in doc["frames"]])
    r = rounded[:, :3, :3]
    assert np.abs(np.einsum("fji,fjk->fik", r, r) - np.eye(3)).max() > 10.0 ** -(decimals + 1)  # not rigid as written
    cap = load(root, undistort=False)
    rr = cap.c2w[:, :3, :3]
    np.testing.assert_allclose(np.einsum("fji,fjk->fik", rr, rr), np.broadcast_to(np.eye(3), rr.shape), atol=1e-12)
    np.testing.assert_allclose(cap.c2w, rounded, atol=2 * 10.0**-decimals)  # the nearest rotation, not another one
    np.testing.assert_array_equal(cap.c2w[:, :3, 3], rounded[:, :3, 3])


@pytest.mark.parametrize("scale", [1.01, 0.99, 1.002])
def test_pose_with_a_scale_is_refused(saved, scale):
    root, doc = saved
    doc["frames"][1]["c2w"] = (np.diag([scale, scale, scale, 1.0]) @ np.array(doc["frames"][1]["c2w"])).tolist()
    _rewrite(root, doc)
    with pytest.raises(CaptureError, match=r"capture\.json.*frames\[1\]\.c2w.*scales by"):
        load(root)


def test_pose_with_a_reflection_is_refused(saved):
    root, doc = saved
    doc["test_views"][0]["c2w"] = (np.diag([1.0, 1.0, -1.0, 1.0]) @ np.array(doc["test_views"][0]["c2w"])).tolist()
    _rewrite(root, doc)
    with pytest.raises(CaptureError, match=r"capture\.json.*test_views\[0\]\.c2w.*reflection"):
        load(root)


def test_nearest_rigid_within_tolerance_is_the_svd_rotation():
    from scipy.spatial.transform import Rotation

    for seed in range(5):
        rng = np.random.default_rng(seed)
        m = np.eye(4)
        m[:3, :3] = Rotation.random(random_state=seed).as_matrix()
        m[:3, 3] = rng.normal(size=3)
        noisy = m.copy()
        noisy[:3, :3] += rng.normal(scale=fmt.ROTATION_REPAIR_TOL / 20, size=(3, 3))
        fixed = fmt.nearest_rigid(noisy, "f", "c2w")
        u, _, vt = np.linalg.svd(noisy[:3, :3])
        np.testing.assert_allclose(fixed[:3, :3], u @ vt, atol=1e-14)
        np.testing.assert_allclose(fixed[:3, :3], m[:3, :3], atol=fmt.ROTATION_REPAIR_TOL)
        np.testing.assert_array_equal(fmt.nearest_rigid(m, "f", "c2w"), m)  # rigid input is untouched


# ---------------------------------------------------------------- corrupt files and wrong types (issue 13 row 9)


def test_truncated_events_npz_names_file(saved):
    root, _ = saved
    data = (root / "events.npz").read_bytes()
    (root / "events.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match=r"events\.npz.*events\.file.*unreadable"):
        load(root)


def test_corrupt_events_h5_names_file(saved):
    root, doc = saved
    (root / "ev.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100)
    doc["events"] = {"file": "ev.h5", "t_unit": "us"}
    _rewrite(root, doc)
    with pytest.raises(CaptureError, match=r"ev\.h5.*unreadable"):
        load(root)


def test_truncated_frame_png_names_file_and_field(saved):
    root, doc = saved
    p = root / doc["frames"][2]["file"]
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match=r"f2\.png.*frames\[2\]\.file.*unreadable"):
        load(root)


def test_capture_json_that_is_not_json(saved):
    root, _ = saved
    (root / "capture.json").write_text('{"format": "ebad-capture/1", "width": ')
    with pytest.raises(CaptureError, match=r"capture\.json.*not valid JSON"):
        load(root)


# ---------------------------------------------------------------- gt.json


def test_read_ground_truth_of_a_written_scene(tmp_path):
    from scenes import make_scene, write_scene

    scene = make_scene("boxes", "tiny", n_frames=3, n_test=1)
    write_scene(scene, tmp_path / "s", trajectory_samples=5)
    gt = fmt.read_ground_truth(tmp_path / "s" / "gt")
    names = scene.capture.names
    np.testing.assert_array_equal(gt.frames(names), scene.gt_frames)
    traj = gt.trajectory_c2w(names)
    assert traj.shape == (3, 5, 4, 4)
    np.testing.assert_allclose(traj[1], scene.gt_trajectory(1, 5))
    assert gt.frames(names + ["absent"]) is None and gt.trajectory_c2w(["absent"]) is None


def test_read_ground_truth_errors_name_file_and_field(tmp_path):
    with pytest.raises(CaptureError, match=r"gt\.json.*not found"):
        fmt.read_ground_truth(tmp_path)
    (tmp_path / "gt.json").write_text(
        json.dumps({"frames": [{"name": "a", "trajectory": {"t": [0, 1], "c2w": [[1]]}}]})
    )
    with pytest.raises(CaptureError, match=r"gt\.json.*frames\[0\]\.trajectory"):
        fmt.read_ground_truth(tmp_path)
