"""Readers for real recordings and published datasets, plus ``load`` which detects the layout.

Layouts: ``ebad-capture/1`` (scenes.format), the Event Camera Dataset text layout, AEDAT4
files, EvDeblurNeRF folders, EBAD-NeRF / E2NeRF folders (scenes.e2nerf) and ROS1 bags of the
rpg_dvs_ros driver (scenes.rosbag, needs the ``ros`` extra).

Distortion: when a recording comes with radial-tangential distortion, ``load`` undistorts the
frames (bilinear resampling onto the pinhole grid with the same K) and moves every event to
the ideal pixel that contains its undistorted pixel centre (events leaving the sensor are
dropped and counted in ``meta['events_dropped_undistort']``); the returned Capture has
``distortion=None`` and ``meta['undistorted'] = True``. Pass ``undistort=False`` to carry the
distortion coefficients in ``Capture.distortion`` untouched instead. A capture with a colour
filter (``Capture.cfa``) keeps it true on the ideal grid: each event moves to the nearest pixel
of its own channel, and raw mosaics are demosaiced, resampled and mosaicked again
(``_undistort_cfa``).
"""

from __future__ import annotations

import math
import os
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from edi import CorruptFileError, EbadError, EventStream, read_aedat4
from edi.cfa import check_pattern

from .capture import Capture, frame_name, guess_K
from .cdavis import CDAVIS_CFA, EV_MAP, read_cdavis_events, snap_to_channel
from .e2nerf import LLFF_HOLD, detect_e2nerf, load_e2nerf, load_ebad_nerf
from .errors import CaptureError
from .format import FORMAT, decode_events, load_capture_folder, nearest_rigid
from .images import read_image
from .poses import interpolate_poses, read_poses_bounds
from .rosbag import load_rosbag
from .undistort import undistort_events, undistort_frames

__all__ = [
    "load",
    "load_ecd",
    "load_aedat4",
    "load_evdeblurnerf",
    "detect_layout",
    "interpolate_poses",
    "LAYOUTS",
    "AEDAT_INSTALL",
]

ECD_CLAMP_S = 0.05  # frames up to this far outside the ground-truth time range take the end pose
#: the layouts ``load`` reads (``detect_layout`` names one)
Layout = Literal["ebad-capture/1", "aedat4", "ecd", "evdeblurnerf", "ebad-nerf", "e2nerf", "rosbag1"]
LAYOUTS: tuple[Layout, ...] = get_args(Layout)
AEDAT_INSTALL = "pip install aedat (part of ebad's install)"


def detect_layout(path: str | os.PathLike) -> Layout:
    """One of :data:`LAYOUTS`; CaptureError if none fits."""
    path = Path(path)
    if not path.exists():
        raise CaptureError(str(path), None, "no such file or folder")
    if path.is_file():
        if path.suffix.lower() == ".aedat4":
            return "aedat4"
        if path.suffix.lower() == ".bag":
            return "rosbag1"
        if path.name == "capture.json":
            return FORMAT
        raise CaptureError(str(path), None, "not a capture: expected a folder, capture.json, an .aedat4 or a .bag file")
    if (path / "capture.json").is_file():
        return FORMAT
    if (path / "images.txt").is_file() and (path / "calib.txt").is_file():
        return "ecd"
    e2 = detect_e2nerf(path)
    if e2 is not None:
        return e2
    if (path / "poses_bounds.npy").is_file() and any(
        (path / n).is_file() for n in ("events.h5", "events.npz", "events.txt")
    ):
        return "evdeblurnerf"
    single_files: tuple[tuple[str, Layout], ...] = ((".aedat4", "aedat4"), (".bag", "rosbag1"))
    for suffix, layout in single_files:
        found = sorted(path.glob(f"*{suffix}"))
        if len(found) == 1:
            return layout
    raise CaptureError(
        str(path),
        None,
        "layout not recognised: expected capture.json (ebad-capture/1), an "
        ".aedat4 or .bag file, images.txt + calib.txt (Event Camera Dataset), "
        "events.pt + poses_bounds.npy or transforms_train.json (EBAD-NeRF / "
        "E2NeRF) or poses_bounds.npy + events.h5 (EvDeblurNeRF)",
    )


def _single_file(path: Path, suffix: str) -> Path:
    return path if path.is_file() else sorted(path.glob(f"*{suffix}"))[0]


def load(
    path: str | os.PathLike,
    undistort: bool = True,
    K: np.ndarray | None = None,
    exposure_us: int | None = None,
    llffhold: int = LLFF_HOLD,
    cfa: str | None = None,
) -> Capture:
    """Read a capture in any supported layout (see :func:`detect_layout`).

    Args:
        path: a capture folder, its capture.json, an .aedat4 or a ROS1 .bag file.
        undistort: undistort frames and events on load when the layout gives distortion
            (default), or carry the coefficients in ``Capture.distortion``.
        K: [3, 3] intrinsics for layouts without calibration (AEDAT4, a bag without
            camera_info); ignored otherwise.
        exposure_us: APS exposure in microseconds for a ROS bag that did not record
            ``/dvs/exposure``; ignored otherwise.
        llffhold: EBAD-NeRF layout: every ``llffhold``-th view is held out (when
            ``images_gt_novel/`` exists).
        cfa: the Bayer pattern of a colour DAVIS (``edi.cfa.CFA_PATTERNS``, in the frames'
            pixel grid) when the layout does not record it, or ``"none"``: take the events as
            luminance whatever the file records. None (default): what the file records.
            A pattern that disagrees with the one the file records is refused (CaptureError
            naming ``cfa``): the file's record is the camera's own statement (frames flipped or
            cropped by a reader carry the transformed pattern already).

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
        cap = load_aedat4(_single_file(path, ".aedat4"), K=K)
    elif layout == "rosbag1":
        cap = load_rosbag(_single_file(path, ".bag"), K=K, exposure_us=exposure_us)
    elif layout == "ebad-nerf":
        cap = load_ebad_nerf(path, llffhold=llffhold)
    elif layout == "e2nerf":
        cap = load_e2nerf(path)
    else:
        cap = load_evdeblurnerf(path)
    if cfa is not None:
        _state_cfa(cap, cfa, str(path))
    if undistort and cap.distortion is not None and np.any(np.asarray(cap.distortion) != 0):
        d = np.asarray(cap.distortion, dtype=np.float64)
        if cap.cfa is None:
            cap.frames = undistort_frames(cap.frames, cap.K, d)
            cap.events, dropped = undistort_events(cap.events, cap.K, d)
        else:
            cap.frames, cap.events, dropped = _undistort_cfa(cap, d)
            cap.meta["undistort_cfa"] = CFA_UNDISTORT_RULE
        cap.meta["undistorted"] = True
        cap.meta["distortion_removed"] = d.tolist()
        cap.meta["events_dropped_undistort"] = dropped
        cap.distortion = None
    return cap.validate(str(path))


CFA_UNDISTORT_RULE = (
    "events move to the nearest pixel of their own filter around their undistorted centre; "
    "raw mosaics are demosaiced, resampled and mosaicked again"
)


def _undistort_cfa(cap: Capture, d: np.ndarray) -> tuple[np.ndarray, EventStream, int]:  # d [5]
    """Undistort a colour-filter capture so that the filter still holds on the ideal grid.

    An event fired on the log of its own pixel's channel, so it moves to the pixel *of that
    channel* nearest to its undistorted pixel centre (within the 3 x 3 pixels around the one
    containing it; at most sqrt(2) px from it, sqrt(5) at the sensor's border, against 0.71 px
    for the plain rule) and keeps meaning what it meant. Demosaiced RGB frames are resampled as any
    frames; raw mosaics are demosaiced (``edi.cfa.demosaic``), resampled and mosaicked again, so
    each pixel holds its own channel. Returns (frames, events, number of events dropped)."""
    from edi.cfa import channel_map, demosaic, mosaic

    from .undistort import undistort_normalized

    assert cap.cfa is not None
    K = cap.K
    if cap.raw_mosaic:
        rgb = demosaic(cap.frames[..., 0], cap.cfa).astype(np.float32)
        frames = mosaic(undistort_frames(rgb, K, d), cap.cfa)[..., None].astype(np.float32)
    else:
        frames = undistort_frames(cap.frames, K, d)
    ev = cap.events
    w, h = ev.width, ev.height
    chan = channel_map(cap.cfa, h, w)
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    xy = undistort_normalized(np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], -1), d)
    pu, pv = xy[..., 0] * K[0, 0] + K[0, 2], xy[..., 1] * K[1, 1] + K[1, 2]  # [H, W] ideal pixel coordinates
    tx, ty, keep_px = (a.reshape(h, w) for a in snap_to_channel(pu.ravel(), pv.ravel(), chan.ravel(), chan))
    keep = keep_px[ev.y, ev.x]
    out = EventStream(ev.t[keep], tx[ev.y, ev.x][keep], ty[ev.y, ev.x][keep], ev.p[keep], w, h)
    object.__setattr__(out, "t0", ev.t0)
    return frames, out, int((~keep).sum())


def _state_cfa(cap: Capture, cfa: str, source: str) -> None:
    """``cap.cfa`` as stated by hand (``load(cfa=...)``): a pattern, or "none"; see ``load``."""
    if isinstance(cfa, str) and cfa.lower() == "none":
        if cap.cfa is not None:
            cap.meta["cfa_dropped"] = cap.cfa
        cap.cfa = None
        cap.meta["cfa_source"] = "stated: none (events taken as luminance)"
        return
    try:
        pattern = check_pattern(cfa, "cfa")
    except EbadError as exc:
        raise CaptureError(source, "cfa", str(exc).split(": ", 1)[-1]) from None
    if cap.cfa is not None and cap.cfa != pattern:
        raise CaptureError(
            source,
            "cfa",
            f"stated {pattern} but the capture records {cap.cfa} ({cap.meta.get('cfa_source', 'its own field')}); "
            "leave it out to use the recorded one, or pass 'none' to take the events as luminance",
        )
    if cap.cfa is None:
        cap.meta["cfa_source"] = "stated by hand"
    cap.cfa = pattern


# --------------------------------------------------------------------------- ECD


def _loadtxt(path: Path, ncols: int, field: str, usecols: Sequence[int] | None = None) -> np.ndarray:
    if not path.is_file():
        raise CaptureError(str(path), field, "file not found")
    try:
        a = np.loadtxt(path, dtype=np.float64, comments="#", ndmin=2, usecols=usecols)
    except (ValueError, OSError, IndexError) as exc:
        raise CaptureError(str(path), field, f"unreadable ({type(exc).__name__}: {exc})") from None
    if a.shape[0] == 0 or a.shape[1] < ncols:
        raise CaptureError(str(path), field, f"expected rows of {ncols} numbers, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise CaptureError(str(path), field, "has a non-finite value")
    return a


def _read_images_txt(itxt: Path) -> list[tuple[float, str]]:
    """The (t seconds, image path) rows of an ECD ``images.txt`` (``#`` comments and blank lines skipped)."""
    if not itxt.is_file():
        raise CaptureError(str(itxt), "images", "file not found")
    lines = []
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
    return lines


def load_ecd(root: str | os.PathLike) -> Capture:
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
    itxt = root / "images.txt"
    lines = _read_images_txt(itxt)
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
        c2w, keep = interpolate_poses(times, gt[:, 0], gt[:, 1:4], gt[:, 4:8], clamp_s=ECD_CLAMP_S)
        c2w = c2w[keep]
        meta["dropped_frames"] = [lines[i][1] for i in np.flatnonzero(~keep)]
        meta["pose_source"] = "groundtruth.txt (interpolated to frame times)"
    frames = []
    for j in np.flatnonzero(keep):
        frames.append(read_image(root / lines[j][1], f"images.txt line {j + 1}"))
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise CaptureError(str(itxt), "images", f"frames differ in size/channels: {sorted(shapes)}")
    h, w, _ = frames[0].shape
    ev_path = root / "events.txt"
    if ev_path.is_file():
        events = _read_events(ev_path, "s", w, h)
        if len(events):
            meta["events_span_s"] = [float(events.t[0]) * 1e-6, float(events.t[-1]) * 1e-6]
    else:
        events = EventStream.empty(w, h)
    kt = times[keep]
    names = [Path(lines[i][1]).stem for i in np.flatnonzero(keep)]
    return Capture(
        frames=np.stack(frames),
        exposures=np.stack([kt, kt], 1),
        events=events,
        K=K,
        distortion=dist if np.any(dist != 0) else None,
        c2w=c2w,
        split=["train"] * len(frames),
        names=names,
        meta=meta,
    )


# --------------------------------------------------------------------------- AEDAT4 / EvDeblurNeRF

# What a truncated or corrupt recording makes the decoders raise: the aedat decoder reports a
# short file as RuntimeError("failed to fill whole buffer"); numpy, zipfile and h5py as below.
CORRUPT_RECORDING_ERRORS = (RuntimeError, OSError, EOFError, ValueError, zipfile.BadZipFile)


def _read_events(path: Path, t_unit: str | None, width: int, height: int) -> EventStream:
    return decode_events(path, t_unit, width, height, "events")


def load_aedat4(path: str | os.PathLike, K: np.ndarray | None = None) -> Capture:  # K [3, 3]
    """An AEDAT4 recording: APS frames with exposure begin/end and events, no poses. AEDAT4
    holds no calibration: pass ``K``, or a guess from a 70-degree horizontal field of view is
    used and ``meta['K_guessed'] = True``. A colour DAVIS recorded by DV states its Bayer
    filter in the header (``edi.io.DV_COLOR_FILTER``): it becomes ``Capture.cfa``, and the
    frames are DV's demosaiced RGB or, in DV's "Original" frame mode, 1-channel raw mosaics.
    Needs the ``aedat`` package (the ``aedat`` extra): without it a CaptureError says how to
    install it."""
    path = Path(path)
    try:
        rec = read_aedat4(path)
    except ImportError:
        raise CaptureError(str(path), None, f"reading .aedat4 needs the 'aedat' package: {AEDAT_INSTALL}") from None
    except CorruptFileError as exc:
        raise CaptureError(
            str(path), None, f"unreadable AEDAT4 recording: {str(exc).replace(f'{path}: ', '')}"
        ) from None
    except EbadError as exc:
        raise CaptureError(str(path), getattr(exc, "field", None), str(exc)) from None
    except CORRUPT_RECORDING_ERRORS as exc:
        raise CaptureError(str(path), None, f"unreadable AEDAT4 recording ({type(exc).__name__}: {exc})") from None
    frames = np.asarray(rec.frames, dtype=np.float32)
    if frames.ndim != 4 or len(frames) == 0:
        raise CaptureError(str(path), "frames", f"the recording has no APS frames (got shape {frames.shape})")
    f, h, w, _ = frames.shape
    meta: dict = {"source_layout": "aedat4", "source": str(path), "t0_us": int(getattr(rec, "t0", 0))}
    cfa = getattr(rec, "cfa", None)
    if cfa is not None:
        meta["cfa_source"] = "AEDAT4 header: events stream info colorFilter (DV)"
    if K is None:
        K = guess_K(w, h)
        meta["K_guessed"] = True
    return Capture(
        frames=frames,
        exposures=np.asarray(rec.exposures, dtype=np.float64),
        events=rec.events,
        K=np.asarray(K, dtype=np.float64),
        split=["train"] * f,
        names=[frame_name(i) for i in range(f)],
        meta=meta,
        cfa=cfa,
    )


def load_evdeblurnerf(root: str | os.PathLike) -> Capture:
    """An EvDeblurNeRF-style folder: ``events.h5`` (or .npz/.txt), LLFF ``poses_bounds.npy``
    (see scenes.poses) and ``images_1/`` frames with ``images_1/timestamps.npz`` holding start
    and end times (seconds). With ``ev_map.npz`` it is the CDAVIS layout (a colour DAVIS346):
    ``cfa`` is RGGB and the rectified events are placed on their filter (``scenes.cdavis``), and
    its sharp images (start == end, Ev-DeblurNeRF's held-out views) become test views."""
    root = Path(root)
    pb_path = root / "poses_bounds.npy"
    c2w_llff, hwf, bounds = read_poses_bounds(pb_path)
    img_dir = root / "images_1"
    files = (
        sorted(p for p in img_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
        if img_dir.is_dir()
        else []
    )
    if len(files) != len(c2w_llff):
        raise CaptureError(str(img_dir), "images", f"{len(files)} images for {len(c2w_llff)} poses")
    ts_path = img_dir / "timestamps.npz"
    try:
        with np.load(ts_path, allow_pickle=False) as z:
            keys = z.files
            start = next((z[k] for k in ("start", "t_start", "timestamps_start") if k in keys), None)
            end = next((z[k] for k in ("end", "t_end", "timestamps_end") if k in keys), None)
    except CORRUPT_RECORDING_ERRORS as exc:
        raise CaptureError(str(ts_path), "timestamps", f"unreadable ({type(exc).__name__}: {exc})") from None
    if start is None:
        raise CaptureError(str(ts_path), "start", "missing")
    if end is None:
        raise CaptureError(str(ts_path), "end", "missing")
    frames = np.stack([read_image(p, f"images_1/{p.name}") for p in files])
    f, h, w, _ = frames.shape
    K = np.array([[hwf[0, 2] * w / hwf[0, 1], 0, w / 2], [0, hwf[0, 2] * h / hwf[0, 0], h / 2], [0, 0, 1.0]])
    c2w = np.stack([nearest_rigid(c2w_llff[i], str(pb_path), f"poses_bounds[{i}]") for i in range(f)])
    ev_file = next(root / n for n in ("events.h5", "events.npz", "events.txt") if (root / n).is_file())
    cdavis = (root / EV_MAP).is_file() and ev_file.suffix != ".txt"
    if cdavis:  # Ev-DeblurNeRF's colour DAVIS: rectified events, each on its filter (scenes.cdavis)
        events, cdavis_meta = read_cdavis_events(ev_file, root / EV_MAP, w, h)
    else:
        events = _read_events(ev_file, None, w, h)
    exps = np.stack([np.asarray(start, np.float64).reshape(-1), np.asarray(end, np.float64).reshape(-1)], 1)
    if exps.shape != (f, 2) or not np.isfinite(exps).all():
        raise CaptureError(str(ts_path), "start", f"need {f} finite start and end times, got shape {exps.shape}")
    meta = {"source_layout": "evdeblurnerf", "source": str(root), "bounds": bounds.tolist()}
    if cdavis:
        meta.update(cdavis_meta)
    if exps.max() > 1e3:  # not seconds of a short capture: microseconds on the events' raw clock
        exps = (exps - events.t0) * 1e-6
        meta["timestamps_unit"] = "us (converted to seconds on the events' clock)"
    cap = Capture(
        frames=frames,
        exposures=exps,
        events=events,
        K=K,
        c2w=c2w,
        split=["train"] * f,
        names=[p.stem for p in files],
        meta=meta,
        cfa=CDAVIS_CFA if cdavis else None,
    )
    sharp = [cap.names[i] for i in np.flatnonzero(exps[:, 0] == exps[:, 1])]
    if cdavis and 0 < len(sharp) < f:
        # CDAVIS interleaves the sharp ground-truth views (t_start == t_end) with the blurry
        # frames and holds them out (llffhold_end): they are test views, never training frames
        from .holdout import hold_out

        cap = hold_out(cap, test_frames=sharp)
        cap.meta["test_rule"] = "CDAVIS: the sharp images (timestamps_start == timestamps_end) are the test views"
    return cap
