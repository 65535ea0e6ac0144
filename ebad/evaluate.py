"""Evaluation: novel views (optionally after test-pose refinement with the scene frozen, the
EBAD-NeRF protocol) and deblurred training frames against ground truth."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from .errors import UserError
from .gaussians import render
from .lie import compose_pose, so3_exp
from .losses import l1_ssim
from .metrics import psnr, ssim
from .trainer import ViewScores, score_views

__all__ = ["refine_pose", "evaluate", "load_gt_frames", "oracle_capture", "score_frames"]


def refine_pose(run, c2w: np.ndarray, image: np.ndarray, iters: int = 60, lr: float = 2e-3) -> np.ndarray:
    """Align one test camera [4, 4] to its image [H, W, D] with the Gaussians frozen.

    A left-multiplied se(3) correction (rotation vector; translation in units of the run's
    scene scale) is optimised with Adam on 0.8 L1 + 0.2 (1 - SSIM); returns the refined c2w.
    """
    base = torch.as_tensor(np.asarray(c2w), dtype=torch.float32)
    target = torch.as_tensor(np.asarray(image), dtype=torch.float32)
    xi = torch.zeros(6, requires_grad=True)
    opt = torch.optim.Adam([xi], lr=lr)
    scale = float(run.trajectories.scale)
    params = {k: v.detach() for k, v in run.params.items()}
    K = torch.as_tensor(run.K, dtype=torch.float32)
    best, best_loss = base.clone(), float("inf")
    for _ in range(iters):
        delta = compose_pose(so3_exp(xi[:3]), scale * xi[3:])
        pose = base @ delta
        img, _, _ = render(params, pose[None], K, run.width, run.height, run.config.model.background)
        loss = l1_ssim(img[0], target)
        if float(loss.detach()) < best_loss:
            best_loss, best = float(loss.detach()), pose.detach().clone()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return best.numpy().astype(np.float64)


def load_gt_frames(gt_dir: str | Path, names: list[str]) -> np.ndarray | None:
    """Sharp training frames [F, H, W, D] from a ``scenes.write_scene`` gt folder, by frame name."""
    gt_dir = Path(gt_dir)
    doc_path = gt_dir / "gt.json"
    if not doc_path.exists():
        return None
    from scenes.images import read_image

    doc = json.loads(doc_path.read_text())
    by_name = {fr["name"]: fr["file"] for fr in doc.get("frames", [])}
    if not all(n in by_name for n in names):
        return None
    return np.stack([read_image(gt_dir / by_name[n]) for n in names])


def evaluate(run, capture=None, refine: bool = False, gt_frames: np.ndarray | None = None,
             refine_iters: int = 60) -> dict:
    """PSNR / SSIM of the capture's test views that carry an image (before and, with ``refine``,
    after test-pose refinement) and of the run's deblurred frames against ``gt_frames``."""
    out: dict[str, ViewScores] = {}
    views = [v for v in (capture.test_views if capture is not None else []) if v.image is not None]
    if views:
        out["test"] = score_views(run.render(np.stack([v.c2w for v in views])), views)
        if refine:
            poses = np.stack([refine_pose(run, v.c2w, v.image, refine_iters) for v in views])
            out["test_refined"] = score_views(run.render(poses), views)
    if gt_frames is not None:
        db = run.deblurred_frames()
        if db.shape != gt_frames.shape:
            raise UserError(f"ground-truth frames {gt_frames.shape} do not match the run's frames {db.shape}")
        out["deblurred"] = score_frames(db, gt_frames)
    return out


def score_frames(images: np.ndarray, truth: np.ndarray) -> ViewScores:  # [F, H, W, D] x2
    """Mean PSNR / SSIM of frames against their ground truth, in order."""
    ps = [psnr(a, b) for a, b in zip(images, truth)]
    ss = [ssim(a, b) for a, b in zip(images, truth)]
    return ViewScores(psnr=float(np.mean(ps)), ssim=float(np.mean(ss)), n=len(ps))


def oracle_capture(scene):
    """The ``oracle`` preset's input: a synthetic capture whose frames are the sharp
    mid-exposure ground truth with zero-length exposures (trusted poses stay)."""
    import copy

    cap = copy.copy(scene.capture)
    cap.frames = np.asarray(scene.gt_frames, dtype=np.float32)
    mid = cap.exposures.mean(1)
    cap.exposures = np.stack([mid, mid], 1)
    return cap
