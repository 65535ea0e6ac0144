"""Camera initialisation with pycolmap: SfM on (EDI-deblurred) frames with known intrinsics.

Convention: COLMAP's camera axes and pixel convention (top-left pixel centre at (0.5, 0.5))
are ours, so K goes in unchanged and ``cam_from_world`` inverts to our OpenCV c2w. The
reconstruction's gauge (origin, orientation, scale) is COLMAP's: align to another frame with
a similarity transform (``align_similarity``) before comparing positions.
"""
from __future__ import annotations

import math
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from edi.errors import EbadError

from .capture import Capture

__all__ = ["ColmapConfig", "PoseEstimate", "SfMError", "estimate_poses", "align_similarity", "pose_errors"]


class SfMError(EbadError, ValueError):
    """Structure from motion failed (too few frames registered); the message says how many."""


@dataclass
class ColmapConfig:
    """Settings of ``estimate_poses``."""

    deblur: bool = True  # EDI-deblur blurry frames with their events before feature extraction
    matcher: Literal["auto", "sequential", "exhaustive"] = "auto"  # auto: exhaustive up to 40 frames
    overlap: int = 10  # sequential matcher: neighbours matched per frame
    max_num_features: int = 4096  # SIFT features per frame
    min_registered_fraction: float = 0.5  # fewer registered frames than this raise SfMError
    min_registered: int = 3  # and never fewer than this many
    init_min_num_inliers: int = 50  # initial pair (COLMAP's default 100 is too strict for tiny frames)
    abs_pose_min_num_inliers: int = 15  # registering a new frame (COLMAP default 30)
    min_num_matches: int = 15  # verified matches for a pair to count
    num_threads: int = 2
    seed: int = 0
    upsample_below: int = 200  # frames narrower than this are upsampled x2 (SIFT needs pixels)
    verbose: bool = False  # COLMAP's INFO log lines on stderr


@dataclass
class PoseEstimate:
    """What SfM recovered, in the capture's convention (OpenCV c2w) and COLMAP's gauge."""

    c2w: np.ndarray  # [F, 4, 4]; unregistered frames interpolated in time from registered ones
    points: np.ndarray  # [P, 3] sparse points (world)
    colors: np.ndarray  # [P, D] linear [0, 1] (D as the capture; 3 for colour)
    registered: np.ndarray  # [F] bool
    report: dict = field(default_factory=dict)

    @property
    def unregistered(self) -> list[int]:
        return np.flatnonzero(~self.registered).tolist()


def _sfm_frames(capture: Capture, deblur: bool, report: dict) -> np.ndarray:
    """[F, H, W, D] frames for SfM: EDI latents at mid-exposure where possible, else raw."""
    frames = capture.frames.astype(np.float64)
    report["deblurred"] = 0
    if not deblur:
        report["deblur_note"] = "deblurring disabled"
        return frames
    try:
        from edi import deblur as edi_deblur
    except ImportError:
        report["deblur_note"] = "edi.deblur not available: raw frames used"
        return frames
    c = capture.meta.get("c")
    if c is None and capture.num_frames >= 2 and len(capture.events):
        # one c for the whole capture from the consistency between frames: cheaper and far
        # more reliable than a single-frame estimate per frame
        from edi import estimate_c

        try:
            c = float(estimate_c(capture.frames, capture.exposures, capture.events))
            report["c_estimated"] = c
        except ValueError as exc:  # no pixel fired between frames: fall back to per frame
            report["c_note"] = f"joint estimate failed ({exc}); per-frame estimates"
    out = frames.copy()
    for i in range(capture.num_frames):
        t0, t1 = capture.exposures[i]
        if t1 <= t0 or len(capture.events.slice_time(t0, t1)) == 0:
            continue
        out[i] = np.asarray(edi_deblur(capture.frames[i], (t0, t1), capture.events, None, c), dtype=np.float64)
        report["deblurred"] += 1
    report["deblur_note"] = f"EDI at mid-exposure, c = {c if c is not None else 'estimated per frame'}"
    return out


def _write_png(path: Path, img: np.ndarray, scale: int) -> None:
    from PIL import Image

    a = np.clip(img, 0, 1) ** (1 / 2.2)  # display gamma: SIFT sees dark regions better
    a = np.round(a * 255).astype(np.uint8)
    im = Image.fromarray(a[..., 0] if a.shape[2] == 1 else a)
    if scale != 1:
        im = im.resize((im.width * scale, im.height * scale), Image.BICUBIC)
    im.save(path)


def _interp_missing(c2w: np.ndarray, registered: np.ndarray, t: np.ndarray) -> np.ndarray:
    idx = np.flatnonzero(registered)
    if len(idx) == len(registered):
        return c2w
    out = c2w.copy()
    rots = Rotation.from_matrix(c2w[idx, :3, :3])
    tq = np.clip(t, t[idx].min(), t[idx].max())
    tk, uniq = np.unique(t[idx], return_index=True)
    if len(tk) >= 2:
        sl = Slerp(tk, rots[uniq])
        miss = ~registered
        out[miss, :3, :3] = sl(tq[miss]).as_matrix()
        for k in range(3):
            out[miss, k, 3] = np.interp(tq[miss], tk, c2w[idx[uniq], k, 3])
    else:
        out[~registered] = c2w[idx[0]]
    return out


def estimate_poses(capture: Capture, config: ColmapConfig | None = None, frames: list[int] | None = None,
                   workdir: str | None = None) -> PoseEstimate:
    """SfM with pycolmap on the CPU: EDI-deblur, SIFT, matching, incremental mapping with K fixed.

    Args:
        capture: the capture (its K is used and kept fixed; its poses are ignored).
        config: ColmapConfig (defaults when None).
        frames: indices of the frames to use (default all); the result covers these only.
        workdir: keep COLMAP's database and images there (default a temporary folder, removed).

    Returns:
        PoseEstimate with c2w [F, 4, 4] (F = number of frames used), points [P, 3], colours
        [P, D], registered [F] bool and a report (timings, counts, reprojection error).

    Raises:
        SfMError: fewer than max(min_registered, min_registered_fraction * F) frames registered.
        ValueError: bad arguments (names them).
    """
    import pycolmap

    cfg = config or ColmapConfig()
    capture.validate("capture")
    if capture.distortion is not None and np.any(np.asarray(capture.distortion) != 0):
        raise ValueError("capture: has lens distortion; load it with undistort=True first")
    idx = np.arange(capture.num_frames) if frames is None else np.asarray(frames, dtype=int)
    if idx.ndim != 1 or len(idx) < 2 or idx.min() < 0 or idx.max() >= capture.num_frames:
        raise ValueError(f"frames: need >= 2 indices in [0, {capture.num_frames}), got {frames!r}")
    if cfg.matcher not in ("auto", "sequential", "exhaustive"):
        raise ValueError(f"config.matcher: must be auto, sequential or exhaustive, got {cfg.matcher!r}")
    report: dict = {"frames_used": len(idx)}
    t_start = time.perf_counter()
    imgs = _sfm_frames(capture, cfg.deblur, report)[idx]
    scale = 2 if capture.width < cfg.upsample_below else 1
    K = np.asarray(capture.K, dtype=np.float64)
    root = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="ebad-colmap-"))
    old_level = pycolmap.logging.minloglevel
    if not cfg.verbose:
        pycolmap.logging.minloglevel = 1  # warnings and errors only
    try:
        img_dir = root / "images"
        img_dir.mkdir(parents=True, exist_ok=True)
        names = [f"{i:05d}.png" for i in range(len(idx))]
        for name, im in zip(names, imgs):
            _write_png(img_dir / name, im, scale)
        db = root / "database.db"
        if db.exists():
            db.unlink()
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(f"{v:.10g}" for v in (K[0, 0] * scale, K[1, 1] * scale, K[0, 2] * scale,
                                                               K[1, 2] * scale))
        if hasattr(pycolmap, "set_random_seed"):  # RANSAC in matching and mapping; bit-exact only with 1 thread
            pycolmap.set_random_seed(cfg.seed)
        ext = pycolmap.FeatureExtractionOptions()
        ext.num_threads = cfg.num_threads
        ext.use_gpu = False
        ext.sift.max_num_features = cfg.max_num_features
        pycolmap.extract_features(db, img_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
        t_feat = time.perf_counter()
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = cfg.num_threads
        mopt.use_gpu = False
        matcher = cfg.matcher if cfg.matcher != "auto" else ("exhaustive" if len(idx) <= 40 else "sequential")
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
        else:
            pair = pycolmap.SequentialPairingOptions()
            pair.overlap = cfg.overlap
            pair.num_threads = cfg.num_threads
            pycolmap.match_sequential(db, matching_options=mopt, pairing_options=pair, device=pycolmap.Device.cpu)
        t_match = time.perf_counter()
        opt = pycolmap.IncrementalPipelineOptions()
        opt.num_threads = cfg.num_threads
        opt.random_seed = cfg.seed
        opt.min_num_matches = cfg.min_num_matches
        opt.min_model_size = min(cfg.min_registered, len(idx))
        opt.ba_refine_focal_length = False
        opt.ba_refine_principal_point = False
        opt.ba_refine_extra_params = False
        opt.mapper.init_min_num_inliers = cfg.init_min_num_inliers
        opt.mapper.abs_pose_min_num_inliers = cfg.abs_pose_min_num_inliers
        opt.mapper.abs_pose_refine_focal_length = False
        opt.mapper.abs_pose_refine_extra_params = False
        opt.mapper.random_seed = cfg.seed
        out_dir = root / "sparse"
        out_dir.mkdir(exist_ok=True)
        recs = pycolmap.incremental_mapping(db, img_dir, out_dir, options=opt)
        t_map = time.perf_counter()
    finally:
        pycolmap.logging.minloglevel = old_level
        if not workdir:
            shutil.rmtree(root, ignore_errors=True)
    need = max(min(cfg.min_registered, len(idx)), int(math.ceil(cfg.min_registered_fraction * len(idx))))
    if not recs:
        raise SfMError(f"SfM registered no frames (0 of {len(idx)}; need {need}): too little texture or overlap")
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    n_reg = rec.num_reg_images()
    if n_reg < need:
        raise SfMError(f"SfM registered only {n_reg} of {len(idx)} frames (need {need})")
    c2w = np.tile(np.eye(4), (len(idx), 1, 1))
    registered = np.zeros(len(idx), bool)
    name_to_i = {n: i for i, n in enumerate(names)}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        i = name_to_i[image.name]
        m = np.eye(4)
        m[:3, :4] = image.cam_from_world().matrix()
        c2w[i] = np.linalg.inv(m)
        registered[i] = True
    t_mid = capture.exposures[idx].mean(axis=1)
    c2w = _interp_missing(c2w, registered, t_mid)
    pts = [(p.xyz, p.color) for p in rec.points3D.values()]
    points = np.array([p[0] for p in pts], np.float64).reshape(-1, 3)
    colors = (np.array([p[1] for p in pts], np.float64).reshape(-1, 3) / 255.0) ** 2.2  # undo display gamma
    if capture.channels == 1:
        colors = colors.mean(axis=1, keepdims=True)
    ok = np.isfinite(points).all(1)
    points, colors = points[ok], np.clip(colors[ok], 0, 1)
    report.update({"registered": int(n_reg), "unregistered": np.flatnonzero(~registered).tolist(),
                   "points": len(points), "models": len(recs), "matcher": matcher, "upsampled": scale,
                   "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()) / scale,
                   "time_features_s": t_feat - t_start, "time_matching_s": t_match - t_feat,
                   "time_mapping_s": t_map - t_match, "time_total_s": time.perf_counter() - t_start})
    return PoseEstimate(c2w=c2w, points=points, colors=colors.astype(np.float32), registered=registered, report=report)


def align_similarity(src: np.ndarray,  # [N, 3]
                     dst: np.ndarray  # [N, 3]
                     ) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama: (s, R [3, 3], t [3]) minimising |dst - (s R src + t)|^2."""
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"src, dst: need matching [N >= 3, 3] arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sgn = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2, 2] = -1
    r = u @ sgn @ vt
    var = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(d) @ sgn) / var) if var > 0 else 1.0
    t = mu_d - s * r @ mu_s
    return s, r, t


def pose_errors(est_c2w: np.ndarray,  # [N, 4, 4]
                gt_c2w: np.ndarray  # [N, 4, 4]
                ) -> dict:
    """Pose errors after a similarity alignment of ``est`` onto ``gt``: ATE (RMSE and max of
    camera-centre distances, gt units) and rotation errors (degrees).

    The alignment's rotation comes from the orientations (chordal mean of R_gt R_est^T), its
    scale and translation from the centres by least squares: unlike Umeyama on centres alone,
    this stays well defined on a straight trajectory (a slider), where rotation about the line
    is not observable from positions."""
    if est_c2w.shape != gt_c2w.shape or est_c2w.ndim != 3 or est_c2w.shape[1:] != (4, 4) or len(est_c2w) < 2:
        raise ValueError(f"est_c2w, gt_c2w: need matching [N >= 2, 4, 4], got {est_c2w.shape} and {gt_c2w.shape}")
    m = np.einsum("nij,nkj->ik", gt_c2w[:, :3, :3], est_c2w[:, :3, :3])
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    ps, pd = est_c2w[:, :3, 3], gt_c2w[:, :3, 3]
    xs, xd = ps - ps.mean(0), pd - pd.mean(0)
    rx = xs @ r.T
    s = float((rx * xd).sum() / max((xs**2).sum(), 1e-300))
    t = pd.mean(0) - s * r @ ps.mean(0)
    pos = s * ps @ r.T + t
    err = np.linalg.norm(pos - pd, axis=1)
    rel = np.einsum("nji,jk,nkl->nil", gt_c2w[:, :3, :3], r, est_c2w[:, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    extent = float(np.linalg.norm(pd.max(0) - pd.min(0)))
    return {"ate_rmse": float(np.sqrt((err**2).mean())), "ate_max": float(err.max()),
            "rot_mean_deg": float(ang.mean()), "rot_max_deg": float(ang.max()), "scale": s,
            "trajectory_extent": extent, "n": int(len(err))}
