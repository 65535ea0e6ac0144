"""Scores of rendered views against images: the helpers that training-time evaluation
(``ebad.callbacks.Evaluator``) and the evaluation protocol (``ebad.evaluate``) share.

``render_images`` renders views in batches without gradients; ``score_views`` and
``score_frames`` give PSNR / SSIM (``ebad.metrics``) as ``ViewScores``; ``with_poses`` and
``evaluate_views`` pick the views that carry an image and a pose and score them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from edi.cfa import mosaic

from .gaussians import render
from .metrics import psnr, ssim

if TYPE_CHECKING:
    from scenes import TestView

__all__ = [
    "in_image_domain",
    "ViewScores",
    "render_images",
    "score_views",
    "score_frames",
    "with_poses",
    "scorable_views",
    "view_pose",
    "evaluate_views",
]


@dataclass
class ViewScores:
    """Mean PSNR / SSIM over some views, and each view's."""

    psnr: float
    ssim: float
    n: int
    per_view: dict[str, dict[str, float]] = field(default_factory=dict)


def render_images(
    params: Mapping[str, Tensor],
    c2w,
    K,
    width: int,
    height: int,
    background: float = 0.0,
    batch: int = 8,
    response: Callable[[Tensor], Tensor] | None = None,
) -> np.ndarray:
    """Render ``C`` views [C, 4, 4] in batches, without gradients, through the camera ``response``
    when given, clamped to [0, 1] -> [C, H, W, D] numpy float32."""
    c2w_t = torch.as_tensor(np.asarray(c2w), dtype=torch.float32)
    K_t = torch.as_tensor(np.asarray(K), dtype=torch.float32)
    out = []
    with torch.no_grad():
        for i in range(0, c2w_t.shape[0], batch):
            img, _, _ = render(params, c2w_t[i : i + batch], K_t, width, height, background)
            out.append((img if response is None else response(img)).clamp(0, 1))
    return torch.cat(out).numpy()


def in_image_domain(render: Any, image_channels: int, cfa: str | None) -> Any:  # [..., H, W, D] numpy or torch
    """A render in the domain of an image of ``image_channels`` channels: a colour render against a
    raw Bayer mosaic (one channel, a capture with ``cfa``) becomes its mosaic ([..., H, W, 1]); else as is."""
    if cfa is not None and image_channels == 1 and render.shape[-1] == 3:
        return mosaic(render, cfa)[..., None]
    return render


def score_views(
    images: np.ndarray,  # [C, H, W, D]
    views: Sequence[TestView],
    cfa: str | None = None,
) -> ViewScores:
    """PSNR / SSIM of rendered images against the views' images (each view's ``image``, by ``name``);
    against raw mosaics (``cfa``) the renders' mosaics are scored."""

    def pair(i: int, v: TestView) -> tuple[np.ndarray, np.ndarray]:
        assert v.image is not None  # scorable views carry one
        return in_image_domain(images[i], v.image.shape[-1], cfa), v.image

    per = {}
    for i, v in enumerate(views):
        a, b = pair(i, v)
        per[v.name] = {"psnr": psnr(a, b), "ssim": ssim(a, b)}
    return ViewScores(
        psnr=float(np.mean([p["psnr"] for p in per.values()])),
        ssim=float(np.mean([p["ssim"] for p in per.values()])),
        n=len(views),
        per_view=per,
    )


def score_frames(images: np.ndarray, truth: np.ndarray) -> ViewScores:  # [F, H, W, D] x2
    """Mean PSNR / SSIM of frames against their ground truth, in order."""
    ps = [psnr(a, b) for a, b in zip(images, truth)]
    ss = [ssim(a, b) for a, b in zip(images, truth)]
    return ViewScores(psnr=float(np.mean(ps)), ssim=float(np.mean(ss)), n=len(ps))


def with_poses(views: Sequence[TestView], poses: dict[str, np.ndarray]) -> list[TestView]:
    """The views with their pose replaced by ``poses[name]`` where given (poses in the run's frame)."""
    return [dataclasses.replace(v, c2w=poses[v.name]) if v.name in poses else v for v in views]


def scorable_views(views: Sequence[TestView]) -> list[TestView]:
    """The views that carry both an image and a pose."""
    return [v for v in views if getattr(v, "image", None) is not None and getattr(v, "c2w", None) is not None]


def view_pose(view: TestView) -> np.ndarray:  # [4, 4]
    """The pose of a view that has one (a scorable view's, or one given by ``with_poses``)."""
    if view.c2w is None:
        raise ValueError(f"test view {view.name!r} has no pose")
    return view.c2w


def evaluate_views(
    render_fn: Callable[[np.ndarray], np.ndarray], views: Sequence[TestView], cfa: str | None = None
) -> ViewScores | None:
    """Mean PSNR / SSIM of the views that carry an image and a pose (None when none does);
    ``render_fn(c2w [C, 4, 4]) -> [C, H, W, D]``; ``cfa``: as ``score_views``."""
    views = scorable_views(views)
    if not views:
        return None
    return score_views(render_fn(np.stack([view_pose(v) for v in views])), views, cfa)
