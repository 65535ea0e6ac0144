"""The pose files users already have (issue 30, item 3): a COLMAP model, nerfstudio's
``transforms.json``, LLFF ``poses_bounds.npy`` and TUM trajectories as the poses of a capture's
frames, through ``python -m scenes.convert SRC --out DST --poses FILE``. Each format is written
here by an independent writer from known OpenCV c2w, converted, read back and compared to 1e-9."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import scenes
from edi import EventStream
from scenes.convert import main
from scenes.pose_files import PoseFile, apply_pose_file, guess_pose_format

F, W, H = 5, 8, 6
NAMES = ["frame_03", "frame_01", "frame_04", "frame_00", "frame_02"]  # frame order is not name order


def _c2w(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    out[:, :3, 3] = rng.normal(0, 2, (n, 3))
    return out


TRUTH = _c2w(0, F)
TEST_POSE = _c2w(1, 1)[0]


@pytest.fixture(scope="module")
def src(tmp_path_factory):
    """A tiny capture without poses (frames named out of order, one test view with an image)."""
    root = tmp_path_factory.mktemp("posefiles")
    rng = np.random.default_rng(0)
    frames = (np.round(rng.uniform(0, 1, (F, H, W, 1)) * 255) / 255).astype(np.float32)
    t0 = 0.1 * np.arange(F) + 0.01
    cap = scenes.Capture(
        frames=frames,
        exposures=np.stack([t0, t0 + 0.04], 1),
        events=EventStream.empty(W, H),
        K=np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]]),
        names=list(NAMES),
        test_views=[scenes.TestView(name="view_t", t=0.23, c2w=None, image=frames[0].copy())],
    )
    scenes.save(cap, root / "cap")
    return root / "cap"


def _mid() -> np.ndarray:
    t0 = 0.1 * np.arange(F) + 0.01
    return (t0 + (t0 + 0.04)) / 2


def _convert(src, tmp_path, pose_file, *extra) -> scenes.Capture:
    assert main([str(src), "--out", str(tmp_path / "out"), "--poses", str(pose_file), *extra]) == 0
    return scenes.load(tmp_path / "out")


def _write_colmap_txt(folder, names, c2w, fx: float = 10.0) -> None:
    """COLMAP's text model: images.txt rows ``ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` of
    world-to-camera, then an (empty) line of 2D points."""
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text(f"1 PINHOLE {W} {H} {fx} {fx} 4 3\n")
    lines = ["# Image list with two lines of data per image:"]
    for i, (n, m) in enumerate(zip(names, c2w), 1):
        r = m[:3, :3].T
        t = -r @ m[:3, 3]
        x, y, z, w = Rotation.from_matrix(r).as_quat()
        lines += [" ".join(repr(float(v)) for v in (w, x, y, z, *t)).join([f"{i} ", f" 1 {n}"]), ""]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text("")


@pytest.mark.parametrize("binary", [False, True])
def test_colmap_model_by_name(src, tmp_path, binary):
    # a COLMAP project folder: images/ and sparse/0, image names with the suffix, one extra image
    sparse = tmp_path / "proj" / "sparse" / "0"
    _write_colmap_txt(sparse, [f"{n}.png" for n in NAMES] + ["view_t.png", "other.png"], [*TRUTH, TEST_POSE, TRUTH[0]])
    if binary:
        import pycolmap

        rec = pycolmap.Reconstruction(str(sparse))
        for f in sparse.iterdir():
            f.unlink()
        rec.write_binary(str(sparse))
        assert (sparse / "images.bin").is_file()
    cap = _convert(src, tmp_path, tmp_path / "proj")
    np.testing.assert_allclose(cap.c2w, TRUTH, atol=1e-9)
    np.testing.assert_allclose(cap.test_views[0].c2w, TEST_POSE, atol=1e-9)
    assert cap.meta["pose_source"].startswith("colmap: ") and "pose_file_focal_differs" not in cap.meta


def test_nerfstudio_transforms_opengl_axes(src, tmp_path):
    # transform_matrix: camera-to-world with the camera's y up and z backwards (OpenGL)
    gl = TRUTH.copy()
    gl[:, :3, 1] *= -1
    gl[:, :3, 2] *= -1
    doc = {
        "camera_model": "OPENCV",
        "fl_x": 10.0,
        "frames": [{"file_path": f"images/{n}.png", "transform_matrix": m.tolist()} for n, m in zip(NAMES, gl)],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    cap = _convert(src, tmp_path, tmp_path / "transforms.json")
    np.testing.assert_allclose(cap.c2w, TRUTH, atol=1e-9)
    assert cap.test_views[0].c2w is None  # not in the file: left to SfM, never another gauge's pose


def _llff_rows(c2w) -> np.ndarray:
    rows = []
    for m in c2w:
        # LLFF's 3x5: rotation columns (down, right, backwards), translation, (h, w, f)
        pose = np.stack([m[:3, 1], m[:3, 0], -m[:3, 2], m[:3, 3], np.array([H, W, 10.0])], axis=1)
        rows.append(np.concatenate([pose.ravel(), [0.5, 20.0]]))
    return np.asarray(rows)


def test_llff_poses_bounds_rows_follow_sorted_names(src, tmp_path):
    order = np.argsort(NAMES)  # LLFF's imgs2poses lists the images sorted by name
    np.save(tmp_path / "poses_bounds.npy", _llff_rows(TRUTH[order]))
    cap = _convert(src, tmp_path, tmp_path / "poses_bounds.npy")
    np.testing.assert_allclose(cap.c2w, TRUTH, atol=1e-9)


def test_tum_trajectory_by_time_at_mid_exposure(src, tmp_path):
    mid = _mid()
    # poses at each mid-exposure, and one between frames 1 and 2 covering the test view's t
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, m in zip(mid, TRUTH):
        lines.append(" ".join(repr(float(v)) for v in (t, *m[:3, 3], *Rotation.from_matrix(m[:3, :3]).as_quat())))
    (tmp_path / "traj.txt").write_text("\n".join(lines) + "\n")
    cap = _convert(src, tmp_path, tmp_path / "traj.txt")
    np.testing.assert_allclose(cap.c2w, TRUTH, atol=1e-9)
    # the test view (t = 0.23, between the mid-exposures of frames 2 and 3) is interpolated
    a = (0.23 - mid[2]) / (mid[3] - mid[2])
    want_pos = (1 - a) * TRUTH[2, :3, 3] + a * TRUTH[3, :3, 3]
    rel = Rotation.from_matrix(TRUTH[2, :3, :3]).inv() * Rotation.from_matrix(TRUTH[3, :3, :3])
    want_rot = Rotation.from_matrix(TRUTH[2, :3, :3]) * Rotation.from_rotvec(a * rel.as_rotvec())
    np.testing.assert_allclose(cap.test_views[0].c2w[:3, 3], want_pos, atol=1e-9)
    np.testing.assert_allclose(cap.test_views[0].c2w[:3, :3], want_rot.as_matrix(), atol=1e-9)


def test_tum_interpolates_between_poses_with_slerp(src):
    # two poses 90 degrees apart about z, 1 s apart: a frame half-way gets 45 degrees
    cap = scenes.load(src)
    cap.c2w, cap.pose_trust = TRUTH.copy(), "exact"  # the old poses' trust is not the file's
    mid = _mid()
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, :3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    c2w[1, :3, 3] = [2.0, 0, 0]
    out = apply_pose_file(cap, PoseFile("t.txt", "tum", c2w, times=np.array([mid[0], mid[-1]])))
    a = (mid[2] - mid[0]) / (mid[-1] - mid[0])
    np.testing.assert_allclose(out.c2w[2, :3, 3], [2 * a, 0, 0], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(out.c2w[2, :3, :3]).as_euler("zyx", degrees=True)[0], 90 * a)
    assert out.pose_trust is None and cap.pose_trust == "exact"


@pytest.mark.parametrize(
    ("name", "fmt"),
    [("sparse", "colmap"), ("transforms.json", "transforms"), ("poses_bounds.npy", "llff"), ("t.txt", "tum")],
)
def test_format_from_the_name(tmp_path, name, fmt):
    p = tmp_path / name
    p.mkdir() if name == "sparse" else p.write_text("")
    assert guess_pose_format(p) == fmt


@pytest.mark.parametrize(
    ("write", "extra", "says"),
    [
        ("traj.csv", [], "--pose-format"),
        ("traj.txt", [], "outside the trajectory"),
        ("poses_bounds.npy", [], "has 2 rows for the capture's 5 frames"),
        ("transforms.json", [], "no pose for 4 of 5 frames"),
        ("missing.json", [], "not found"),
    ],
)
def test_mistakes_are_one_line_naming_the_file(src, tmp_path, capsys, write, extra, says):
    p = tmp_path / write
    if write == "traj.txt" or write == "traj.csv":
        p.write_text("0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 0 1\n")
    elif write == "poses_bounds.npy":
        np.save(p, _llff_rows(TRUTH[:2]))
    elif write == "transforms.json":
        p.write_text(json.dumps({"frames": [{"file_path": "x/frame_00.png", "transform_matrix": np.eye(4).tolist()}]}))
    assert main([str(src), "--out", str(tmp_path / "out"), "--poses", str(p), *extra]) == 2
    err = capsys.readouterr().err
    assert says in err and str(p) in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_pose_file_with_another_focal_length_is_said(src, tmp_path, capsys):
    sparse = tmp_path / "sparse" / "0"
    _write_colmap_txt(sparse, [f"{n}.png" for n in NAMES], TRUTH, fx=20.0)  # the capture's fx is 10
    cap = _convert(src, tmp_path, sparse / "images.txt")  # COLMAP's own images.txt names the model
    np.testing.assert_allclose(cap.c2w, TRUTH, atol=1e-9)
    assert (
        "warning: the pose file's camera has focal 20.0 px at this width, the capture 10.0 px"
        in capsys.readouterr().out
    )
