"""Pure-torch reference rasteriser: short, obviously correct, runs on any torch device.

Projection (`_project.project`) then, per camera and per 16 x 16 tile, a dense front-to-back
compositor over the Gaussians whose pixel box meets the tile; torch autograd gives every
gradient. Semantics (gsplat classic):

    alpha_k = min(ALPHA_MAX, o_k exp(-sigma_k)),  sigma_k = 0.5 d^T Sigma2d^-1 d,  d = mean2d - pixel
    skip k at the pixel when sigma_k < 0 or alpha_k < ALPHA_MIN
    stop before the first k with T * (1 - alpha_k) <= T_MIN
    image = sum_k alpha_k T_k color_k + T_final * background,  alpha_image = 1 - T_final
"""

from __future__ import annotations

import time

import torch
from torch import Tensor

from ._project import Projected, depth_order, project
from ._sh import sh_colors
from .constants import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE


def composite_dense(
    pix: Tensor,  # [P, 2] pixel centres (x, y)
    means2d: Tensor,  # [G, 2] front to back
    conics: Tensor,  # [G, 3]
    opacities: Tensor,  # [G]
    colors: Tensor,  # [G, D]
) -> tuple[Tensor, Tensor]:  # colour [P, D] (without background), T_final [P]
    """Composite G depth-sorted Gaussians over P pixels, every Gaussian at every pixel."""
    dx = means2d[None, :, 0] - pix[:, None, 0]  # [P, G]
    dy = means2d[None, :, 1] - pix[:, None, 1]
    a, b, c = conics[None, :, 0], conics[None, :, 1], conics[None, :, 2]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities[None, :] * torch.exp(-sigma), max=ALPHA_MAX)
    used = (sigma >= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(used, alpha, torch.zeros_like(alpha))
    with torch.no_grad():  # T after each Gaussian; keep the prefix where it stays above T_MIN
        keep = torch.cumprod(1 - alpha, dim=1) > T_MIN
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    one_minus = 1 - alpha
    trans = torch.cumprod(one_minus, dim=1)  # T after each Gaussian
    t_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
    color = (alpha * t_before) @ colors
    return color, trans[:, -1] if trans.shape[1] > 0 else torch.ones_like(pix[:, 0])


def composite_tiles(
    proj: Projected,
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D] or [C, N, D] (per camera)
    width: int,
    height: int,
    background: Tensor | None,  # [D]
    tile: int = TILE,
) -> tuple[Tensor, Tensor]:  # images [C, H, W, D], alphas [C, H, W, 1]
    """Per camera, per tile: gather the Gaussians whose pixel box meets the tile, composite densely."""
    n_cam = proj.means2d.shape[0]
    d = colors.shape[-1]
    dev, dt = colors.device, colors.dtype
    images = torch.zeros(n_cam, height, width, d, device=dev, dtype=dt)
    t_final = torch.ones(n_cam, height, width, device=dev, dtype=dt)
    for cam in range(n_cam):
        order = depth_order(proj, cam)
        box = proj.pix_box[cam, order]  # [G, 4]
        for ty in range(0, height, tile):
            for tx in range(0, width, tile):
                x1, y1 = min(tx + tile, width), min(ty + tile, height)
                hit = (box[:, 0] < x1) & (box[:, 1] >= tx) & (box[:, 2] < y1) & (box[:, 3] >= ty)
                g = order[hit]
                if g.numel() == 0:
                    continue
                ys, xs = torch.meshgrid(
                    torch.arange(ty, y1, device=dev, dtype=dt),
                    torch.arange(tx, x1, device=dev, dtype=dt),
                    indexing="ij",
                )
                pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1) + 0.5
                cols = colors[cam, g] if colors.ndim == 3 else colors[g]
                col, tf = composite_dense(pix, proj.means2d[cam, g], proj.conics[cam, g], opacities[g], cols)
                images[cam, ty:y1, tx:x1] = col.reshape(y1 - ty, x1 - tx, d)
                t_final[cam, ty:y1, tx:x1] = tf.reshape(y1 - ty, x1 - tx)
    # keep the outputs in the graph even when no Gaussian is visible (zero gradients, not an error)
    images = images + 0.0 * (proj.means2d.sum() + proj.conics.sum() + opacities.sum() + colors.sum())
    if background is not None:
        images = images + t_final[..., None] * background
    return images, (1 - t_final)[..., None]


def rasterize_reference(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
    sh_degree: int | None = None,
) -> tuple[Tensor, Tensor, dict]:
    """Inputs already validated. See `splat_cpu.rasterize` for the contract."""
    t0 = time.perf_counter()
    if sh_degree is not None:
        colors = sh_colors(means, colors, viewmats, sh_degree)  # [C, N, D]
    proj = project(means, quats, scales, opacities, viewmats, Ks, width, height)
    t1 = time.perf_counter()
    images, alphas = composite_tiles(proj, opacities, colors, width, height, background)
    t2 = time.perf_counter()
    meta = {
        "path": "torch",
        "radii": proj.radii,
        "means2d": proj.means2d,
        "depths": proj.depths,
        "n_visible": proj.valid.sum(dim=1),
        "timings": {"project_ms": 1e3 * (t1 - t0), "composite_ms": 1e3 * (t2 - t1)},
    }
    return images, alphas, meta
