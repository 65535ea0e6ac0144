"""The fast CPU path: numba projection and numba tile compositing, each with a hand-written backward.

Threads (issue 8). torch loads its libgomp into the process's global symbol scope, so numba's
"omp" threading layer runs on that same OpenMP runtime, whose threads spin-wait after every
parallel region unless OMP_WAIT_POLICY=PASSIVE was set before torch started; on a machine
with more busy threads than cores every spin steals a core (serial work between two kernels
took several times longer). So that the library does not depend on the caller's environment, the
layer is chosen before the first parallel kernel (``_omp.choose_threading_layer``, called by
``ebad.threads.configure`` or else by the first ``rasterize_numba``), unless the user chose
one (NUMBA_THREADING_LAYER or numba.config.THREADING_LAYER): "omp" when OMP_WAIT_POLICY=PASSIVE
was in force when torch loaded (idle threads sleep), numba's own "workqueue" otherwise. The
omp layer is preferred where it is
safe because it wakes its threads sooner: after a few milliseconds of single-threaded work,
as between the kernels of a training step, a workqueue region ran at about serial speed, and
a half-resolution ebad step was clearly faster on omp (docs/results.md, "Figures quoted in the
code").
torch only carries tensors in and out (conversions by numpy), so no torch parallel region
runs inside `rasterize` or its backward. Measured by `python -m benchmarks.rasterize --omp-check`.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from torch import Tensor

from . import _numba_kernels as K
from . import _numba_project as P
from . import _numba_sh as S
from ._omp import choose_threading_layer
from .constants import TILE

# The compositing kernels' prange over tiles is split statically, one contiguous run of tiles per thread in image order:
# numba.parallel_chunksize does not change that on the omp layer (a prange of 64 with chunks of 2, the first half
# 200,000x costlier, ran its first 32 on thread 0), and balancing the runs by cost did not pay (docs/results.md).


class _Plan:
    """Per-call binning: which Gaussians touch which tile, front to back (no gradients)."""

    def __init__(self, binned: tuple, order: np.ndarray, width: int, height: int, tiles_x: int, tiles_y: int):
        # K.bin_tiles_indexed's outputs; order, cam_start, box_start and ent locate each Gaussian's entries
        self.tile_start, self.gid, self.rows, self.cam_start, self.box_start, self.ent = binned
        self.order = order
        self.width, self.height, self.tiles_x, self.tiles_y = width, height, tiles_x, tiles_y


def _np(x: Tensor) -> np.ndarray:
    return np.ascontiguousarray(x.detach().cpu().numpy())


_NP_DTYPE = {torch.float32: np.float32, torch.float64: np.float64}


def _tensor(a: np.ndarray, dtype: torch.dtype) -> Tensor:
    """numpy -> torch in `dtype`, converted by numpy: no torch kernel (and no OpenMP region) runs."""
    return torch.from_numpy(np.ascontiguousarray(a, dtype=_NP_DTYPE[dtype]))


class _Project(torch.autograd.Function):
    """(means, quats, scales, viewmats) -> means2d [C, N, 2], conics [C, N, 3]; hand-written backward.

    The outputs without gradient go into the dict `out`: depths [C, N] and radii [C, N, 2]
    int32 as tensors, the inclusive pixel boxes [C, N, 4] int64 and the validity mask [C, N]
    as numpy arrays. Opacities only decide validity here (no gradient through this step).
    The backward adds its time to the dict `timings` (key "backward_project_ms").
    """

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, viewmats, ks, width: int, height: int, out: dict, timings: dict):
        n, n_cam = means.shape[0], viewmats.shape[0]
        arrs = (_np(means), _np(quats), _np(scales), _np(opacities), _np(viewmats), _np(ks))
        means2d = np.empty((n_cam, n, 2))
        conics = np.empty((n_cam, n, 3))
        depths = np.empty((n_cam, n))
        radii = np.empty((n_cam, n, 2), dtype=np.int32)
        box = np.empty((n_cam, n, 4), dtype=np.int64)
        valid = np.empty((n_cam, n), dtype=np.bool_)
        P.project_forward(*arrs, width, height, means2d, conics, depths, radii, box, valid)
        ctx.arrs, ctx.conics, ctx.valid, ctx.timings = arrs, conics, valid, timings
        ctx.width, ctx.height = width, height
        dt = means.dtype
        out.update(depths=_tensor(depths, dt), radii=torch.from_numpy(radii), pix_box=box, valid=valid)
        return _tensor(means2d, dt), _tensor(conics, dt)

    @staticmethod
    def backward(ctx, v_means2d, v_conics):
        t0 = time.perf_counter()
        means, quats, scales, _, viewmats, ks = ctx.arrs
        n, n_cam = means.shape[0], viewmats.shape[0]
        zeros = lambda *shape: np.zeros(shape)  # noqa: E731
        v_m2 = _np(v_means2d).astype(np.float64) if v_means2d is not None else zeros(n_cam, n, 2)
        v_co = _np(v_conics).astype(np.float64) if v_conics is not None else zeros(n_cam, n, 3)
        v_means, v_quats, v_scales = np.empty((n, 3)), np.empty((n, 4)), np.empty((n, 3))
        v_view = np.empty((_PROJECT_CHUNKS, n_cam, 3, 4))
        P.project_backward(
            means,
            quats,
            scales,
            viewmats,
            ks,
            ctx.width,
            ctx.height,
            ctx.valid,
            ctx.conics,
            v_m2,
            v_co,
            v_means,
            v_quats,
            v_scales,
            v_view,
        )
        v_vm = np.zeros((n_cam, 4, 4))
        v_vm[:, :3, :] = v_view.sum(axis=0)
        dt = v_means2d.dtype if v_means2d is not None else v_conics.dtype
        out = [_tensor(a, dt) for a in (v_means, v_quats, v_scales, v_vm)]
        ctx.timings["backward_project_ms"] = 1e3 * (time.perf_counter() - t0)
        return out[0], out[1], out[2], None, out[3], None, None, None, None, None


_PROJECT_CHUNKS = 16  # per-chunk partial sums of the pose gradient (deterministic, no atomics)


class _SHColors(torch.autograd.Function):
    """(means [N, 3], SH coefficients [N, K, D], viewmats [C, 4, 4]) -> colours [C, N, D] (`_sh.sh_colors`).

    The camera centres -R^-1 t and R^-1 come from numpy (C tiny 3 x 3 inverses); the kernels are `_numba_sh`.
    The backward adds its time to the dict `timings` (key "backward_sh_ms")."""

    @staticmethod
    def forward(ctx, means, coeffs, viewmats, degree: int, timings: dict):
        vm = _np(viewmats).astype(np.float64)
        rinv = np.linalg.inv(vm[:, :3, :3])  # [C, 3, 3]
        campos = np.ascontiguousarray(-np.einsum("cij,cj->ci", rinv, vm[:, :3, 3]))
        arrs = (_np(means), _np(coeffs))
        out = np.empty((vm.shape[0], coeffs.shape[0], coeffs.shape[2]), dtype=arrs[1].dtype)
        S.sh_forward(arrs[0], arrs[1], campos, degree, out)
        ctx.arrs, ctx.rinv, ctx.campos, ctx.degree, ctx.timings = arrs, rinv, campos, degree, timings
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, v_colors):
        t0 = time.perf_counter()
        means, coeffs = ctx.arrs
        n, n_cam = means.shape[0], ctx.campos.shape[0]
        v_means = np.empty((n, 3))
        v_coeffs = np.zeros(coeffs.shape)
        v_campos = np.empty((max(min(n, S.CHUNKS), 1), n_cam, 3))
        v_campos[:] = 0.0
        S.sh_backward(means, coeffs, ctx.campos, ctx.degree, _np(v_colors), v_means, v_coeffs, v_campos)
        # campos = -A t, A = R^-1: v_t = -A^T v_c, v_R = -(A^T v_c) campos^T
        w = np.einsum("cji,cj->ci", ctx.rinv, v_campos.sum(axis=0))
        v_vm = np.zeros((n_cam, 4, 4))
        v_vm[:, :3, 3] = -w
        v_vm[:, :3, :3] = -w[:, :, None] * ctx.campos[:, None, :]
        dt = v_colors.dtype
        ctx.timings["backward_sh_ms"] = 1e3 * (time.perf_counter() - t0)
        return _tensor(v_means, dt), _tensor(v_coeffs, dt), _tensor(v_vm, dt), None, None


class _Composite(torch.autograd.Function):
    """Screen-space Gaussians -> images [C, H, W, D], alphas [C, H, W, 1]; hand-written backward.

    Colours are [N, D] (shared by the cameras) or [C, N, D] (per camera: view-dependent colours).
    Gradients go to means2d, conics, opacities, colors and background; the projection's
    autograd graph carries them on to means, quats, scales and viewmats. The backward adds its
    time to the dict `timings` (key "backward_composite_ms").
    """

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, background, plan: _Plan, timings: dict):  # noqa: D401
        p = plan
        c_n = means2d.shape[0]
        d = colors.shape[-1]
        col = _np(colors)
        arrs = (_np(means2d), _np(conics), _np(opacities), col[None] if col.ndim == 2 else col, _np(background))
        img = np.empty((c_n, p.height, p.width, d), dtype=arrs[0].dtype)
        t_final = np.empty((c_n, p.height, p.width), dtype=arrs[0].dtype)
        last = np.empty((c_n, p.height, p.width), dtype=np.int32)
        K.forward_tiles(*arrs, p.rows, p.tile_start, p.gid, p.width, p.height, p.tiles_x, p.tiles_y, img, t_final, last)
        ctx.plan, ctx.arrs, ctx.t_final, ctx.last = plan, arrs, t_final, last
        ctx.dtype, ctx.timings, ctx.shared = means2d.dtype, timings, colors.ndim == 2
        alphas = torch.from_numpy((1.0 - t_final)[..., None])
        return torch.from_numpy(img), alphas

    @staticmethod
    def backward(ctx, v_img, v_alphas):
        t0 = time.perf_counter()
        p, arrs = ctx.plan, ctx.arrs
        means2d, conics, opac, colors, bg = arrs
        c_n, n = means2d.shape[0], means2d.shape[1]
        d = colors.shape[2]
        v_img_np = _np(v_img) if v_img is not None else np.zeros((c_n, p.height, p.width, d), dtype=means2d.dtype)
        v_al_np = (
            _np(v_alphas[..., 0]) if v_alphas is not None else np.zeros((c_n, p.height, p.width), dtype=means2d.dtype)
        )
        n_isect = p.gid.shape[0]
        geo = np.empty((n_isect, 6), dtype=means2d.dtype)  # every row written by backward_tiles
        col = np.empty((n_isect, d), dtype=means2d.dtype)
        K.backward_tiles(
            *arrs,
            p.rows,
            p.tile_start,
            p.gid,
            p.width,
            p.height,
            p.tiles_x,
            p.tiles_y,
            ctx.t_final,
            ctx.last,
            v_img_np,
            v_al_np,
            geo,
            col,
        )
        v_m = np.zeros((c_n, n, 2))
        v_c = np.zeros((c_n, n, 3))
        v_o = np.zeros((c_n, n))
        v_col = np.zeros((c_n, n, d))
        K.reduce_grads(p.order, p.cam_start, p.box_start, p.ent, geo, col, v_m, v_c, v_o, v_col)
        v_o = v_o.sum(axis=0)
        if ctx.shared:  # colours shared by the cameras: their gradient is the sum over the cameras
            v_col = v_col.sum(axis=0)
        # background: image += T_final * bg
        v_bg = np.einsum("chw,chwd->d", ctx.t_final, v_img_np, dtype=np.float64)
        dt = ctx.dtype
        out = [_tensor(a, dt) for a in (v_m, v_c, v_o, v_col, v_bg)]
        ctx.timings["backward_composite_ms"] = 1e3 * (time.perf_counter() - t0)
        return (*out, None, None)


def _depth_order(depths: np.ndarray, valid: np.ndarray) -> np.ndarray:  # [C, N], [C, N] -> [C, N] int64
    """Per camera, the Gaussians front to back, the valid ones first, ties in index order (a stable argsort).

    float32 depths (positive: z > NEAR) sort as their bit patterns: one unstable sort of (bits << 32 | index),
    unique keys, gives the stable order several times faster than a stable argsort (+inf, the invalid ones, last)."""
    key = np.where(valid, depths, np.inf).astype(depths.dtype, copy=False)
    if key.dtype != np.float32:
        return np.argsort(key, axis=1, kind="stable")
    packed = (key.view(np.uint32).astype(np.uint64) << np.uint64(32)) | np.arange(key.shape[1], dtype=np.uint64)
    packed.sort(axis=1)
    return (packed & np.uint64(0xFFFFFFFF)).astype(np.int64)


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
    sh_degree: int | None = None,
) -> tuple[Tensor, Tensor, dict]:
    """Inputs already validated, CPU tensors. See `splat_cpu.rasterize` for the contract."""
    choose_threading_layer()  # before the first parallel kernel, unless a set-up chose already (splat_cpu._omp)
    t0 = time.perf_counter()
    pr: dict = {}
    timings: dict = {}  # the forward's stages now, the backward's when it runs
    if sh_degree is not None:  # view-dependent colours [C, N, D] from the SH coefficients [N, K, D]
        colors = _SHColors.apply(means, colors, viewmats, sh_degree, timings)
    tsh = time.perf_counter()
    means2d, conics = _Project.apply(means, quats, scales, opacities, viewmats, Ks, width, height, pr, timings)
    t1 = time.perf_counter()
    valid = pr["valid"]
    order = _depth_order(pr["depths"].numpy(), valid)
    n_valid = valid.sum(axis=1)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    binned = K.bin_tiles_indexed(
        order, n_valid, pr["pix_box"], _np(means2d), _np(conics), _np(opacities), width, height, tiles_x, tiles_y
    )
    plan = _Plan(binned, order, width, height, tiles_x, tiles_y)
    t2 = time.perf_counter()
    bg = background if background is not None else torch.zeros(colors.shape[-1], dtype=colors.dtype)
    images, alphas = _Composite.apply(means2d, conics, opacities, colors, bg, plan, timings)
    t3 = time.perf_counter()
    meta = {
        "path": "numba",
        "radii": pr["radii"],
        "means2d": means2d,
        "depths": pr["depths"],
        "n_visible": torch.from_numpy(n_valid),
        "n_isect": int(plan.gid.shape[0]),
        "timings": timings,
    }
    timings.update(
        sh_ms=1e3 * (tsh - t0), project_ms=1e3 * (t1 - tsh), bin_ms=1e3 * (t2 - t1), composite_ms=1e3 * (t3 - t2)
    )
    return images, alphas, meta
