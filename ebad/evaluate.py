"""Evaluation: novel views and deblurred training frames against ground truth, by a stated protocol.

The protocol (``evaluate``), as in BAD-Gaussians / EBAD-NeRF:

1. **Which poses.** Each test view with an image is rendered at its pose in the run's frame:
   the pose the run's SfM registered for it (by name), else the capture's own pose when the run
   trained on the capture's poses, else the capture's pose moved by the Sim(3) (Umeyama) that
   maps the capture's training cameras onto the run's recovered mid-exposure cameras.
2. **Refinement** (``refine=True``): each test pose is then refined against its image with the
   scene frozen, a left-multiplied se(3) correction optimised by Adam on 0.8 L1 + 0.2 (1 - SSIM)
   until the loss improves by less than ``REFINE_TOL`` (relative) over ``REFINE_WINDOW`` steps
   or ``refine_iters`` steps are spent; the best pose seen is kept. Scores are reported before
   and after.
3. **Metrics.** PSNR over all pixels and channels of images clamped to [0, 1] (data range 1);
   SSIM with kornia's Gaussian window of 11 pixels, sigma 1.5, reflect padding, data range 1.
   The deblurred training frames (each rendered at its recovered mid-exposure pose) are scored
   against the sharp ground truth where it is given, frame by name (``run_truth``: a frame SfM did
   not register is not in the run and not scored).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from .data import align_poses
from .errors import UserError
from .gaussians import render
from .lie import compose_pose, so3_exp
from .losses import l1_ssim_each
from .progress import Ticker
from .run import Run
from .scoring import ViewScores, in_image_domain, score_frames, score_views, view_pose, with_poses
from .threads import torch_single_threaded

if TYPE_CHECKING:
    from scenes import Capture, SynthScene, TestView

__all__ = [
    "refine_pose",
    "refine_poses",
    "evaluate",
    "eval_poses",
    "run_truth",
    "sharp_capture",
    "score_frames",
    "score_views",
    "ViewScores",
    "REFINE_TOL",
    "REFINE_WINDOW",
    "REFINE_LR",
]

REFINE_TOL = 1e-4  # refinement stops when the loss improved by less than this fraction ...
REFINE_WINDOW = 20  # ... over this many steps
REFINE_LR = 2e-3  # Adam step of the correction (radians; translation in units of the run's scene scale)


def _image(view: TestView) -> np.ndarray:  # [H, W, D]
    """The sharp image of a view that has one (``evaluate`` keeps only those)."""
    if view.image is None:
        raise ValueError(f"test view {view.name!r} has no image")
    return view.image


def refine_pose(
    run: Run,
    c2w: np.ndarray,
    image: np.ndarray,
    iters: int = 300,
    lr: float = REFINE_LR,
    tol: float = REFINE_TOL,
    window: int = REFINE_WINDOW,
    cfa: str | None = None,
) -> tuple[np.ndarray, int]:
    """Align one test camera [4, 4] to its image [H, W, D] with the Gaussians frozen.

    Returns the best pose seen and the steps taken (see the module docstring for the rule). A raw
    Bayer mosaic ``image`` (one channel, ``cfa`` given) is compared with the render's mosaic."""
    return refine_poses(run, [c2w], [image], iters, lr, tol, window, cfa)[0]


def refine_poses(
    run: Run,
    c2ws: Sequence[np.ndarray],
    images: Sequence[np.ndarray],
    iters: int = 300,
    lr: float = REFINE_LR,
    tol: float = REFINE_TOL,
    window: int = REFINE_WINDOW,
    cfa: str | None = None,
    done: Callable[[int], None] | None = None,
) -> list[tuple[np.ndarray, int]]:
    """``refine_pose`` for each test camera ``c2ws[i]`` [4, 4] and its image ``images[i]``, each view
    as it would be alone (its own correction, Adam state, stopping rule and best pose), the views
    still refining rendered in one rasteriser call a step and their losses in one kernel call,
    torch on one thread. ``done(k)`` is called after every step with the k views stopped so far
    (``progress.Ticker``)."""
    bases = [torch.as_tensor(np.asarray(c), dtype=torch.float32) for c in c2ws]
    targets = [torch.as_tensor(np.asarray(im), dtype=torch.float32) for im in images]
    xis = [torch.zeros(6, requires_grad=True) for _ in bases]
    scale = float(run.trajectories.scale)
    params = {k: v.detach() for k, v in run.params.items()}
    K = torch.as_tensor(run.K, dtype=torch.float32)
    best = [b.clone() for b in bases]
    best_loss = [float("inf")] * len(bases)
    losses: list[list[float]] = [[] for _ in bases]  # a view's steps: the length of its list
    active = list(range(len(bases)))
    n_done = 0
    with torch_single_threaded():
        opt = torch.optim.Adam(xis, lr=lr)  # per-parameter state: a view without a gradient is not moved
        for _step in range(iters):
            if not active:
                break
            poses = [bases[v] @ compose_pose(so3_exp(xis[v][:3]), scale * xis[v][3:]) for v in active]
            img, _, _ = render(params, torch.stack(poses), K, run.width, run.height, run.config.model.background)
            pairs = [
                (in_image_domain(run.response(img[j]), targets[v].shape[-1], cfa), targets[v])
                for j, v in enumerate(active)
            ]
            loss = l1_ssim_each(pairs)  # in the camera's domain, like the image
            going = []
            for j, v in enumerate(active):
                value = float(loss[j].detach())
                losses[v].append(value)
                if value < best_loss[v]:
                    best_loss[v], best[v] = value, poses[j].detach().clone()
                h = losses[v]
                if len(h) > window and h[-window - 1] - min(h[-window:]) < tol * h[-window - 1]:
                    n_done += 1
                    continue
                going.append(j)
            if done is not None:
                done(n_done)
            opt.zero_grad()
            if going:
                torch.stack([loss[j] for j in going]).sum().backward()
                opt.step()
            active = [active[j] for j in going]
    if done is not None:
        for k in range(n_done + 1, len(bases) + 1):
            done(k)  # the views that spent their steps stop too
    return [(b.numpy().astype(np.float64), len(h)) for b, h in zip(best, losses)]


def eval_poses(run: Run, capture: Capture) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Each test view's pose in the run's frame, and how it was found: 'run' (registered by the
    run's SfM), 'capture' (the run trained on the capture's poses) or 'aligned' (Sim(3) from the
    training cameras). Views with neither are left out (named in the second dict as 'none')."""
    poses, how = {}, {}
    frame_idx = {n: i for i, n in enumerate(capture.names)} if capture.names else {}
    common = [n for n in run.names if n in frame_idx]
    for v in capture.test_views:
        if v.image is None:
            continue
        if v.name in run.test_c2w:
            poses[v.name], how[v.name] = np.asarray(run.test_c2w[v.name]), "run"
        elif v.c2w is not None and run.pose_source in ("capture", "static"):
            poses[v.name], how[v.name] = np.asarray(v.c2w, np.float64), "capture"
        elif v.c2w is not None and capture.c2w is not None and len(common) >= 2:
            src = np.asarray(capture.c2w, np.float64)[[frame_idx[n] for n in common]]
            mids = run.trajectories.mid_poses().double().numpy()[[run.names.index(n) for n in common]]
            poses[v.name], how[v.name] = align_poses(src, mids, np.asarray(v.c2w, np.float64)), "aligned"
        else:
            how[v.name] = "none"
    return poses, how


def run_truth(run: Run, gt_frames: np.ndarray, capture: Capture | None = None) -> np.ndarray:
    """The rows of ``gt_frames`` that belong to the run's frames, in ``run.names``' order. ``gt_frames``
    holds one sharp frame per run frame, or one per capture frame (``capture.frame_names()``' order,
    ``capture`` given): then the run's are picked by name (a run leaves out the test frames and the
    frames SfM did not register)."""
    truth = np.asarray(gt_frames)
    if capture is not None and len(truth) == capture.num_frames and len(truth) != len(run.names):
        pos = {n: i for i, n in enumerate(capture.frame_names())}
        missing = [n for n in run.names if n not in pos]
        if missing:
            raise UserError(f"the run's frames {', '.join(missing[:3])} are not frames of the capture")
        truth = truth[[pos[n] for n in run.names]]
    return truth


def evaluate(
    run: Run,
    capture: Capture | None = None,
    refine: bool = False,
    gt_frames: np.ndarray | None = None,
    refine_iters: int = 300,
    renders_to: Callable[[str, np.ndarray], None] | None = None,
    show: bool = False,
) -> dict:
    """The protocol of the module docstring. Returns ``{"test": ViewScores, "test_refined":
    ViewScores, "deblurred": ViewScores}`` (those that apply), plus "poses" (how each test pose
    was found) and "refine_steps" (per view). ``renders_to(name, image)`` receives each test
    render (the refined one when refining). Refining says how far it is (``ebad.progress``; printed
    with ``show``): it takes a minute or two on a 346x260 capture."""
    out: dict = {}
    if capture is not None:
        poses, how = eval_poses(run, capture)
        views = [v for v in with_poses(capture.test_views, poses) if v.image is not None and v.name in poses]
        out["poses"] = how
        if views:
            images = run.render(np.stack([view_pose(v) for v in views]))
            cfa = capture.cfa
            out["test"] = score_views(images, views, cfa)
            if refine:
                tick = Ticker(show, f"refining test poses (up to {refine_iters} steps a view)", len(views))
                refined = refine_poses(
                    run, [view_pose(v) for v in views], [_image(v) for v in views], refine_iters, cfa=cfa, done=tick
                )
                out["refine_steps"] = {v.name: steps for v, (_, steps) in zip(views, refined)}
                images = run.render(np.stack([pose for pose, _ in refined]))
                out["test_refined"] = score_views(images, views, cfa)
            if renders_to is not None:
                for v, img in zip(views, images):
                    renders_to(v.name, img)
    if gt_frames is not None:
        db, truth = run.deblurred_frames(), run_truth(run, gt_frames, capture)
        if db.shape != truth.shape:
            raise UserError(f"ground-truth frames {truth.shape} do not match the run's frames {db.shape}")
        out["deblurred"] = score_frames(db, truth)
    return out


def sharp_capture(scene: SynthScene) -> Capture:
    """The ``3dgs-sharp`` preset's input: a synthetic capture whose frames are the sharp
    mid-exposure ground truth with zero-length exposures (its poses as the capture gives them)."""
    cap = copy.copy(scene.capture)
    cap.frames = np.asarray(scene.gt_frames, dtype=np.float32)
    mid = cap.exposures.mean(1)
    cap.exposures = np.stack([mid, mid], 1)
    return cap
