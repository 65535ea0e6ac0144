"""The pose files users already have, as the poses of a capture's frames (``--poses`` of
``python -m scenes.convert``).

Every format is read as OpenCV camera-to-world (x right, y down, z forward), the capture's own
convention, then matched to the frames:

- ``colmap``: a COLMAP model folder (``sparse/0`` with ``cameras``, ``images``, ``points3D`` as
  ``.bin`` or ``.txt``; a capture folder holding ``sparse/0`` is accepted), read with pycolmap.
  COLMAP stores world-to-camera (``cam_from_world``, quaternion w first) in OpenCV camera axes:
  ``c2w = inv(cam_from_world)``. Matched by name.
- ``transforms``: nerfstudio / instant-ngp / NeRF ``transforms.json``: ``frames[k].transform_matrix``
  is camera-to-world in OpenGL camera axes (x right, y up, z backwards):
  ``c2w = transform_matrix @ diag(1, -1, -1, 1)``. Matched by name (``file_path``).
- ``llff``: LLFF ``poses_bounds.npy`` [N, 17] (``scenes.poses.read_poses_bounds``: rotation columns
  down, right, backwards). It carries no names: row k is the k-th frame in the order of the
  frames' names (LLFF's ``imgs2poses`` sorts the image names), so N must equal the frame count.
- ``tum``: a TUM trajectory, ``timestamp tx ty tz qx qy qz qw`` per line (``#`` comments),
  camera-to-world, quaternion real part last, seconds on the capture's clock (what ``ebad``
  writes as ``trajectories_tum.txt``). Matched by time: the pose at each frame's mid-exposure
  (test view: its ``t``), linear in position and scipy ``Slerp`` in rotation; a time outside the
  trajectory is refused.

Matching by name compares file stems (``images/frame_0001.png`` -> ``frame_0001``) with the
frames' names (``Capture.names``); every frame needs a pose. Test views whose name (or time,
for ``tum``) the file covers get its pose; the others lose theirs (another file's gauge), and
SfM registers them from their images.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .capture import Capture, nearest_rigid
from .errors import CaptureError
from .poses import OPENGL_TO_OPENCV, interpolate_poses, read_poses_bounds

__all__ = ["POSE_FORMATS", "PoseFile", "guess_pose_format", "read_pose_file", "apply_pose_file"]

POSE_FORMATS = ("colmap", "transforms", "llff", "tum")
COLMAP_FILES = ("cameras", "images", "points3D")
FOCAL_MISMATCH = 0.02  # a pose file's focal length (per image width) this far from the capture's is said
PRINCIPAL_MISMATCH = 0.02  # and its principal point this far (a fraction of the width / height)


@dataclass
class FileCamera:
    """The intrinsics a pose file states, in pixels of its own image size (``cx``, ``cy`` None where
    the format has none: LLFF's hwf assumes the centre)."""

    width: float
    height: float
    fx: float
    fy: float
    cx: float | None = None
    cy: float | None = None


@dataclass
class PoseFile:
    """Poses read from a file: by name (``names``, colmap / transforms), in order (llff) or by
    time (``times``, tum); ``c2w`` [P, 4, 4] OpenCV camera-to-world."""

    path: str
    format: str
    c2w: np.ndarray  # [P, 4, 4]
    names: list[str] | None = None  # file stems, one per pose (by name)
    times: np.ndarray | None = None  # [P] seconds, increasing (by time)
    camera: FileCamera | None = None  # the file's intrinsics, when it has them


def _colmap_dir(path: Path) -> Path | None:
    for d in (path, path / "sparse" / "0", path / "0", path / "sparse"):
        if d.is_dir() and all((d / f"{n}.bin").is_file() or (d / f"{n}.txt").is_file() for n in COLMAP_FILES):
            return d
    return None


def guess_pose_format(path: str | Path) -> str:
    """The format of ``path`` from its kind and suffix (a folder: colmap; ``.json``: transforms;
    ``.npy``: llff; ``.txt``: tum, or colmap for COLMAP's own ``images.txt``/``cameras.txt``).

    Raises:
        CaptureError: the suffix says nothing (pass ``--pose-format``).
    """
    p = Path(path)
    if p.is_dir():
        return "colmap"
    suffix = p.suffix.lower()
    if suffix == ".txt" and p.stem in COLMAP_FILES:
        return "colmap"
    fmt = {".json": "transforms", ".npy": "llff", ".txt": "tum", ".tum": "tum"}.get(suffix)
    if fmt is None:
        raise CaptureError(
            str(p), "--poses", f"cannot tell the format from the name: pass --pose-format {{{','.join(POSE_FORMATS)}}}"
        )
    return fmt


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".npy")


def _stem(name: str) -> str:
    """``images/frame_0001.png`` -> ``frame_0001``: the file name without an image suffix."""
    p = PurePosixPath(name.replace("\\", "/"))
    return p.stem if p.suffix.lower() in IMAGE_SUFFIXES else p.name


def read_colmap(path: Path) -> PoseFile:
    """The registered images of a COLMAP model (see the module docstring)."""
    d = _colmap_dir(path if path.is_dir() else path.parent)
    if d is None:
        raise CaptureError(str(path), "--poses", "no COLMAP model here (cameras and images .bin or .txt, or sparse/0/)")
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(d))
    except Exception as exc:  # pycolmap raises plain RuntimeError/ValueError on malformed models
        raise CaptureError(str(d), "COLMAP model", f"unreadable ({type(exc).__name__}: {exc})") from None
    names, c2w = [], []
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        if not image.has_pose:
            continue
        m = np.eye(4)
        m[:3, :4] = image.cam_from_world().matrix()
        names.append(image.name)
        c2w.append(np.linalg.inv(m))
    if not names:
        raise CaptureError(str(d), "images", "no registered image")
    cam = next(iter(rec.cameras.values()), None)
    fc = None
    if cam is not None and cam.width and cam.height:  # COLMAP's pixel convention is ours
        k = np.asarray(cam.calibration_matrix(), dtype=np.float64)
        fc = FileCamera(float(cam.width), float(cam.height), k[0, 0], k[1, 1], k[0, 2], k[1, 2])
    return PoseFile(str(d), "colmap", np.stack(c2w), names=names, camera=fc)


def read_transforms(path: Path) -> PoseFile:
    """``frames[k].file_path`` and ``transform_matrix`` of a transforms.json (module docstring)."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(str(path), None, f"unreadable JSON ({type(exc).__name__}: {exc})") from None
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list) or not frames:
        raise CaptureError(str(path), "frames", "must be a non-empty list")
    names, c2w = [], []
    for k, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str):
            raise CaptureError(str(path), f"frames[{k}].file_path", "missing (a string naming the image)")
        m = nearest_rigid(fr.get("transform_matrix"), str(path), f"frames[{k}].transform_matrix")
        names.append(fr["file_path"])
        c2w.append(m @ OPENGL_TO_OPENCV)
    return PoseFile(str(path), "transforms", np.stack(c2w), names=names, camera=_transforms_camera(doc))


def _transforms_camera(doc: dict) -> FileCamera | None:
    """nerfstudio's ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h`` (fl_y defaults to fl_x, the
    principal point to the centre), or None without ``fl_x`` and ``w``."""

    def num(key: str) -> float | None:
        v = doc.get(key)
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None

    fx, w = num("fl_x"), num("w")
    if fx is None or w is None or w <= 0 or fx <= 0:
        return None
    h = num("h")
    h = h if h is not None and h > 0 else None
    fy = num("fl_y") or fx
    cx, cy = num("cx"), num("cy")
    return FileCamera(w, h if h is not None else w, fx, fy if h is not None else fx, cx, cy if h is not None else None)


def read_llff(path: Path) -> PoseFile:
    """The rows of a ``poses_bounds.npy`` in order (module docstring)."""
    c2w, hwf, _ = read_poses_bounds(path)
    h, w, f = (float(v) for v in hwf[0])
    fc = FileCamera(w, h, f, f) if h > 0 and w > 0 and f > 0 else None  # LLFF: one focal, centred
    poses = np.stack([nearest_rigid(m, str(path), f"row {i}") for i, m in enumerate(c2w)])
    return PoseFile(str(path), "llff", poses, camera=fc)


def read_tum_file(path: Path) -> PoseFile:
    """A TUM trajectory (module docstring); repeated timestamps keep their first pose."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureError(str(path), None, f"unreadable ({type(exc).__name__}: {exc})") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            vals = [float(v) for v in s.replace(",", " ").split()]
        except ValueError:
            vals = []
        if len(vals) != 8 or not all(math.isfinite(v) for v in vals):
            raise CaptureError(str(path), f"line {n}", "expected 8 finite numbers 'timestamp tx ty tz qx qy qz qw'")
        rows.append(vals)
    if not rows:
        raise CaptureError(str(path), None, "no poses")
    a = np.asarray(rows, dtype=np.float64)
    if np.any(np.diff(a[:, 0]) < 0):
        i = int(np.flatnonzero(np.diff(a[:, 0]) < 0)[0]) + 1
        raise CaptureError(str(path), f"pose {i}.timestamp", "timestamps must not decrease")
    first = np.concatenate([[True], np.diff(a[:, 0]) > 0])
    a = a[first]
    qn = np.linalg.norm(a[:, 4:8], axis=1)
    if np.any(np.abs(qn - 1) > 1e-3):
        i = int(np.flatnonzero(np.abs(qn - 1) > 1e-3)[0])
        raise CaptureError(str(path), f"pose {i}.q", f"quaternion norm {qn[i]:.4f} is not 1")
    c2w = np.tile(np.eye(4), (len(a), 1, 1))
    c2w[:, :3, :3] = Rotation.from_quat(a[:, 4:8]).as_matrix()
    c2w[:, :3, 3] = a[:, 1:4]
    return PoseFile(str(path), "tum", c2w, times=a[:, 0].copy())


def read_pose_file(path: str | Path, fmt: str | None = None) -> PoseFile:
    """Read a pose file of format ``fmt`` (one of ``POSE_FORMATS``; None: :func:`guess_pose_format`).

    Raises:
        CaptureError: a missing, unreadable or malformed file, naming it and the field.
    """
    p = Path(path)
    if not p.exists():
        raise CaptureError(str(p), "--poses", "not found")
    fmt = fmt or guess_pose_format(p)
    if fmt not in POSE_FORMATS:
        raise CaptureError(str(p), "--pose-format", f"must be one of {', '.join(POSE_FORMATS)}, got {fmt!r}")
    if fmt != "colmap" and p.is_dir():
        raise CaptureError(str(p), "--poses", f"a {fmt} pose file must be a file, not a folder")
    reader = {"colmap": read_colmap, "transforms": read_transforms, "llff": read_llff, "tum": read_tum_file}[fmt]
    return reader(p)


def _by_name(pf: PoseFile) -> dict[str, np.ndarray]:
    assert pf.names is not None
    out: dict[str, np.ndarray] = {}
    for name, m in zip(pf.names, pf.c2w):
        s = _stem(name)
        if s in out:
            raise CaptureError(pf.path, "names", f"two poses for images named {s!r}")
        out[s] = m
    return out


def _at_times(pf: PoseFile, t: np.ndarray, what: list[str]) -> np.ndarray:  # [Q] -> [Q, 4, 4]
    assert pf.times is not None
    if len(pf.times) == 1:
        ok = t == pf.times[0]
        out = np.repeat(pf.c2w, len(t), axis=0)
    else:
        quat = Rotation.from_matrix(pf.c2w[:, :3, :3]).as_quat()
        out, ok = interpolate_poses(t, pf.times, pf.c2w[:, :3, 3], quat)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        i = int(bad[0])
        more = f" and {len(bad) - 1} more lie" if len(bad) > 1 else " lies"
        raise CaptureError(
            pf.path,
            "timestamp",
            f"{what[i]} (t = {t[i]:.6f} s){more} outside the trajectory's {pf.times[0]:.6f}..{pf.times[-1]:.6f} s "
            "(seconds on the capture's clock): a pose is never extrapolated, give a trajectory that covers every frame",
        )
    return out


def apply_pose_file(cap: Capture, pf: PoseFile) -> Capture:
    """``cap`` with its frames' (and matching test views') poses from ``pf`` (``cap`` is not changed),
    its ``pose_trust`` unstated (the trust of the poses it had says nothing of these).

    Raises:
        CaptureError: a frame the file has no pose for (names it), a count mismatch (llff).
    """
    names = cap.frame_names()
    tv_pose: list[np.ndarray | None]
    if pf.format == "tum":
        mid = np.asarray(cap.exposures, dtype=np.float64).mean(axis=1)
        c2w = _at_times(pf, mid, [f"frame {n}" for n in names])
        assert pf.times is not None
        tv_t = np.array([v.t for v in cap.test_views], dtype=np.float64)
        inside = (tv_t >= pf.times[0]) & (tv_t <= pf.times[-1])
        tv_pose = [None] * len(cap.test_views)
        if inside.any():
            got = _at_times(pf, tv_t[inside], [v.name for v, i in zip(cap.test_views, inside) if i])
            for k, j in enumerate(np.flatnonzero(inside)):
                tv_pose[j] = got[k]
    elif pf.format == "llff":
        if len(pf.c2w) != cap.num_frames:
            raise CaptureError(
                pf.path,
                "poses",
                f"has {len(pf.c2w)} rows for the capture's {cap.num_frames} frames (row k is the k-th frame by name)",
            )
        order = sorted(range(cap.num_frames), key=lambda i: names[i])
        c2w = np.empty_like(pf.c2w)
        c2w[order] = pf.c2w
        tv_pose = [None] * len(cap.test_views)
    else:
        table = _by_name(pf)
        missing = [n for n in names if _stem(n) not in table]
        if missing:
            shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
            raise CaptureError(pf.path, "names", f"no pose for {len(missing)} of {len(names)} frames: {shown}")
        c2w = np.stack([table[_stem(n)] for n in names])
        tv_pose = [table.get(_stem(v.name)) for v in cap.test_views]
    views = [
        dataclasses.replace(v, c2w=None if m is None else np.array(m, dtype=np.float64))
        for v, m in zip(cap.test_views, tv_pose)
    ]
    unposed = [v.name for v in views if v.c2w is None and v.image is None]
    if unposed:
        raise CaptureError(pf.path, "test views", f"no pose for test view {unposed[0]!r}, which has no image either")
    meta: dict[str, Any] = {**cap.meta, "pose_source": f"{pf.format}: {pf.path}"}
    meta.pop("pose_file_focal_differs", None)
    differs = _intrinsics_differ(pf.camera, cap)
    if differs:
        meta["pose_file_focal_differs"] = differs
    # the trust stated for the capture's old poses says nothing of these: unstated (approximate) until
    # the user states it (``--pose-trust``)
    return dataclasses.replace(cap, c2w=np.asarray(c2w, dtype=np.float64), test_views=views, meta=meta, pose_trust=None)


def _intrinsics_differ(cam: FileCamera | None, cap: Capture) -> str:
    """A warning naming the pose file's intrinsics and the capture's K where they differ beyond
    ``FOCAL_MISMATCH`` (focal lengths, relative) or ``PRINCIPAL_MISMATCH`` (principal point, a
    fraction of the size), the file's scaled to the capture's size; "" when they agree. K is never
    replaced: the user decides which is right."""
    if cam is None:
        return ""
    K = np.asarray(cap.K, dtype=np.float64)
    sx, sy = cap.width / cam.width, cap.height / cam.height
    fx, fy = cam.fx * sx, cam.fy * sy
    rx, ry = fx / K[0, 0], fy / K[1, 1]
    parts = []
    if abs(rx - 1) > FOCAL_MISMATCH:
        parts.append(f"focal {fx:.1f} px at this width, the capture {K[0, 0]:.1f} px")
    if abs(ry - 1) > FOCAL_MISMATCH and not (parts and abs(ry - rx) <= FOCAL_MISMATCH):  # fy off in its own way
        parts.append(f"fy {fy:.1f} px, the capture {K[1, 1]:.1f} px")
    if cam.cx is not None and cam.cy is not None:
        cx, cy = cam.cx * sx, cam.cy * sy
        if abs(cx - K[0, 2]) > PRINCIPAL_MISMATCH * cap.width or abs(cy - K[1, 2]) > PRINCIPAL_MISMATCH * cap.height:
            parts.append(f"principal point ({cx:.1f}, {cy:.1f}) px, the capture ({K[0, 2]:.1f}, {K[1, 2]:.1f}) px")
    if not parts:
        return ""
    return (
        "the pose file's camera has "
        + "; ".join(parts)
        + ": poses estimated with other intrinsics may be off (check the capture's K, or --intrinsics)"
    )
