"""A pose file's intrinsics against the capture's K (issue 30): COLMAP's cameras.txt, nerfstudio's
fl_x / fl_y / cx / cy and LLFF's hwf, scaled to the capture's size; beyond a small tolerance a warning
names both, and K is never replaced."""
# ruff: noqa: F811  (``src``, test_pose_files.py's capture fixture, is imported and used as a fixture)

import json

import numpy as np
import pytest

import scenes
from scenes.pose_files import apply_pose_file, read_pose_file
from tests.scenes.test_pose_files import NAMES, TRUTH, H, W, _llff_rows, _write_colmap_txt, src  # noqa: F401

TAIL = ": poses estimated with other intrinsics may be off (check the capture's K, or --intrinsics)"
K = np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]])  # the capture's (src)


def _said(src, path) -> str:
    cap = scenes.load(src)
    out = apply_pose_file(cap, read_pose_file(path))
    np.testing.assert_array_equal(out.K, K)  # never replaced
    np.testing.assert_allclose(out.c2w, TRUTH, atol=1e-9)
    return out.meta.get("pose_file_focal_differs", "")


def _transforms(tmp_path, **camera) -> object:
    gl = TRUTH.copy()
    gl[:, :3, 1:3] *= -1
    frames = [{"file_path": f"images/{n}.png", "transform_matrix": m.tolist()} for n, m in zip(NAMES, gl)]
    p = tmp_path / "transforms.json"
    p.write_text(json.dumps({**camera, "frames": frames}))
    return p


def test_colmap_principal_point_differs(src, tmp_path):
    sparse = tmp_path / "sparse" / "0"
    _write_colmap_txt(sparse, [f"{n}.png" for n in NAMES], TRUTH)
    assert _said(src, sparse) == ""
    (sparse / "cameras.txt").write_text(f"1 PINHOLE {W} {H} 10 10 6 3\n")
    assert (
        _said(src, sparse)
        == "the pose file's camera has principal point (6.0, 3.0) px, the capture (4.0, 3.0) px" + TAIL
    )


@pytest.mark.parametrize(
    "camera, says",
    [
        (dict(fl_x=20.0, w=W, h=H, cx=4.0, cy=3.0), "focal 20.0 px at this width, the capture 10.0 px"),
        (dict(fl_x=20.0, fl_y=20.0, w=2 * W, h=2 * H, cx=8.0, cy=6.0), ""),  # twice the size: the same camera
        (dict(fl_x=10.0, fl_y=14.0, w=W, h=H), "fy 14.0 px, the capture 10.0 px"),
        (
            dict(fl_x=15.0, fl_y=21.0, w=W, h=H, cx=4.0, cy=5.0),
            "focal 15.0 px at this width, the capture 10.0 px; fy 21.0 px, the capture 10.0 px; "
            "principal point (4.0, 5.0) px, the capture (4.0, 3.0) px",
        ),
        (dict(fl_x=10.1, w=W, h=H, cx=4.1, cy=3.0), ""),  # within 2 %
        (dict(fl_x=20.0), ""),  # no image size: nothing to compare
    ],
)
def test_nerfstudio_intrinsics(src, tmp_path, camera, says):
    said = _said(src, _transforms(tmp_path, **camera))
    assert said == (f"the pose file's camera has {says}{TAIL}" if says else "")


@pytest.mark.parametrize("f, says", [(10.0, ""), (15.0, "focal 15.0 px at this width, the capture 10.0 px")])
def test_llff_hwf(src, tmp_path, f, says):
    order = np.argsort(NAMES)
    rows = _llff_rows(TRUTH[order])
    rows[:, 14] = f  # the 3x5's last column holds (h, w, f): f is entry 14
    np.save(tmp_path / "poses_bounds.npy", rows)
    assert _said(src, tmp_path / "poses_bounds.npy") == (f"the pose file's camera has {says}{TAIL}" if says else "")
