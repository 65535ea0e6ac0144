"""Camera initialisation with pycolmap: SfM on (EDI-deblurred) frames with known intrinsics.

Convention: COLMAP's camera axes and pixel convention (top-left pixel centre at (0.5, 0.5))
are ours, so K goes in unchanged and ``cam_from_world`` inverts to our OpenCV c2w. The
reconstruction's gauge (origin, orientation, scale) is COLMAP's: align to another frame with
a similarity transform (``align_similarity``, then ``apply_similarity``) before comparing
positions.

Test views that carry an image but no pose are registered by the same SfM as the training
frames (their images are matched and mapped with them, never deblurred, never counted in the
registration threshold): ``PoseEstimate.test_c2w`` holds their poses in the SfM frame, by name.

No truth is read: the contrast threshold for EDI is estimated from the capture
(``edi.estimate_c``), never taken from ``Capture.meta``.
"""

from __future__ import annotations

import logging
import math
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from edi import deblur as edi_deblur
from edi import estimate_c
from edi.errors import EbadError

from .capture import Capture, TestView
from .errors import CaptureError
from .poses import interpolate_poses

__all__ = [
    "choose_matcher",
    "ColmapConfig",
    "PoseEstimate",
    "SfMError",
    "estimate_poses",
    "align_similarity",
    "apply_similarity",
    "rotation_errors_deg",
    "pose_errors",
]

log = logging.getLogger(__name__)

AXIS_LENGTH = 1.0  # align_similarity: camera axis tips at this x the RMS spread of the centres


class SfMError(EbadError, ValueError):
    """Structure from motion failed (too few frames registered); the message says how many
    and what to try."""


@dataclass
class ColmapConfig:
    """Settings of ``estimate_poses``."""

    deblur: bool = True  # EDI-deblur blurry frames with their events before feature extraction
    # auto: exhaustive up to ``exhaustive_max`` images (frames and test views), else sequential in time (the frames
    # are named in the order of their exposures, so a video-like capture pairs neighbours in time)
    matcher: Literal["auto", "sequential", "exhaustive"] = "auto"
    exhaustive_max: int = 40  # 780 pairs at 40 images (sequential, overlap 10: 345); 20 made slider_depth's error 0.53%
    overlap: int = 10  # sequential matcher: neighbours matched per frame
    max_num_features: int = 4096  # SIFT features per frame
    min_registered_fraction: float = 0.5  # fewer registered frames than this raise SfMError
    min_registered: int = 3  # and never fewer than this many
    init_min_num_inliers: int = 50  # initial pair (COLMAP's default 100 is too strict for tiny frames)
    abs_pose_min_num_inliers: int = 15  # registering a new frame (COLMAP default 30)
    min_num_matches: int = 15  # verified matches for a pair to count
    # threads of feature extraction, matching and mapping: with more than one, each of the three differs from run
    # to run (the same tiny capture SfM'd 5 times with 2 threads: 54 to 207 points, other poses each time; with 2
    # for extraction and 1 for the rest, still other poses each time), so one: the same capture, the same poses
    num_threads: int = 1
    seed: int = 0
    upsample_below: int = 200  # frames narrower than this are upsampled x2 (SIFT needs pixels)
    verbose: bool = False  # COLMAP's log lines (INFO and up) on stderr; off: none (a failure raises SfMError)
    # test views with an image registered with the frames: "unposed" (those without c2w),
    # "all" (every test view with an image, e.g. to align a capture's given test poses), "none"
    test_views: Literal["unposed", "all", "none"] = "unposed"
    # EDI with the estimated (c_pos, c_neg) pair instead of their mean. Measured (issue 30): the pair's
    # mid-exposure latents are 0.15-0.19 dB closer to the sharp truth (boxes small, realistic, seeds 0-2:
    # 26.55, 26.42, 27.03 against 26.40, 26.25, 26.84 dB) but the poses are no better (benchmarks/
    # colmap_poses.py, small, boxes + spheres x 3 seeds: ATE 0.41 +- 0.07 % against 0.41 +- 0.12 %, rotation
    # 0.35 against 0.32 deg) and the 33-frame tiny capture of tests/scenes/test_colmap_scale.py breaks with
    # it (ATE 26.6 % against 1.44 %); slider_depth's frames are sharp (nothing deblurred): the mean stays
    c_polarity: bool = False


@dataclass
class PoseEstimate:
    """What SfM recovered, in the capture's convention (OpenCV c2w) and COLMAP's gauge."""

    c2w: np.ndarray  # [F, 4, 4]; unregistered frames interpolated in time from registered ones
    points: np.ndarray  # [P, 3] sparse points (world)
    colors: np.ndarray  # [P, D] linear [0, 1] (D as the capture; 3 for colour, a raw mosaic's too)
    registered: np.ndarray  # [F] bool, always present: which rows of c2w SfM registered
    report: dict = field(default_factory=dict)
    test_c2w: dict[str, np.ndarray] = field(default_factory=dict)  # test view name -> [4, 4], registered ones
    test_unregistered: list[str] = field(default_factory=list)  # test views given to SfM and not registered

    @property
    def unregistered(self) -> list[int]:
        return np.flatnonzero(~self.registered).tolist()


def _c_text(c: float | tuple[float, float] | None) -> str:
    """An estimated c (one value or (c_pos, c_neg)) for a message."""
    if c is None:
        return "estimated per frame"
    if isinstance(c, tuple):
        return f"(c_pos {c[0]:.4g}, c_neg {c[1]:.4g})"
    return f"{c:.4g}"


def _sfm_frames(capture: Capture, deblur: bool, report: dict, polarity: bool = False) -> np.ndarray:
    """[F, H, W, D] frames for SfM: EDI latents at mid-exposure where possible, else raw. The
    contrast threshold is estimated from the capture (one c, or (c_pos, c_neg) with ``polarity``).
    A colour DAVIS capture (``capture.cfa``) is deblurred as the filter says (each pixel's events
    on its own channel), and its raw mosaics are demosaiced for SIFT (3 channels out)."""
    frames = capture.frames.astype(np.float64)
    report["deblurred"] = 0
    if not deblur:
        report["deblur_note"] = "deblurring disabled"
        return _for_features(frames, capture.cfa)
    c: float | tuple[float, float] | None = None
    if capture.num_frames >= 2 and len(capture.events):
        # one c for the whole capture from the consistency between frames: cheaper and far
        # more reliable than a single-frame estimate per frame
        try:
            est = estimate_c(capture.frames, capture.exposures, capture.events, pair=polarity, cfa=capture.cfa)
            c = (float(est.pos), float(est.neg)) if polarity else float(est.mean)
            report["c_estimated"] = c
        except ValueError as exc:  # no pixel fired between frames: fall back to per frame
            report["c_note"] = f"joint estimate failed ({exc}); per-frame estimates"
    out = frames.copy()
    for i in range(capture.num_frames):
        t0, t1 = capture.exposures[i]
        if t1 <= t0 or len(capture.events.slice_time(t0, t1)) == 0:
            continue
        lat = edi_deblur(capture.frames[i], (t0, t1), capture.events, None, c, cfa=capture.cfa)
        out[i] = np.asarray(lat, dtype=np.float64)
        report["deblurred"] += 1
    report["deblur_note"] = f"EDI at mid-exposure, c = {_c_text(c)}"
    return _for_features(out, capture.cfa)


def _for_features(frames: np.ndarray, cfa: str | None) -> np.ndarray:  # [F, H, W, D] -> [F, H, W, D or 3]
    """Raw Bayer mosaics (one channel with a ``cfa``) demosaiced bilinearly: the filter's pattern would
    be texture to SIFT. Other frames as they are."""
    if cfa is None or frames.shape[-1] != 1:
        return frames
    from edi.cfa import demosaic

    return np.asarray(demosaic(frames[..., 0], cfa), dtype=np.float64)


def _write_png(path: Path, img: np.ndarray, scale: int) -> None:
    from PIL import Image

    a = np.clip(img, 0, 1) ** (1 / 2.2)  # display gamma: SIFT sees dark regions better
    a = np.round(a * 255).astype(np.uint8)
    im = Image.fromarray(a[..., 0] if a.shape[2] == 1 else a)
    if scale != 1:
        im = im.resize((im.width * scale, im.height * scale), Image.Resampling.BICUBIC)
    im.save(path)


def _interp_missing(c2w: np.ndarray, registered: np.ndarray, t: np.ndarray) -> np.ndarray:
    idx = np.flatnonzero(registered)
    if len(idx) == len(registered):
        return c2w
    out = c2w.copy()
    tk, uniq = np.unique(t[idx], return_index=True)
    if len(tk) >= 2:
        known = c2w[idx[uniq]]
        miss = ~registered
        out[miss], _ = interpolate_poses(
            t[miss], tk, known[:, :3, 3], Rotation.from_matrix(known[:, :3, :3]).as_quat(), clamp_s=np.inf
        )  # beyond the ends: the end pose
    else:
        out[~registered] = c2w[idx[0]]
    return out


def choose_matcher(cfg: ColmapConfig, n_images: int) -> Literal["sequential", "exhaustive"]:
    """The matcher ``estimate_poses`` uses: the configured one, or with "auto" exhaustive up to
    ``cfg.exhaustive_max`` images (every pair: n (n - 1) / 2), sequential beyond (each frame with its
    ``cfg.overlap`` neighbours in time; about n x overlap pairs, test views matched against every frame)."""
    if cfg.matcher != "auto":
        return cfg.matcher
    return "exhaustive" if n_images <= cfg.exhaustive_max else "sequential"


def _view_names(capture: Capture, idx: np.ndarray, which: np.ndarray) -> str:
    """The capture's names (or indices) of frames idx[which], for a message."""
    return ", ".join(capture.names[int(i)] if capture.names else f"frame {int(i)}" for i in idx[which])


def _failure_hint(cfg: ColmapConfig, capture: Capture, report: dict) -> str:
    """What to try when too few frames register (the usual cause: too few features in blurry frames)."""
    tips = []
    if not cfg.deblur:
        tips.append("EDI deblurring with an estimated c (ColmapConfig(deblur=True), the default)")
    elif report.get("deblurred", 0) == 0:
        tips.append("EDI deblurring needs events inside the exposures: none of the frames had any")
    else:
        c = report.get("c_estimated")
        tips.append(
            f"a better contrast threshold for EDI (c = {_c_text(c)}; "
            f"`ebad deblur` on one frame shows whether the latents are sharp)"
        )
    tips.append(
        f"more frames with more overlap ({capture.num_frames} in the capture, {report.get('frames_used', '?')} used)"
    )
    tips.append("correct known intrinsics (K is kept fixed; a wrong K breaks registration)")
    if capture.width < 2 * cfg.upsample_below:
        tips.append(
            f"lower matching thresholds (init_min_num_inliers {cfg.init_min_num_inliers}, "
            f"abs_pose_min_num_inliers {cfg.abs_pose_min_num_inliers}) for small frames"
        )
    return "; try: " + "; ".join(tips)


def estimate_poses(
    capture: Capture, config: ColmapConfig | None = None, frames: list[int] | None = None, workdir: str | None = None
) -> PoseEstimate:
    """SfM with pycolmap on the CPU: EDI-deblur, SIFT, matching, incremental mapping with K fixed.

    Test views with an image (those without a pose, or all: ``config.test_views``) are matched
    and mapped together with the frames; their images are used as they are (sharp).

    Args:
        capture: the capture (its K is used and kept fixed; its poses are ignored).
        config: ColmapConfig (defaults when None).
        frames: indices of the frames to use (default all); the result covers these only.
        workdir: keep COLMAP's database and images there (default a temporary folder, removed).

    Returns:
        PoseEstimate with c2w [F, 4, 4] (F = number of frames used), points [P, 3], colours
        [P, D], registered [F] bool, test_c2w {name: [4, 4]} for the registered test views,
        test_unregistered [names], and a report (timings, counts, reprojection error, the
        estimated c).

    Raises:
        SfMError: fewer than max(min_registered, min_registered_fraction * F) frames
            registered; the message says how many and what to try.
        CaptureError: bad arguments (names them).
    """
    import pycolmap

    cfg = config or ColmapConfig()
    idx, tests = _sfm_inputs(capture, cfg, frames)
    report: dict = {"frames_used": len(idx), "test_views_used": len(tests)}
    t_start = time.perf_counter()
    log.info("SfM: EDI-deblurring the frames for features (%d frames, %d test views)", len(idx), len(tests))
    imgs = _sfm_frames(capture, cfg.deblur, report, cfg.c_polarity)[idx]
    log.info(
        "SfM: deblurred %d frames in %.1f s; extracting SIFT features",
        report["deblurred"],
        time.perf_counter() - t_start,
    )
    scale = 2 if capture.width < cfg.upsample_below else 1
    K = np.asarray(capture.K, dtype=np.float64)
    root = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="ebad-colmap-"))
    old_level = pycolmap.logging.minloglevel
    if not cfg.verbose:
        # fatal only: bundle adjustment warns by the hundred on tiny frames, and a failed mapping logs
        # "Failed to create any sparse model" from C++ to fd 2, which SfMError below says with what to try
        pycolmap.logging.minloglevel = int(pycolmap.logging.Level.FATAL)
    try:
        img_dir = root / "images"
        img_dir.mkdir(parents=True, exist_ok=True)
        # named by their rank in time: the sequential matcher pairs neighbours in time, whatever the frames' order
        rank = np.empty(len(idx), int)
        rank[np.argsort(capture.exposures[idx, 0], kind="stable")] = np.arange(len(idx))
        names = [f"{int(r):05d}.png" for r in rank]
        test_names = [f"test_{j:05d}.png" for j in range(len(tests))]
        for name, im in zip(names, imgs):
            _write_png(img_dir / name, im, scale)
        for name, tv in zip(test_names, tests):
            assert tv.image is not None  # _sfm_inputs keeps only the test views with an image
            _write_png(img_dir / name, tv.image, scale)
        db = root / "database.db"
        if db.exists():
            db.unlink()
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(
            f"{v:.10g}" for v in (K[0, 0] * scale, K[1, 1] * scale, K[0, 2] * scale, K[1, 2] * scale)
        )
        if hasattr(pycolmap, "set_random_seed"):  # RANSAC in matching and mapping
            pycolmap.set_random_seed(cfg.seed)
        ext = pycolmap.FeatureExtractionOptions()
        ext.num_threads = cfg.num_threads
        ext.use_gpu = False
        ext.sift.max_num_features = cfg.max_num_features
        pycolmap.extract_features(
            db,
            img_dir,
            image_names=names + test_names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=ext,
            device=pycolmap.Device.cpu,
        )
        t_feat = time.perf_counter()
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = cfg.num_threads
        mopt.use_gpu = False
        n_img = len(names) + len(test_names)
        matcher = choose_matcher(cfg, n_img)
        log.info(
            "SfM: features of %d images in %.1f s; matching them (%s%s)",
            n_img,
            t_feat - t_start,
            matcher,
            f", overlap {cfg.overlap}" if matcher == "sequential" else f", {n_img * (n_img - 1) // 2} pairs",
        )
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
        else:
            # test views sort after the frames ("test_" > digits): sequential matching pairs them
            # with the last frames only, so they also get matched exhaustively against the frames
            pair = pycolmap.SequentialPairingOptions()
            pair.overlap = cfg.overlap
            pair.num_threads = cfg.num_threads
            pycolmap.match_sequential(db, matching_options=mopt, pairing_options=pair, device=pycolmap.Device.cpu)
            if test_names:
                _match_test_views(pycolmap, db, names, test_names, mopt)
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
        log.info("SfM: matched in %.1f s; incremental mapping of %d images", t_match - t_feat, n_img)
        recs = pycolmap.incremental_mapping(db, img_dir, out_dir, options=opt)
        t_map = time.perf_counter()
        log.info("SfM: mapped in %.1f s", t_map - t_match)
    finally:
        pycolmap.logging.minloglevel = old_level
        if not workdir:
            shutil.rmtree(root, ignore_errors=True)
    need = max(min(cfg.min_registered, len(idx)), int(math.ceil(cfg.min_registered_fraction * len(idx))))
    if not recs:
        raise SfMError(
            f"SfM registered no frames (0 of {len(idx)}; need {need}): too few matched features"
            + _failure_hint(cfg, capture, report)
        )
    name_to_i = {n: i for i, n in enumerate(names)}
    rec = max(recs.values(), key=lambda r: sum(1 for im in r.images.values() if im.has_pose and im.name in name_to_i))
    c2w, registered, test_c2w = _registered_poses(rec, name_to_i, dict(zip(test_names, tests)))
    n_reg = int(registered.sum())
    log.info("SfM: registered %d of %d frames and %d of %d test views", n_reg, len(idx), len(test_c2w), len(tests))
    if n_reg < need:
        raise SfMError(
            f"SfM registered only {n_reg} of {len(idx)} frames (need {need}) in its largest model "
            f"({len(recs)} model(s)); not registered: {_view_names(capture, idx, ~registered)}"
            + _failure_hint(cfg, capture, report)
        )
    if n_reg < len(idx):
        log.warning(
            "SfM registered %d of %d frames (%.0f%%); not registered (poses interpolated in time): %s",
            n_reg,
            len(idx),
            100.0 * n_reg / len(idx),
            _view_names(capture, idx, ~registered),
        )
    t_mid = capture.exposures[idx].mean(axis=1)
    c2w = _interp_missing(c2w, registered, t_mid)
    points, colors = _sparse_points(rec, 3 if capture.cfa is not None else capture.channels)
    test_unreg = [tv.name for tv in tests if tv.name not in test_c2w]
    report.update(
        {
            "registered": n_reg,
            "registration_rate": n_reg / len(idx),
            "unregistered": np.flatnonzero(~registered).tolist(),
            "unregistered_names": _view_names(capture, idx, ~registered).split(", ") if n_reg < len(idx) else [],
            "test_registered": len(test_c2w),
            "test_unregistered": test_unreg,
            "points": len(points),
            "models": len(recs),
            "matcher": matcher,
            "upsampled": scale,
            "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()) / scale,
            "time_features_s": t_feat - t_start,
            "time_matching_s": t_match - t_feat,
            "time_mapping_s": t_map - t_match,
            "time_total_s": time.perf_counter() - t_start,
        }
    )
    return PoseEstimate(
        c2w=c2w,
        points=points,
        colors=colors.astype(np.float32),
        registered=registered,
        report=report,
        test_c2w=test_c2w,
        test_unregistered=test_unreg,
    )


def _sfm_inputs(capture: Capture, cfg: ColmapConfig, frames: list[int] | None) -> tuple[np.ndarray, list[TestView]]:
    """The capture and config checked (CaptureError naming the argument): the indices [F] of the frames
    to use and the test views whose images go to SfM."""
    capture.validate("capture")
    if capture.distortion is not None and np.any(np.asarray(capture.distortion) != 0):
        raise CaptureError(None, "capture", "has lens distortion; load it with undistort=True first")
    idx = np.arange(capture.num_frames) if frames is None else np.asarray(frames, dtype=int)
    if idx.ndim != 1 or len(idx) < 2 or idx.min() < 0 or idx.max() >= capture.num_frames:
        raise CaptureError(None, "frames", f"need >= 2 indices in [0, {capture.num_frames}), got {frames!r}")
    if cfg.matcher not in ("auto", "sequential", "exhaustive"):
        raise CaptureError(None, "config.matcher", f"must be auto, sequential or exhaustive, got {cfg.matcher!r}")
    if cfg.test_views not in ("unposed", "all", "none"):
        raise CaptureError(None, "config.test_views", f"must be unposed, all or none, got {cfg.test_views!r}")
    tests = [
        tv
        for tv in capture.test_views
        if tv.image is not None and (cfg.test_views == "all" or (cfg.test_views == "unposed" and tv.c2w is None))
    ]
    return idx, tests


def _registered_poses(
    rec: Any, name_to_i: dict[str, int], name_to_test: dict[str, TestView]
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """From a pycolmap Reconstruction: c2w [F, 4, 4] of the frames (identity where not registered),
    registered [F] bool, and the c2w [4, 4] of each registered test view by its name."""
    c2w = np.tile(np.eye(4), (len(name_to_i), 1, 1))
    registered = np.zeros(len(name_to_i), bool)
    test_c2w: dict[str, np.ndarray] = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        m = np.eye(4)
        m[:3, :4] = image.cam_from_world().matrix()
        if image.name in name_to_i:
            c2w[name_to_i[image.name]] = np.linalg.inv(m)
            registered[name_to_i[image.name]] = True
        elif image.name in name_to_test:
            test_c2w[name_to_test[image.name].name] = np.linalg.inv(m)
    return c2w, registered, test_c2w


def _sparse_points(rec: Any, channels: int) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction's finite points [P, 3] and their colours [P, D] (display gamma undone, in [0, 1])."""
    pts = [(p.xyz, p.color) for p in rec.points3D.values()]
    points = np.array([p[0] for p in pts], np.float64).reshape(-1, 3)
    colors = (np.array([p[1] for p in pts], np.float64).reshape(-1, 3) / 255.0) ** 2.2  # undo display gamma
    if channels == 1:
        colors = colors.mean(axis=1, keepdims=True)
    ok = np.isfinite(points).all(1)
    return points[ok], np.clip(colors[ok], 0, 1)


def _match_test_views(pycolmap: Any, db: Path, names: list[str], test_names: list[str], mopt: Any) -> None:
    """Match every test image against every frame (after sequential matching of the frames)."""
    pairs = db.parent / "test_pairs.txt"
    pairs.write_text("".join(f"{t} {n}\n" for t in test_names for n in names))
    popt = pycolmap.ImportedPairingOptions()
    popt.match_list_path = str(pairs)
    pycolmap.match_image_pairs(db, matching_options=mopt, pairing_options=popt, device=pycolmap.Device.cpu)


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama (1991) on points [N, 3]: (s, R, t) minimising sum |dst - (s R src + t)|^2."""
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
    return s, r, mu_d - s * r @ mu_s


def _is_pose_stack(a: np.ndarray) -> bool:
    return a.ndim == 3 and a.shape[1:] == (4, 4)


def align_similarity(
    src: np.ndarray,  # [N, 4, 4] c2w (or [N, 3] points)
    dst: np.ndarray,  # [N, 4, 4] c2w (or [N, 3] points), the same cameras in another frame
) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity (s, R [3, 3], t [3]) taking the frame of ``src`` to the frame of ``dst``:
    ``dst ~ s R src + t`` for camera centres, ``R_dst ~ R R_src`` for orientations.

    Umeyama's least squares over each camera's centre and the tips of its three axes at
    ``AXIS_LENGTH`` x the RMS spread of the centres (in each frame its own spread, whose ratio
    is the scale): the orientations fix the rotation where the centres alone do not (fewer
    than 3 cameras, centres on a line as on a slider), and an exact similarity is recovered
    exactly. Points [N >= 3, 3] are aligned by Umeyama on the points alone.

    Convention: c2w OpenCV camera-to-world; apply the result with ``apply_similarity``.

    Raises:
        ValueError naming src, dst: mismatched or malformed arrays, non-finite values, or
        camera centres that all coincide.
    """
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    poses = _is_pose_stack(src) and _is_pose_stack(dst)
    points = src.ndim == 2 and src.shape[1:] == (3,)
    if src.shape != dst.shape or not (poses or points) or len(src) < (2 if poses else 3):
        raise ValueError(
            f"src, dst: need matching [N >= 2, 4, 4] poses or [N >= 3, 3] points, got {src.shape} and {dst.shape}"
        )
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("src, dst: must be finite")
    if points:
        return _umeyama(src, dst)

    def augmented(c2w: np.ndarray) -> np.ndarray:  # [N, 4, 4] -> [4 N, 3]
        p = c2w[:, :3, 3]
        spread = math.sqrt(((p - p.mean(0)) ** 2).sum(1).mean())
        if spread == 0:
            raise ValueError("src, dst: the camera centres all coincide; the scale is undefined")
        tips = p[:, None, :] + AXIS_LENGTH * spread * np.swapaxes(c2w[:, :3, :3], 1, 2)  # [N, 3 axes, 3]
        return np.concatenate([p, tips.reshape(-1, 3)])

    return _umeyama(augmented(src), augmented(dst))


def apply_similarity(
    c2w: np.ndarray,  # [..., 4, 4]
    s: float,
    R: np.ndarray,  # [3, 3]
    t: np.ndarray,  # [3]
) -> np.ndarray:
    """Poses [..., 4, 4] moved by the similarity x -> s R x + t: orientation R R_c, centre
    s R p + t (still rigid: the scale acts on the world, not on the camera)."""
    c = np.asarray(c2w, np.float64)
    if c.shape[-2:] != (4, 4):
        raise ValueError(f"c2w: need [..., 4, 4], got {c.shape}")
    r = np.asarray(R, np.float64)
    out = c.copy()
    out[..., :3, :3] = r @ c[..., :3, :3]
    out[..., :3, 3] = float(s) * c[..., :3, 3] @ r.T + np.asarray(t, np.float64)
    return out


def rotation_errors_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # [N, >=3, >=3] x2 -> [N]
    """The angle (degrees) of the rotation between each ``a[n]`` and ``b[n]`` (poses or rotations:
    the top-left 3 x 3 blocks are read)."""
    rel = np.einsum("nji,njk->nik", np.asarray(a, np.float64)[:, :3, :3], np.asarray(b, np.float64)[:, :3, :3])
    return np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))


def pose_errors(
    est_c2w: np.ndarray,  # [N, 4, 4]
    gt_c2w: np.ndarray,  # [N, 4, 4]
) -> dict:
    """Pose errors after a similarity alignment (``align_similarity``) of ``est`` onto ``gt``:
    ATE (RMSE and max of camera-centre distances, gt units) and rotation errors (degrees)."""
    est_c2w, gt_c2w = np.asarray(est_c2w, np.float64), np.asarray(gt_c2w, np.float64)
    if est_c2w.shape != gt_c2w.shape or est_c2w.ndim != 3 or est_c2w.shape[1:] != (4, 4) or len(est_c2w) < 2:
        raise ValueError(f"est_c2w, gt_c2w: need matching [N >= 2, 4, 4], got {est_c2w.shape} and {gt_c2w.shape}")
    s, r, t = align_similarity(est_c2w, gt_c2w)
    aligned = apply_similarity(est_c2w, s, r, t)
    pd = gt_c2w[:, :3, 3]
    err = np.linalg.norm(aligned[:, :3, 3] - pd, axis=1)
    ang = rotation_errors_deg(gt_c2w, aligned)
    extent = float(np.linalg.norm(pd.max(0) - pd.min(0)))
    return {
        "ate_rmse": float(np.sqrt((err**2).mean())),
        "ate_max": float(err.max()),
        "rot_mean_deg": float(ang.mean()),
        "rot_max_deg": float(ang.max()),
        "scale": s,
        "trajectory_extent": extent,
        "n": int(len(err)),
    }
