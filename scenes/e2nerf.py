"""The EBAD-NeRF and E2NeRF dataset layouts: binned events, LLFF or NeRF-synthetic poses.

EBAD-NeRF (LLFF variant; also E2NeRF's real-world data)::

    images/                  blurry frames, all views, in sorted file-name order
    images_gt_blur/          optional: sharp frames at the training views (same order)
    images_gt_novel/         optional: sharp frames at the held-out views (same order)
    events.pt                signed event counts [V, B, H*W] (or [V, B, H, W]); V = all views
                             or the training views only
    poses_bounds.npy         LLFF [V, 17] (``pose_bounds.npy`` accepted): COLMAP on the blurry frames

    Held-out views are every ``llffhold``-th image, i = 0, llffhold, 2 llffhold, ... (EBAD-NeRF's
    split, default 8), only when ``images_gt_novel/`` exists; they become ``Capture.test_views``
    with the sharp image of ``images_gt_novel/`` and the LLFF pose of their blurry frame (to be
    refined against the image at scoring, the BAD-NeRF protocol). Their blurry frames and events
    are not part of the capture (listed in ``meta['held_out_frames']``).

E2NeRF (NeRF-synthetic variant)::

    transforms_train.json    (or transform_train.json) ``camera_angle_x`` and ``frames``, each
                             with ``transform_matrix``: one 4x4 c2w, or a list of them equally
                             spaced over the exposure (the poses the blur was rendered from);
                             optional ``file_path`` (``./train/r_0``) naming the image
    train/                   blurry frames; without ``file_path`` matched to frames in order
    transforms_test.json     optional, with ``test/``: sharp held-out views
    events.pt                as above, one row per training frame

    Poses are Blender/OpenGL camera-to-world (x right, y up, z back): we flip y and z. A list
    of poses gives the mid-exposure c2w by slerp at its middle; a test view takes the first pose
    of its list (E2NeRF renders the ground truth there).

Binned events (what the capture cannot know, and the rule that stands in for it):
the layouts keep signed counts per view and bin, not timestamps, and no exposure times.
Frame k gets the nominal exposure ``[2 k T, 2 k T + T]`` with ``T = B * BIN_S`` (``BIN_S`` =
10 ms), so exposures never overlap and bins are whole microseconds. Bin b of frame k covers
``[t_start + b T / B, t_start + (b + 1) T / B)`` (B equal parts of the exposure, as E2NeRF's
event loss assumes), and a count n at a pixel becomes |n| events of polarity sign(n) at the bin
centre. So the events between any two bin edges are exactly the counts of the bins between
them: EDI's double integral sees E(t) as a step at each bin centre, and an event loss between
virtual views placed on bin edges is exact. Nothing is known between exposures (no events
there). ``meta['events_binned']`` records B, the bin length and this rule;
``meta['exposure_known'] = False``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from edi import EventStream, seconds_to_us

from .capture import Capture, TestView, nearest_rigid
from .errors import CaptureError
from .images import read_image
from .jsonio import read_json_object
from .poses import interpolate_poses, opengl_to_opencv, read_poses_bounds
from .truth import GroundTruth

__all__ = [
    "load_ebad_nerf",
    "load_e2nerf",
    "read_event_bins",
    "events_from_bins",
    "nominal_exposures",
    "detect_e2nerf",
    "ground_truth_blur",
    "BIN_S",
    "LLFF_HOLD",
    "EVENTS_FILE",
    "CFA_NOTE",
]

BIN_S = 0.01  # nominal length of one event bin, seconds (the layouts record none)
LLFF_HOLD = 8  # every 8th view is held out when images_gt_novel/ exists (EBAD-NeRF's llffhold)
EVENTS_FILE = "events.pt"
# Counts that cannot be right, refused before anything is allocated from them: more events in one
# pixel and bin than a DAVIS pixel can fire (~1 MHz over a 10 ms bin), or more events in all than
# fit in memory as a stream (about 33 bytes an event: 2^28 events is ~9 GB).
MAX_BIN_COUNT = 10_000
MAX_EVENTS = 2**28
POSES_FILES = ("poses_bounds.npy", "pose_bounds.npy")
TRANSFORMS = {
    "train": ("transforms_train.json", "transform_train.json"),
    "test": ("transforms_test.json", "transform_test.json"),
}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
# E2NeRF's real-world preprocessing (orginal_data&preprocessing/real-world/Data-preprocessing) writes
# DV's demosaiced frames of a colour DAVIS346 as images and sums the events per sensor pixel: the
# events come from the mosaic, but the layout does not record which Bayer filter it has
CFA_NOTE = (
    "colour frames, but the layout records no colour filter: the events are taken as luminance; "
    "a colour DAVIS's filter is stated with --cfa (scenes.load(cfa=...))"
)
BINNED_RULE = (
    "bin b of a frame covers [t_start + b T/B, t_start + (b+1) T/B) of its nominal exposure T; a "
    "signed count n becomes |n| events of polarity sign(n) at the bin centre"
)


def _first(root: Path, names: tuple[str, ...]) -> Path | None:
    return next((root / n for n in names if (root / n).is_file()), None)


def detect_e2nerf(root: str | os.PathLike) -> Literal["ebad-nerf", "e2nerf"] | None:
    """ "ebad-nerf" (LLFF poses), "e2nerf" (transforms json) or None."""
    root = Path(root)
    if not (root / EVENTS_FILE).is_file():
        return None
    if _first(root, POSES_FILES) is not None and (root / "images").is_dir():
        return "ebad-nerf"
    if _first(root, TRANSFORMS["train"]) is not None:
        return "e2nerf"
    return None


def _images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _same_shape(img: np.ndarray, ref: np.ndarray, path: Path) -> np.ndarray:
    if img.shape != ref.shape:
        raise CaptureError(
            str(path),
            "images",
            f"is {img.shape[1]}x{img.shape[0]}x{img.shape[2]}, the first image "
            f"{ref.shape[1]}x{ref.shape[0]}x{ref.shape[2]}",
        )
    return img


def read_event_bins(path: Path) -> np.ndarray:  # -> [V, B, P] int32 (P = H*W, or [V, B, H, W] flattened)
    """Signed event counts from an ``events.pt`` (a tensor [V, B, H*W] or [V, B, H, W]), read
    with ``torch.load(weights_only=True)``: no code in the file runs.

    Counts that cannot be right are refused before any allocation from them: a tensor that views
    a smaller storage (stride 0: a tiny file standing for a huge array), a count beyond
    ``MAX_BIN_COUNT`` in magnitude (which int32 would wrap), more than ``MAX_EVENTS`` in all.

    Raises:
        CaptureError: empty or unreadable file, not a tensor, wrong rank, non-integer, non-finite
            or impossible counts.
    """
    import pickle

    import torch

    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), "events", "file not found")
    if path.stat().st_size == 0:
        raise CaptureError(str(path), "events", "empty file (0 bytes)")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, EOFError, RuntimeError, pickle.UnpicklingError, ValueError, IndexError) as exc:
        raise CaptureError(
            str(path), "events", f"unreadable ({type(exc).__name__}: {str(exc).splitlines()[0]})"
        ) from None
    if not isinstance(obj, torch.Tensor):
        raise CaptureError(str(path), "events", f"must hold one tensor [views, bins, H*W], got {type(obj).__name__}")
    stored = obj.untyped_storage().nbytes() // max(obj.element_size(), 1)
    if obj.numel() > stored:
        raise CaptureError(
            str(path),
            "events",
            f"a tensor of shape {tuple(obj.shape)} ({obj.numel()} counts) over a storage of {stored}: "
            "repeated counts (stride 0) cannot be event data",
        )
    a = obj.detach().numpy()
    if a.ndim == 4:
        a = a.reshape(a.shape[0], a.shape[1], -1)
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise CaptureError(
            str(path), "events", f"expected shape [views, bins, H*W] or [views, bins, H, W], got {tuple(obj.shape)}"
        )
    if a.dtype.kind == "f":
        if not np.isfinite(a).all():
            raise CaptureError(str(path), "events", "has non-finite counts")
        if np.any(a != np.round(a)):
            raise CaptureError(str(path), "events", "counts must be whole numbers of events")
    elif a.dtype.kind not in "iu":
        raise CaptureError(str(path), "events", f"counts must be numeric, got {a.dtype}")
    # compared, not abs(): abs of the most negative int64 is itself
    big = np.flatnonzero(((a > MAX_BIN_COUNT) | (a < -MAX_BIN_COUNT)).reshape(-1))
    if big.size:
        v, b, px = np.unravel_index(int(big[0]), a.shape)
        raise CaptureError(
            str(path),
            "events",
            f"count {a[v, b, px]} at view {v}, bin {b}, pixel {px}: more than {MAX_BIN_COUNT} events in one pixel "
            f"and bin cannot be right ({big.size} such counts)",
        )
    counts = a.astype(np.int32)
    total = int(np.abs(counts).sum(dtype=np.int64))
    if total > MAX_EVENTS:
        raise CaptureError(
            str(path), "events", f"{total} events in all: more than {MAX_EVENTS} cannot be held as an event stream"
        )
    return counts


def nominal_exposures(n_frames: int, n_bins: int, bin_s: float = BIN_S) -> np.ndarray:  # -> [F, 2] seconds
    """The stand-in exposures of the module docstring: frame k spans [2 k T, 2 k T + T], T = B bin_s."""
    T = n_bins * bin_s
    start = 2.0 * T * np.arange(n_frames)
    return np.stack([start, start + T], 1)


def events_from_bins(
    counts: np.ndarray,  # [F, B, H*W] signed counts
    exposures: np.ndarray,  # [F, 2] seconds
    width: int,
    height: int,
) -> EventStream:
    """Events at bin centres standing for binned counts (the rule in the module docstring)."""
    f, b, p = counts.shape
    if p != width * height:
        raise ValueError(f"counts have {p} pixels per bin, the frames {width}x{height} = {width * height}")
    start_us = np.array([seconds_to_us(t) for t in exposures[:, 0]], np.int64)
    end_us = np.array([seconds_to_us(t) for t in exposures[:, 1]], np.int64)
    # centre of bin j of frame k: start + (2 j + 1) (end - start) / (2 B), whole microseconds
    centres = start_us[:, None] + ((2 * np.arange(b)[None, :] + 1) * (end_us - start_us)[:, None]) // (2 * b)
    flat = counts.reshape(-1)
    nz = np.flatnonzero(flat)
    reps = np.abs(flat[nz]).astype(np.int64)
    fb, pix = np.divmod(nz, p)
    t = np.repeat(centres.reshape(-1)[fb], reps)
    pol = np.repeat(np.sign(flat[nz]).astype(np.int8), reps)
    pix = np.repeat(pix, reps)
    return EventStream(t, pix % width, pix // width, pol, width, height)


def _binned_meta(b: int, exposures: np.ndarray) -> dict[str, Any]:
    return {
        "events_binned": {"bins": int(b), "bin_s": float((exposures[0, 1] - exposures[0, 0]) / b), "rule": BINNED_RULE},
        "exposure_known": False,
        "exposure_rule": "nominal: frame k spans [2 k T, 2 k T + T], T = bins x bin_s; no events between exposures",
    }


def _match_events(counts: np.ndarray, n_all: int, keep: np.ndarray, ev_path: Path) -> np.ndarray:
    if counts.shape[0] == n_all:
        return counts[keep]
    if counts.shape[0] == len(keep):
        return counts
    raise CaptureError(
        str(ev_path),
        "events",
        f"{counts.shape[0]} views of counts for {n_all} images ({len(keep)} of them for training)",
    )


def load_ebad_nerf(root: str | os.PathLike, llffhold: int = LLFF_HOLD) -> Capture:
    """The EBAD-NeRF / E2NeRF real-world LLFF layout (module docstring)."""
    root = Path(root)
    pb_path = _first(root, POSES_FILES)
    if pb_path is None:
        raise CaptureError(str(root / POSES_FILES[0]), "poses_bounds", "file not found")
    c2w_all, hwf, bounds = read_poses_bounds(pb_path)
    files = _images(root / "images")
    n = len(files)
    if n != len(c2w_all):
        raise CaptureError(str(root / "images"), "images", f"{n} images for {len(c2w_all)} poses in {pb_path.name}")
    first = read_image(files[0], "images[0]")
    h, w, _ = first.shape
    novel = _images(root / "images_gt_novel")
    test_idx = np.arange(0, n, llffhold) if novel else np.zeros(0, np.int64)
    if novel and len(novel) != len(test_idx):
        raise CaptureError(
            str(root / "images_gt_novel"),
            "images",
            f"{len(novel)} images, but holding out every {llffhold}th of {n} views gives {len(test_idx)}",
        )
    keep = np.setdiff1d(np.arange(n), test_idx)
    if len(keep) == 0:
        raise CaptureError(str(root / "images"), "images", "no training view left after holding out the novel views")
    ev_path = root / EVENTS_FILE
    counts = _match_events(read_event_bins(ev_path), n, keep, ev_path)
    if counts.shape[2] != w * h:
        raise CaptureError(str(ev_path), "events", f"{counts.shape[2]} pixels per bin, the images are {w}x{h}")
    frames = np.stack(
        [_same_shape(first if i == 0 else read_image(files[i], f"images[{i}]"), first, files[i]) for i in keep]
    )
    slots = nominal_exposures(n, counts.shape[1])  # every view keeps its slot on the clock
    exposures = slots[keep]
    events = events_from_bins(counts, exposures, w, h)
    c2w = np.stack([nearest_rigid(c2w_all[i], str(pb_path), f"poses_bounds[{i}]") for i in range(n)])
    f = hwf[0, 2] * w / hwf[0, 1]  # focal of the stored size, scaled to the images
    if abs(hwf[0, 0] / hwf[0, 1] - h / w) > 0.02:
        raise CaptureError(
            str(pb_path),
            "poses_bounds[0].hwf",
            f"aspect {hwf[0, 1]:g}x{hwf[0, 0]:g} does not match the images' {w}x{h}",
        )
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    test_views = [
        TestView(
            name=novel[j].stem,
            t=float(slots[i].mean()),
            c2w=c2w[i],
            image=read_image(novel[j], f"images_gt_novel[{j}]"),
        )
        for j, i in enumerate(test_idx)
    ]
    meta = {
        "source_layout": "ebad-nerf",
        "source": str(root),
        "bounds": bounds[keep].tolist(),
        "pose_source": f"{pb_path.name} (LLFF; COLMAP on the blurry frames)",
        "held_out_frames": [files[i].name for i in test_idx],
        **_binned_meta(counts.shape[1], exposures),
    }
    if frames.shape[-1] == 3:
        meta["cfa_note"] = CFA_NOTE
    return Capture(
        frames=frames,
        exposures=exposures,
        events=events,
        K=K,
        c2w=c2w[keep],
        split=["train"] * len(keep),
        test_views=test_views,
        names=[files[i].stem for i in keep],
        meta=meta,
    )


def _transforms(path: Path) -> tuple[dict, list]:
    doc = read_json_object(path)
    if not isinstance(doc.get("frames"), list) or not doc["frames"]:
        raise CaptureError(str(path), "frames", "must be a non-empty list")
    return doc, doc["frames"]


def _pose_list(v: Any, jf: str, field: str) -> np.ndarray:  # -> [S, 4, 4] OpenCV, rigid
    try:
        a = np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise CaptureError(jf, field, "must be a 4x4 matrix or a list of them") from None
    if a.shape == (4, 4):
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (4, 4) or len(a) == 0:
        raise CaptureError(jf, field, f"must be a 4x4 matrix or a list of them, got shape {a.shape}")
    return np.stack([opengl_to_opencv(nearest_rigid(m, jf, f"{field}[{s}]")) for s, m in enumerate(a)])


def _mid_pose(poses: np.ndarray) -> np.ndarray:  # [S, 4, 4] over the exposure -> [4, 4] at its middle
    if len(poses) == 1:
        return poses[0]
    s = np.linspace(0.0, 1.0, len(poses))
    out, _ = interpolate_poses(np.array([0.5]), s, poses[:, :3, 3], Rotation.from_matrix(poses[:, :3, :3]).as_quat())
    return out[0]


def _frame_image(root: Path, fr: dict, k: int, files: list[Path], jf: str) -> Path | None:
    fp = fr.get("file_path")
    if fp is None:
        return files[k] if k < len(files) else None
    if not isinstance(fp, str):
        raise CaptureError(jf, f"frames[{k}].file_path", f"must be a string, got {fp!r}")
    p = (root / fp).resolve()
    if p.suffix.lower() in IMAGE_SUFFIXES:
        return p if p.is_file() else None
    return next((p.with_suffix(s) for s in IMAGE_SUFFIXES if p.with_suffix(s).is_file()), None)


def load_e2nerf(root: str | os.PathLike) -> Capture:
    """The E2NeRF NeRF-synthetic layout (module docstring)."""
    root = Path(root)
    tj = _first(root, TRANSFORMS["train"])
    if tj is None:
        raise CaptureError(str(root / TRANSFORMS["train"][0]), None, "file not found")
    jf = str(tj)
    doc, frames_doc = _transforms(tj)
    files = _images(root / "train")
    with_path = any(isinstance(fr, dict) and "file_path" in fr for fr in frames_doc)
    if not with_path and len(files) != len(frames_doc):
        raise CaptureError(
            str(root / "train"),
            "images",
            f"{len(files)} images for {len(frames_doc)} frames in {tj.name} (and no file_path to match them)",
        )
    images: list[np.ndarray] = []
    c2w: list[np.ndarray] = []
    names: list[str] = []
    for k, fr in enumerate(frames_doc):
        if not isinstance(fr, dict) or "transform_matrix" not in fr:
            raise CaptureError(jf, f"frames[{k}].transform_matrix", "missing")
        img = _frame_image(root, fr, k, files, jf)
        if img is None:
            continue  # a pose without a training image (E2NeRF lists every second view)
        im = read_image(img, f"frames[{k}].file_path")
        images.append(_same_shape(im, images[0], img) if images else im)
        c2w.append(_mid_pose(_pose_list(fr["transform_matrix"], jf, f"frames[{k}].transform_matrix")))
        names.append(img.stem)
    if not images:
        raise CaptureError(jf, "frames", "no frame has its image under train/")
    frames = np.stack(images)
    _, h, w, _ = frames.shape
    angle = doc.get("camera_angle_x")
    if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not 0 < angle < math.pi:
        raise CaptureError(jf, "camera_angle_x", f"must be a number in (0, pi) radians, got {angle!r}")
    f = 0.5 * w / math.tan(0.5 * angle)
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    ev_path = root / EVENTS_FILE
    counts = read_event_bins(ev_path)
    if counts.shape[0] != len(frames):
        raise CaptureError(
            str(ev_path), "events", f"{counts.shape[0]} views of counts for {len(frames)} training frames"
        )
    if counts.shape[2] != w * h:
        raise CaptureError(str(ev_path), "events", f"{counts.shape[2]} pixels per bin, the images are {w}x{h}")
    exposures = nominal_exposures(len(frames), counts.shape[1])
    events = events_from_bins(counts, exposures, w, h)
    test_views = []
    tt = _first(root, TRANSFORMS["test"])
    if tt is not None:
        _, test_doc = _transforms(tt)
        test_files = _images(root / "test")
        for k, fr in enumerate(test_doc):
            if not isinstance(fr, dict) or "transform_matrix" not in fr:
                raise CaptureError(str(tt), f"frames[{k}].transform_matrix", "missing")
            img = _frame_image(root, fr, k, test_files, str(tt))
            if img is None:
                continue
            pose = _pose_list(fr["transform_matrix"], str(tt), f"frames[{k}].transform_matrix")[0]
            # a novel view has no time on the capture's clock: t = 0 stands for "none"
            test_views.append(
                TestView(
                    name=f"test_{img.stem}", t=0.0, c2w=pose, image=read_image(img, f"{tt.name}: frames[{k}].file_path")
                )
            )
    meta = {
        "source_layout": "e2nerf",
        "source": str(root),
        "pose_source": f"{tj.name} (Blender, mid-exposure)",
        **_binned_meta(counts.shape[1], exposures),
    }
    return Capture(
        frames=frames,
        exposures=exposures,
        events=events,
        K=K,
        c2w=np.stack(c2w),
        split=["train"] * len(frames),
        test_views=test_views,
        names=names,
        meta=meta,
    )


def ground_truth_blur(root: str | os.PathLike, llffhold: int = LLFF_HOLD) -> GroundTruth:
    """A :class:`scenes.truth.GroundTruth` mapping the training frames of an EBAD-NeRF folder
    (names as :func:`load_ebad_nerf` gives them) to the sharp images of ``images_gt_blur/``
    (sorted, one per training view, in the same order)."""
    root = Path(root)
    all_files = _images(root / "images")
    held = set(range(0, len(all_files), llffhold)) if _images(root / "images_gt_novel") else set()
    names = [p.stem for i, p in enumerate(all_files) if i not in held]
    files = _images(root / "images_gt_blur")
    if len(files) != len(names):
        raise CaptureError(
            str(root / "images_gt_blur"), "images", f"{len(files)} images for {len(names)} training frames"
        )
    return GroundTruth(root=root / "images_gt_blur", frame_files=dict(zip(names, files)))
