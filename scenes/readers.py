"""Readers for real recordings: the Event Camera Dataset text layout, AEDAT4 files and
EvDeblurNeRF-style folders, plus ``load`` which detects the layout.

Distortion: when a recording comes with radial-tangential distortion, ``load`` undistorts the
frames (bilinear resampling onto the pinhole grid with the same K) and moves every event to
the ideal pixel that contains its undistorted pixel centre (events leaving the sensor are
dropped and counted in ``meta['events_dropped_undistort']``); the returned Capture has
``distortion=None`` and ``meta['undistorted'] = True``. Pass ``undistort=False`` to carry the
distortion coefficients in ``Capture.distortion`` untouched instead.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from edi import EventError, EventStream

from .capture import Capture
from .errors import CaptureError
from .format import FORMAT, load_capture_folder
from .images import read_image
from .undistort import undistort_events, undistort_frames

__all__ = ["load", "load_ecd", "load_aedat4", "load_evdeblurnerf", "detect_layout", "interpolate_poses"]

ECD_CLAMP_S = 0.05  # frames up to this far outside the ground-truth time range take the end pose


def detect_layout(path: Path) -> str:
    """One of "ebad-capture/1", "aedat4", "ecd", "evdeblurnerf"; CaptureError if none fits."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(str(path), None, "no such file or folder")
    if path.is_file():
        if path.suffix.lower() == ".aedat4":
            return "aedat4"
        if path.name == "capture.json":
            return FORMAT
        raise CaptureError(str(path), None, "not a capture: expected a folder, capture.json or an .aedat4 file")
    if (path / "capture.json").is_file():
        return FORMAT
    if (path / "images.txt").is_file() and (path / "calib.txt").is_file():
        return "ecd"
    if (path / "poses_bounds.npy").is_file() and any((path / n).is_file() for n in ("events.h5", "events.npz", "events.txt")):
        return "evdeblurnerf"
    aed = sorted(path.glob("*.aedat4"))
    if len(aed) == 1:
        return "aedat4"
    raise CaptureError(str(path), None, "layout not recognised: expected capture.json (ebad-capture/1), an "
                                        ".aedat4 file, images.txt + calib.txt (Event Camera Dataset) or "
                                        "poses_bounds.npy + events.h5 (EvDeblurNeRF)")


def load(path: str | os.PathLike, undistort: bool = True, K: np.ndarray | None = None) -> Capture:
    """Read a capture in any supported layout (see :func:`detect_layout`).

    Args:
        path: a capture folder, its capture.json, or an .aedat4 file.
        undistort: undistort frames and events on load when the layout gives distortion
            (default), or carry the coefficients in ``Capture.distortion``.
        K: [3, 3] intrinsics for layouts without calibration (AEDAT4); ignored otherwise.

    Raises:
        CaptureError: unknown layout or malformed input; names the file and the field.
    """
    path = Path(path)
    layout = detect_layout(path)
    if layout == FORMAT:
        cap = load_capture_folder(path)
    elif layout == "ecd":
        cap = load_ecd(path)
    elif layout == "aedat4":
        cap = load_aedat4(path if path.is_file() else sorted(path.glob("*.aedat4"))[0], K=K)
    else:
        cap = load_evdeblurnerf(path)
    if undistort and cap.distortion is not None and np.any(np.asarray(cap.distortion) != 0):
        d = np.asarray(cap.distortion, dtype=np.float64)
        cap.frames = undistort_frames(cap.frames, cap.K, d)
        cap.events, dropped = undistort_events(cap.events, cap.K, d)
        cap.meta["undistorted"] = True
        cap.meta["distortion_removed"] = d.tolist()
        cap.meta["events_dropped_undistort"] = dropped
        cap.distortion = None
    return cap.validate(str(path))


# --------------------------------------------------------------------------- poses


def interpolate_poses(t_query: np.ndarray,  # [F] seconds
                      t_pose: np.ndarray,  # [P] seconds, increasing
                      pos: np.ndarray,  # [P, 3]
                      quat_xyzw: np.ndarray,  # [P, 4]
                      clamp_s: float = ECD_CLAMP_S) -> tuple[np.ndarray, np.ndarray]:
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


# --------------------------------------------------------------------------- ECD


def _loadtxt(path: Path, ncols: int, field: str, usecols=None) -> np.ndarray:
    if not path.is_file():
        raise CaptureError(str(path), field, "file not found")
    try:
        a = np.loadtxt(path, dtype=np.float64, comments="#", ndmin=2, usecols=usecols)
    except Exception as exc:
        raise CaptureError(str(path), field, f"unreadable ({type(exc).__name__}: {exc})") from None
    if a.shape[0] == 0 or a.shape[1] < ncols:
        raise CaptureError(str(path), field, f"expected rows of {ncols} numbers, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise CaptureError(str(path), field, "has a non-finite value")
    return a


def load_ecd(root: Path) -> Capture:
    """The Event Camera Dataset text layout (images.txt, events.txt, groundtruth.txt, calib.txt).

    Convention changes on load: calib.txt's principal point (OpenCV, pixel centres at integers)
    gets +0.5 (our centre-of-top-left-pixel (0.5, 0.5)); groundtruth.txt's ``t tx ty tz qx qy qz
    qw`` is camera-to-world and becomes c2w at each frame time (linear / slerp). Frames whose time
    is more than ECD_CLAMP_S outside the ground truth's range are dropped (listed in
    ``meta['dropped_frames']``); those within it take the end pose. APS exposure times are not in
    the layout: every frame gets t_start == t_end == its timestamp (sharp).
    """
    root = Path(root)
    calib = _loadtxt(root / "calib.txt", 4, "calib")[0]
    fx, fy, cx, cy = calib[:4]
    dist = np.zeros(5)
    dist[: min(5, len(calib) - 4)] = calib[4:9]
    K = np.array([[fx, 0.0, cx + 0.5], [0.0, fy, cy + 0.5], [0.0, 0.0, 1.0]])
    lines = []
    itxt = root / "images.txt"
    if not itxt.is_file():
        raise CaptureError(str(itxt), "images", "file not found")
    for ln, raw in enumerate(itxt.read_text().splitlines(), 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) < 2:
            raise CaptureError(str(itxt), f"line {ln}", "expected 't path'")
        try:
            t = float(parts[0])
        except ValueError:
            raise CaptureError(str(itxt), f"line {ln}.t", f"not a number: {parts[0]!r}") from None
        if not math.isfinite(t):
            raise CaptureError(str(itxt), f"line {ln}.t", "not finite")
        lines.append((t, parts[1]))
    if not lines:
        raise CaptureError(str(itxt), "images", "no frames listed")
    times = np.array([t for t, _ in lines])
    if np.any(np.diff(times) < 0):
        i = int(np.flatnonzero(np.diff(times) < 0)[0]) + 1
        raise CaptureError(str(itxt), f"frame {i}.t", "timestamps are not sorted")
    meta: dict = {"source_layout": "ecd", "source": str(root), "exposure_known": False}
    c2w = None
    keep = np.ones(len(lines), bool)
    gt_path = root / "groundtruth.txt"
    if gt_path.is_file():
        gt = _loadtxt(gt_path, 8, "groundtruth")
        if np.any(np.diff(gt[:, 0]) <= 0):
            raise CaptureError(str(gt_path), "t", "timestamps must increase")
        qn = np.linalg.norm(gt[:, 4:8], axis=1)
        if np.any(np.abs(qn - 1) > 1e-3):
            i = int(np.flatnonzero(np.abs(qn - 1) > 1e-3)[0])
            raise CaptureError(str(gt_path), f"row {i}.q", f"quaternion norm {qn[i]:.4f} is not 1")
        c2w, keep = interpolate_poses(times, gt[:, 0], gt[:, 1:4], gt[:, 4:8])
        c2w = c2w[keep]
        meta["dropped_frames"] = [lines[i][1] for i in np.flatnonzero(~keep)]
        meta["pose_source"] = "groundtruth.txt (interpolated to frame times)"
    frames = []
    for i in np.flatnonzero(keep):
        frames.append(read_image(root / lines[i][1], f"images.txt line {i + 1}"))
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise CaptureError(str(itxt), "images", f"frames differ in size/channels: {sorted(shapes)}")
    h, w, _ = frames[0].shape
    ev_path = root / "events.txt"
    if ev_path.is_file():
        ev = _loadtxt(ev_path, 4, "events", usecols=(0, 1, 2, 3))
        try:
            events = EventStream(np.round(ev[:, 0] * 1e6).astype(np.int64), ev[:, 1], ev[:, 2], ev[:, 3], w, h)
        except EventError as exc:
            raise CaptureError(str(ev_path), "events", str(exc)) from None
        meta["events_span_s"] = [float(ev[0, 0]), float(ev[-1, 0])]
    else:
        events = EventStream.empty(w, h)
    kt = times[keep]
    names = [Path(lines[i][1]).stem for i in np.flatnonzero(keep)]
    return Capture(frames=np.stack(frames), exposures=np.stack([kt, kt], 1), events=events, K=K,
                   distortion=dist if np.any(dist != 0) else None, c2w=c2w, split=["train"] * len(frames),
                   names=names, meta=meta)


# --------------------------------------------------------------------------- AEDAT4 / EvDeblurNeRF


def _edi_reader(name: str):
    import edi

    fn = getattr(edi, name, None)
    if fn is None:
        raise NotImplementedError(f"edi.{name} is not available yet; this layout needs it")
    return fn


DAVIS_DEFAULT_HFOV_DEG = 70.0  # used only when an AEDAT4 capture comes with no K


def load_aedat4(path: Path, K: np.ndarray | None = None) -> Capture:
    """An AEDAT4 recording: APS frames with exposure begin/end and events, no poses. AEDAT4
    holds no calibration: pass ``K``, or a guess from a 70-degree horizontal field of view is
    used and ``meta['K_guessed'] = True``."""
    path = Path(path)
    read = _edi_reader("read_aedat4")
    try:
        rec = read(path)
    except (ValueError, OSError) as exc:
        raise CaptureError(str(path), getattr(exc, "field", None), str(exc)) from None
    frames = np.asarray(rec.frames, dtype=np.float32)
    if frames.ndim != 4 or len(frames) == 0:
        raise CaptureError(str(path), "frames", f"the recording has no APS frames (got shape {frames.shape})")
    f, h, w, _ = frames.shape
    meta = {"source_layout": "aedat4", "source": str(path), "t0_us": int(getattr(rec, "t0", 0))}
    if K is None:
        fx = 0.5 * w / math.tan(math.radians(DAVIS_DEFAULT_HFOV_DEG) / 2)
        K = np.array([[fx, 0, w / 2], [0, fx, h / 2], [0, 0, 1.0]])
        meta["K_guessed"] = True
    return Capture(frames=frames, exposures=np.asarray(rec.exposures, dtype=np.float64), events=rec.events,
                   K=np.asarray(K, dtype=np.float64), split=["train"] * f, names=[f"{i:05d}" for i in range(f)],
                   meta=meta)


def load_evdeblurnerf(root: Path) -> Capture:
    """An EvDeblurNeRF-style folder: ``events.h5`` (or .npz/.txt), LLFF ``poses_bounds.npy``
    ([F, 17]: 3x5 matrix [R | t | (h, w, f)] in LLFF axes (x down, y right, z backward) and two
    depth bounds) and ``images_1/`` frames with ``images_1/timestamps.npz`` holding start and end
    times (seconds). Poses become OpenCV c2w: columns (x, y, z)_cv = (y, x, -z)_llff."""
    root = Path(root)
    read_events = _edi_reader("read_events")
    pb_path = root / "poses_bounds.npy"
    try:
        pb = np.load(pb_path, allow_pickle=False)
    except Exception as exc:
        raise CaptureError(str(pb_path), "poses_bounds", f"unreadable ({exc})") from None
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise CaptureError(str(pb_path), "poses_bounds", f"expected [F, 17], got {pb.shape}")
    img_dir = root / "images_1"
    files = sorted(p for p in img_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")) if img_dir.is_dir() else []
    if len(files) != len(pb):
        raise CaptureError(str(img_dir), "images", f"{len(files)} images for {len(pb)} poses")
    ts_path = img_dir / "timestamps.npz"
    try:
        with np.load(ts_path, allow_pickle=False) as z:
            keys = z.files
            start = next((z[k] for k in ("start", "t_start", "timestamps_start") if k in keys), None)
            end = next((z[k] for k in ("end", "t_end", "timestamps_end") if k in keys), None)
    except Exception as exc:
        raise CaptureError(str(ts_path), "timestamps", f"unreadable ({exc})") from None
    if start is None:
        raise CaptureError(str(ts_path), "start", "missing")
    if end is None:
        raise CaptureError(str(ts_path), "end", "missing")
    frames = np.stack([read_image(p, f"images_1/{p.name}") for p in files])
    f, h, w, _ = frames.shape
    hwf = pb[0, :15].reshape(3, 5)[:, 4]
    K = np.array([[hwf[2] * w / hwf[1], 0, w / 2], [0, hwf[2] * h / hwf[0], h / 2], [0, 0, 1.0]])
    c2w = np.tile(np.eye(4), (f, 1, 1))
    for i in range(f):
        m = pb[i, :15].reshape(3, 5)
        r, t = m[:, :4][:, :3], m[:, 3]
        c2w[i, :3, :3] = np.stack([r[:, 1], r[:, 0], -r[:, 2]], 1)
        c2w[i, :3, 3] = t
    ev_file = next(root / n for n in ("events.h5", "events.npz", "events.txt") if (root / n).is_file())
    try:
        events = read_events(ev_file, width=w, height=h)
    except (ValueError, OSError) as exc:
        raise CaptureError(str(ev_file), "events", str(exc)) from None
    exps = np.stack([np.asarray(start, np.float64).reshape(-1), np.asarray(end, np.float64).reshape(-1)], 1)
    if exps.shape != (f, 2) or not np.isfinite(exps).all():
        raise CaptureError(str(ts_path), "start", f"need {f} finite start and end times, got shape {exps.shape}")
    meta = {"source_layout": "evdeblurnerf", "source": str(root), "bounds": pb[:, 15:17].tolist()}
    if exps.max() > 1e3:  # not seconds of a short capture: microseconds on the events' raw clock
        exps = (exps - events.t0) * 1e-6
        meta["timestamps_unit"] = "us (converted to seconds on the events' clock)"
    return Capture(frames=frames, exposures=exps, events=events, K=K, c2w=c2w, split=["train"] * f,
                   names=[p.stem for p in files], meta=meta)
