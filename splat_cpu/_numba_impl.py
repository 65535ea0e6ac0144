"""The fast CPU path: torch projection (autograd) + numba tile compositing (hand-written backward)."""

from __future__ import annotations

import math
import time

import numba
import numpy as np
import torch
from torch import Tensor

from . import _numba_kernels as K
from ._project import project
from .constants import TILE

_CHUNK = 2  # dynamic scheduling of tiles over threads: tiles cost very different amounts


class _Plan:
    """Per-call binning: which Gaussians touch which tile, front to back (no gradients)."""

    def __init__(self, pix_box: np.ndarray, tile_start: np.ndarray, gid: np.ndarray,
                 width: int, height: int, tiles_x: int, tiles_y: int):
        self.pix_box, self.tile_start, self.gid = pix_box, tile_start, gid
        self.width, self.height, self.tiles_x, self.tiles_y = width, height, tiles_x, tiles_y


def _np(x: Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().cpu().numpy())


class _Composite(torch.autograd.Function):
    """Screen-space Gaussians -> images [C, H, W, D], alphas [C, H, W, 1]; hand-written backward.

    Gradients go to means2d, conics, opacities, colors and background; the projection's
    autograd graph carries them on to means, quats, scales and viewmats.
    """

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, background, plan: _Plan):  # noqa: D401
        p = plan
        c_n = means2d.shape[0]
        d = colors.shape[1]
        arrs = (_np(means2d), _np(conics), _np(opacities), _np(colors), _np(background))
        img = np.empty((c_n, p.height, p.width, d), dtype=arrs[0].dtype)
        t_final = np.empty((c_n, p.height, p.width), dtype=np.float64)
        last = np.empty((c_n, p.height, p.width), dtype=np.int64)
        with numba.parallel_chunksize(_CHUNK):
            K.forward_tiles(*arrs, p.pix_box, p.tile_start, p.gid, p.width, p.height, p.tiles_x, p.tiles_y,
                            img, t_final, last)
        ctx.plan, ctx.arrs, ctx.t_final, ctx.last = plan, arrs, t_final, last
        ctx.dtype = means2d.dtype
        alphas = torch.from_numpy((1.0 - t_final)[..., None]).to(means2d.dtype)
        return torch.from_numpy(img), alphas

    @staticmethod
    def backward(ctx, v_img, v_alphas):
        p, arrs = ctx.plan, ctx.arrs
        means2d, conics, opac, colors, bg = arrs
        c_n, n = means2d.shape[0], means2d.shape[1]
        d = colors.shape[1]
        v_img_np = _np(v_img) if v_img is not None else np.zeros((c_n, p.height, p.width, d), dtype=means2d.dtype)
        v_al_np = (_np(v_alphas[..., 0]) if v_alphas is not None
                   else np.zeros((c_n, p.height, p.width), dtype=means2d.dtype))
        n_isect = p.gid.shape[0]
        geo = np.zeros((n_isect, 6), dtype=np.float64)
        col = np.zeros((n_isect, d), dtype=np.float64)
        with numba.parallel_chunksize(_CHUNK):
            K.backward_tiles(*arrs, p.pix_box, p.tile_start, p.gid, p.width, p.height, p.tiles_x, p.tiles_y,
                             ctx.t_final, ctx.last, v_img_np, v_al_np, geo, col)
        v_m = np.zeros((c_n, n, 2))
        v_c = np.zeros((c_n, n, 3))
        v_o = np.zeros(n)
        v_col = np.zeros((n, d))
        K.reduce_grads(p.tile_start, p.gid, p.tiles_x * p.tiles_y, geo, col, v_m, v_c, v_o, v_col)
        # background: image += T_final * bg
        v_bg = np.einsum("chw,chwd->d", ctx.t_final, v_img_np)
        dt = ctx.dtype
        out = [torch.from_numpy(a).to(dt) for a in (v_m, v_c, v_o, v_col, v_bg)]
        return (*out, None)


def rasterize_numba(
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
) -> tuple[Tensor, Tensor, dict]:
    """Inputs already validated, CPU tensors. See `splat_cpu.rasterize` for the contract."""
    t0 = time.perf_counter()
    proj = project(means, quats, scales, opacities, viewmats, Ks, width, height)
    t1 = time.perf_counter()
    n_cam, n = proj.valid.shape
    key = torch.where(proj.valid, proj.depths, torch.full_like(proj.depths, math.inf))
    order = torch.sort(key, dim=1, stable=True).indices
    n_valid = proj.valid.sum(dim=1)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    pix_box = _np(proj.pix_box)
    tile_start, gid = K.bin_tiles(_np(order), _np(n_valid), pix_box, tiles_x, tiles_y)
    plan = _Plan(pix_box, tile_start, gid, width, height, tiles_x, tiles_y)
    t2 = time.perf_counter()
    bg = background if background is not None else torch.zeros(colors.shape[1], dtype=colors.dtype)
    images, alphas = _Composite.apply(proj.means2d, proj.conics, opacities, colors, bg, plan)
    t3 = time.perf_counter()
    meta = {
        "path": "numba",
        "radii": proj.radii,
        "means2d": proj.means2d,
        "depths": proj.depths,
        "n_visible": n_valid,
        "n_isect": int(gid.shape[0]),
        "timings": {"project_ms": 1e3 * (t1 - t0), "bin_ms": 1e3 * (t2 - t1), "composite_ms": 1e3 * (t3 - t2)},
    }
    return images, alphas, meta
