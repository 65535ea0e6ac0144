"""Real layouts: the Event Camera Dataset's slider_depth, pose interpolation, AEDAT4."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scenes import CaptureError, load, save
from scenes.readers import detect_layout, interpolate_poses
from scenes.undistort import distort_normalized, undistort_normalized

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
SLIDER = SHARED / "data" / "slider_depth"
STREET = SHARED / "data" / "davis346_street" / "davis346_street.aedat4"
needs_slider = pytest.mark.skipif(not SLIDER.is_dir(), reason=f"shared data not found at {SLIDER}")


def test_interpolate_poses_linear_and_slerp():
    tp = np.array([0.0, 1.0, 2.0])
    pos = np.array([[0, 0, 0], [1, 2, 3], [3, 2, 1]], float)
    q = Rotation.from_euler("z", [[0], [40], [80]], degrees=True).as_quat()
    c2w, ok = interpolate_poses(np.array([0.5, 1.75, -0.01, 2.03, 5.0]), tp, pos, q, clamp_s=0.05)
    np.testing.assert_array_equal(ok, [True, True, True, True, False])
    np.testing.assert_allclose(c2w[0, :3, 3], [0.5, 1.0, 1.5])
    np.testing.assert_allclose(c2w[1, :3, 3], [2.5, 2.0, 1.5])
    ang = Rotation.from_matrix(c2w[:4, :3, :3]).as_euler("zyx", degrees=True)[:, 0]
    np.testing.assert_allclose(ang, [20.0, 70.0, 0.0, 80.0], atol=1e-9)


def test_undistort_inverts_distort():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.5, 0.5, (100, 2))
    d = np.array([-0.14, 0.09, -3e-4, 2e-4, 0.0])
    np.testing.assert_allclose(undistort_normalized(distort_normalized(xy, d), d), xy, atol=1e-9)


@needs_slider
def test_slider_depth_loads_with_poses_at_frame_times():
    assert detect_layout(SLIDER) == "ecd"
    cap = load(SLIDER, undistort=False)
    assert cap.frames.shape == (87, 180, 240, 1) and cap.frames.dtype == np.float32
    calib = np.loadtxt(SLIDER / "calib.txt")
    np.testing.assert_allclose(cap.K[0, 2], calib[2] + 0.5)  # OpenCV centre -> (0.5, 0.5) convention
    np.testing.assert_allclose(cap.distortion, calib[4:9])
    assert len(cap.events) == 50_000 and cap.events.t[0] == 3811
    times = np.array([float(line.split()[0]) for line in (SLIDER / "images.txt").read_text().split("\n") if line])
    np.testing.assert_array_equal(cap.exposures[:, 0], times)
    gt = np.loadtxt(SLIDER / "groundtruth.txt")
    # frame 20 lies between two ground-truth rows: linear interpolation of the position
    i = int(np.searchsorted(gt[:, 0], times[20])) - 1
    a = (times[20] - gt[i, 0]) / (gt[i + 1, 0] - gt[i, 0])
    assert 0 < a < 1
    np.testing.assert_allclose(cap.c2w[20, :3, 3], (1 - a) * gt[i, 1:4] + a * gt[i + 1, 1:4], atol=1e-12)
    # the slider moves along x by about 1 m, orientation fixed
    assert 0.9 < cap.c2w[-1, 0, 3] - cap.c2w[0, 0, 3] < 1.1
    np.testing.assert_allclose(cap.c2w[:, :3, :3], np.broadcast_to(np.eye(3), (87, 3, 3)), atol=1e-6)
    # frame 0 (t = 0) is 22 ms before the first pose: clamped, not dropped
    assert cap.meta["dropped_frames"] == []


@needs_slider
def test_slider_depth_undistorted_by_default_and_saves(tmp_path):
    cap = load(SLIDER)
    assert cap.distortion is None and cap.meta["undistorted"]
    assert 0 < cap.meta["events_dropped_undistort"] < 5000
    assert len(cap.events) == 50_000 - cap.meta["events_dropped_undistort"]
    save(cap, tmp_path / "sd")
    back = load(tmp_path / "sd")
    np.testing.assert_array_equal(back.frames, cap.frames)
    np.testing.assert_array_equal(back.c2w, cap.c2w)


@needs_slider
def test_ecd_bad_calib_names_file(tmp_path):
    import shutil

    root = tmp_path / "ecd"
    shutil.copytree(SLIDER, root, ignore=shutil.ignore_patterns("events.txt"))
    (root / "calib.txt").write_text("1 2\n")
    with pytest.raises(CaptureError, match=r"calib\.txt.*calib"):
        load(root)


needs_street = pytest.mark.skipif(not STREET.is_file(), reason=f"shared recording not found at {STREET}")


@needs_street
def test_aedat4_loads():
    cap = load(STREET)
    assert cap.frames.shape[1:] == (260, 346, 1)
    assert cap.c2w is None and cap.meta["K_guessed"]
    assert np.all(cap.exposures[:, 1] >= cap.exposures[:, 0])
    assert len(cap.events) > 0


def test_aedat4_without_the_aedat_package_says_how_to_install(tmp_path, monkeypatch):
    import sys

    (tmp_path / "rec.aedat4").write_bytes(b"#!AER-DAT4.0\r\n")
    for mod in ("aedat", "dv_processing"):
        monkeypatch.setitem(sys.modules, mod, None)  # import fails as if not installed
    with pytest.raises(CaptureError, match=r"rec\.aedat4.*'aedat' package: pip install aedat"):
        load(tmp_path / "rec.aedat4")


@needs_street
def test_truncated_aedat4_names_the_file(tmp_path):
    data = STREET.read_bytes()
    (tmp_path / "cut.aedat4").write_bytes(data[: len(data) // 3])
    with pytest.raises(CaptureError, match=r"cut\.aedat4.*unreadable AEDAT4 recording"):
        load(tmp_path / "cut.aedat4")


def _write_evdeblurnerf(root: Path, cap, t_scale=1.0):
    """An EvDeblurNeRF-style folder from a Capture (LLFF poses: columns down, right, backwards)."""
    import h5py
    from PIL import Image

    (root / "images_1").mkdir(parents=True)
    f, h, w, _ = cap.frames.shape
    rows = []
    for i in range(f):
        c = cap.c2w[i]
        r = np.stack([c[:3, 1], c[:3, 0], -c[:3, 2]], 1)
        m = np.concatenate([r, c[:3, 3:4], np.array([[h], [w], [cap.K[0, 0]]])], 1)
        rows.append(np.concatenate([m.ravel(), [0.5, 20.0]]))
        Image.fromarray(np.round(cap.frames[i, ..., 0] * 255).astype(np.uint8)).save(root / "images_1" / f"{i:03d}.png")
    np.save(root / "poses_bounds.npy", np.array(rows))
    np.savez(
        root / "images_1" / "timestamps.npz", start=cap.exposures[:, 0] * t_scale, end=cap.exposures[:, 1] * t_scale
    )
    with h5py.File(root / "events.h5", "w") as hf:
        g = hf.create_group("events")
        for k in "txyp":
            g[k] = getattr(cap.events, k)
        hf["width"], hf["height"] = w, h


def test_evdeblurnerf_folder_loads(tmp_path):
    from scenes import make_scene

    cap = make_scene("boxes", "tiny", n_frames=3, n_test=0).capture
    _write_evdeblurnerf(tmp_path / "e", cap)
    assert detect_layout(tmp_path / "e") == "evdeblurnerf"
    back = load(tmp_path / "e")
    np.testing.assert_array_equal(back.frames, cap.frames)
    np.testing.assert_allclose(back.c2w, cap.c2w, atol=1e-12)
    np.testing.assert_allclose(back.K, cap.K)
    np.testing.assert_allclose(back.exposures, cap.exposures)
    np.testing.assert_array_equal(back.events.t, cap.events.t)
    assert back.meta["bounds"][0] == [0.5, 20.0]


def test_evdeblurnerf_missing_end_times_names_file_and_field(tmp_path):
    from scenes import make_scene

    cap = make_scene("boxes", "tiny", n_frames=2, n_test=0).capture
    _write_evdeblurnerf(tmp_path / "e", cap)
    np.savez(tmp_path / "e" / "images_1" / "timestamps.npz", start=cap.exposures[:, 0])
    with pytest.raises(CaptureError, match=r"timestamps\.npz.*'end'.*missing"):
        load(tmp_path / "e")
