"""Camera poses in the conventions of other tools, turned into ours (OpenCV c2w).

- LLFF ``poses_bounds.npy`` [F, 17]: a 3x5 matrix per image, ``[R | t | (h, w, f)]``, with
  the rotation's columns pointing (down, right, backwards), then two depth bounds (near, far).
  OpenCV columns: x = right = column 1, y = down = column 0, z = forward = -column 2.
- NeRF / Blender ``transform_matrix``: camera-to-world in OpenGL axes (x right, y up,
  z backwards): ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``.
- Time interpolation: linear in position, slerp in rotation (:func:`interpolate_poses`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .errors import CaptureError

__all__ = ["interpolate_poses", "read_poses_bounds", "opengl_to_opencv", "LLFF_COLUMNS", "OPENGL_TO_OPENCV"]

LLFF_COLUMNS = 17  # 15 entries of the 3x5 [R | t | hwf] matrix, then near and far bounds
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])  # right-multiply: flips the camera's y and z axes


def interpolate_poses(
    t_query: np.ndarray,  # [F] seconds
    t_pose: np.ndarray,  # [P] seconds, increasing
    pos: np.ndarray,  # [P, 3]
    quat_xyzw: np.ndarray,  # [P, 4]
    clamp_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """c2w [F, 4, 4] at ``t_query`` (linear position, slerp rotation), and a [F] bool mask of the
    queries that could be served (inside the range, or within ``clamp_s`` of an end, where the end
    pose is used)."""
    rots = Rotation.from_quat(quat_xyzw)
    slerp = Slerp(t_pose, rots)
    ok = (t_query >= t_pose[0] - clamp_s) & (t_query <= t_pose[-1] + clamp_s)
    tq = np.clip(t_query, t_pose[0], t_pose[-1])
    out = np.tile(np.eye(4), (len(t_query), 1, 1))
    if ok.any():
        out[ok, :3, :3] = slerp(tq[ok]).as_matrix()
        for k in range(3):
            out[ok, k, 3] = np.interp(tq[ok], t_pose, pos[:, k])
    return out, ok


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:  # [..., 4, 4] -> [..., 4, 4]
    """A NeRF/Blender camera-to-world (OpenGL camera axes) as an OpenCV camera-to-world."""
    return np.asarray(c2w, dtype=np.float64) @ OPENGL_TO_OPENCV


def read_poses_bounds(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read an LLFF ``poses_bounds.npy``.

    Returns:
        c2w [F, 4, 4] OpenCV camera-to-world (not yet checked for rigidity),
        hwf [F, 3] (image height, width and focal length in pixels of that size),
        bounds [F, 2] (near, far).

    Raises:
        CaptureError: unreadable file or wrong shape, naming the file.
    """
    path = Path(path)
    try:
        pb = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise CaptureError(str(path), "poses_bounds", f"unreadable ({type(exc).__name__}: {exc})") from None
    if pb.ndim != 2 or pb.shape[1] != LLFF_COLUMNS or pb.shape[0] == 0:
        raise CaptureError(str(path), "poses_bounds", f"expected [F, {LLFF_COLUMNS}], got {pb.shape}")
    if not np.isfinite(pb).all():
        i = int(np.flatnonzero(~np.isfinite(pb).all(1))[0])
        raise CaptureError(str(path), f"poses_bounds[{i}]", "has a non-finite entry")
    m = pb[:, :15].reshape(-1, 3, 5).astype(np.float64)
    r, t = m[:, :, :3], m[:, :, 3]
    c2w = np.tile(np.eye(4), (len(pb), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2] = r[:, :, 1], r[:, :, 0], -r[:, :, 2]
    c2w[:, :3, 3] = t
    return c2w, m[:, :, 4].copy(), pb[:, 15:17].astype(np.float64)
