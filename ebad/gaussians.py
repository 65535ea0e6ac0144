"""The Gaussian scene: parameters, initialisation, activation and rendering.

Parameters live in a plain ``dict[str, nn.Parameter]`` (gsplat's layout) so the
densification strategy can replace them together with their Adam state:

- ``means`` [N, 3] world positions,
- ``scales`` [N, 3] log standard deviations,
- ``quats`` [N, 4] (w, x, y, z), normalised by the rasteriser,
- ``opacities`` [N] logits,
- ``colors`` [N, D] spherical-harmonic DC coefficients: colour = 0.5 + SH_C0 * f_dc, clamped at 0
  (the 3DGS convention, so ``point_cloud.ply`` opens in splat viewers). D = 1 for grey scenes;
- ``sh_rest`` [N, K - 1, D], only when ``model.sh_degree`` > 0: the coefficients of degrees 1..sh_degree
  (K = (sh_degree + 1)^2, INRIA's order), so that colour = max(SH(d) . coeffs + 0.5, 0) for the unit view
  direction d from the camera centre to the mean (``splat_cpu.rasterize``'s ``sh_degree``). They start at 0 and
  learn at ``train.lr_colors / SH_REST_LR_RATIO``. A render at degree 0 (or of a model without them) passes
  ``activate``'s colours to the rasteriser, exactly as a model without view-dependent colour.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

import numpy as np
import torch
from numba import njit
from torch import Tensor, nn

from .lie import viewmat_from_c2w

__all__ = [
    "SH_C0",
    "SH_REST_LR_RATIO",
    "init_params",
    "sh_degree_of",
    "resize_sh",
    "points_from_frames",
    "plane_sweep_points",
    "knn_scale",
    "activate",
    "render",
    "num_gaussians",
    "scene_scale",
    "normalise_quats_",
]

SH_C0 = 0.28209479177387814
SH_REST_LR_RATIO = 20.0  # the higher SH coefficients learn at lr_colors / this (INRIA's feature_lr / 20)
# plane-sweep stereo needs parallax: cameras whose baseline moves a point over the depth range by less
# than this many pixels give every depth plane the same cost, so random depths are used instead
MIN_PARALLAX_PX = 1.0
# plane sweep: this many depth planes are warped in one call per neighbour frame, which torch's threads share (at 30
# views of 346x260, 2 threads, alternating in fresh processes: one plane at a time 11.3-11.7 s, four 8.7-9.2 s, eight
# 8.7-9.1 s; the sweep's peak grew 237, 282 and 331 MB; all 32 at once was no faster and grew 450)
SWEEP_DEPTHS_AT_ONCE = 4

log = logging.getLogger(__name__)


def knn_scale(points: Tensor, k: int = 3) -> Tensor:  # [P, 3] -> [P]
    """Mean distance to the k nearest other points (the 3DGS initial scale), by scipy's cKDTree."""
    from scipy.spatial import cKDTree

    P = points.shape[0]
    if P <= 1:
        return torch.full((P,), 0.01, dtype=points.dtype)
    k = min(k, P - 1)
    pts = points.detach().double().cpu().numpy()
    dist, _ = cKDTree(pts).query(pts, k=k + 1)  # the first neighbour is the point itself
    return torch.from_numpy(dist[:, 1:].mean(-1)).to(points.dtype).clamp_min(1e-7)


def init_params(
    points: Tensor,  # [P, 3]
    colors: Tensor,  # [P, D] linear intensity in [0, 1]
    scales: Tensor | None = None,  # [P] isotropic std, or None: k-NN distance
    opacity: float = 0.3,
) -> dict[str, nn.Parameter]:
    """Gaussians at ``points`` with ``colors``, isotropic, identity rotation."""
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be [P, 3], got {tuple(points.shape)}")
    if colors.ndim != 2 or colors.shape[0] != points.shape[0]:
        raise ValueError(f"colors must be [P, D] with P = {points.shape[0]}, got {tuple(colors.shape)}")
    if not (torch.isfinite(points).all() and torch.isfinite(colors).all()):
        raise ValueError("points and colors must be finite")
    if not 0 < opacity < 1:
        raise ValueError(f"opacity must be in (0, 1), got {opacity}")
    points = points.float()
    P = points.shape[0]
    s = knn_scale(points) if scales is None else scales.float()
    quats = torch.zeros(P, 4)
    quats[:, 0] = 1
    return {
        "means": nn.Parameter(points.clone()),
        "scales": nn.Parameter(torch.log(s)[:, None].repeat(1, 3)),
        "quats": nn.Parameter(quats),
        "opacities": nn.Parameter(torch.full((P,), math.log(opacity / (1 - opacity)))),
        "colors": nn.Parameter((colors.float().clamp(0, 1) - 0.5) / SH_C0),
    }


def points_from_frames(
    frames: np.ndarray,  # [F, H, W, D]
    c2w: np.ndarray,  # [F, 4, 4]
    K: np.ndarray,  # [3, 3]
    n: int,
    depth_range: tuple[float, float],
    scale_px: float = 1.5,
    seed: int = 0,
) -> tuple[Tensor, Tensor, Tensor]:  # points [n, 3], colors [n, D], scales [n]
    """Fallback initialisation without SfM points: back-projected pixels.

    Each point takes a random frame, a random pixel of it and a depth drawn uniformly in
    inverse depth over ``depth_range``; its colour is that pixel's intensity and its size
    ``scale_px`` pixels at that depth. Wrong depths are pruned and re-grown by the
    densification strategy; every line of sight starts covered, which keeps the first
    renders close to the frames.
    """
    near, far = depth_range
    if not 0 < near < far:
        raise ValueError(f"depth_range must satisfy 0 < near < far, got {depth_range}")
    rng = np.random.default_rng(seed)
    F, H, W, D = frames.shape
    f = rng.integers(0, F, n)
    px = rng.uniform(0, W, n)
    py = rng.uniform(0, H, n)
    inv = rng.uniform(1 / far, 1 / near, n)
    z = 1 / inv
    Kinv = np.linalg.inv(K)
    rays = Kinv @ np.stack([px, py, np.ones(n)])  # [3, n] camera space, z = 1
    pc = rays.T * z[:, None]
    R = c2w[f, :3, :3]
    t = c2w[f, :3, 3]
    pw = np.einsum("nij,nj->ni", R, pc) + t
    col = frames[f, np.clip(py.astype(int), 0, H - 1), np.clip(px.astype(int), 0, W - 1)]
    scales = scale_px * z / K[0, 0]
    return (torch.from_numpy(pw).float(), torch.from_numpy(np.asarray(col)).float(), torch.from_numpy(scales).float())


def scene_scale(c2w: np.ndarray, depth_range: tuple[float, float] | None = None) -> float:  # [F, 4, 4]
    """A length for learning rates and size thresholds: the camera spread or the geometric mean of
    the depth range, the larger."""
    centres = c2w[:, :3, 3]
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) * 1.1
    if depth_range is not None:
        spread = max(spread, math.sqrt(float(depth_range[0]) * float(depth_range[1])))
    return max(spread, 1e-3)


def sh_degree_of(params: Mapping[str, Tensor]) -> int:
    """The SH degree a model carries: 0 without ``sh_rest``, else from its K - 1 = (degree + 1)^2 - 1 rows."""
    rest = params.get("sh_rest")
    if rest is None:
        return 0
    degree = math.isqrt(rest.shape[1] + 1) - 1 if rest.ndim == 3 else -1
    if degree < 1 or (degree + 1) ** 2 != rest.shape[1] + 1:
        raise ValueError(f"sh_rest must be [N, (degree + 1)^2 - 1, D], got {tuple(rest.shape)}")
    return degree


def resize_sh(params: dict[str, nn.Parameter], degree: int) -> None:
    """Give ``params`` the SH coefficients of ``degree`` in place: ``sh_rest`` added as zeros, padded with zeros or
    cut to fewer rows; removed at degree 0. The DC ``colors`` are kept as they are."""
    k = (degree + 1) ** 2 - 1
    old = params.get("sh_rest")
    if degree <= 0:
        params.pop("sh_rest", None)
        return
    n, d = params["colors"].shape
    new = torch.zeros(n, k, d, dtype=params["colors"].dtype)
    if old is not None:
        keep = min(k, old.shape[1])
        new[:, :keep] = old.detach()[:, :keep]
    params["sh_rest"] = nn.Parameter(new)


def num_gaussians(params: Mapping[str, Tensor]) -> int:
    return int(params["means"].shape[0])


@njit(cache=True)
def _normalise_rows(q):  # pragma: no cover - jit
    for i in range(q.shape[0]):
        s = 0.0
        for j in range(q.shape[1]):
            s += float(q[i, j]) * float(q[i, j])
        inv = 1.0 / max(math.sqrt(s), 1e-12)
        for j in range(q.shape[1]):
            q[i, j] = q[i, j] * inv


def normalise_quats_(quats: Tensor) -> None:  # [N, 4], in place, no gradient
    """Scale every quaternion to unit norm in place (the norm clamped at 1e-12), as
    ``q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)`` but in one numba pass on a contiguous
    CPU tensor (torch's norm over rows of 4 took 50 us for 6k Gaussians, this a few)."""
    with torch.no_grad():
        if quats.device.type == "cpu" and quats.is_contiguous() and quats.ndim == 2:
            _normalise_rows(quats.detach().numpy())
        else:
            quats.data = quats.data / quats.data.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def activate(params: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The rasteriser's inputs: exp scales, sigmoid opacities, colours from SH DC."""
    return {
        "means": params["means"],
        "quats": params["quats"],
        "scales": torch.exp(params["scales"]),
        "opacities": torch.sigmoid(params["opacities"]),
        "colors": (0.5 + SH_C0 * params["colors"]).clamp_min(0.0),
    }


def render(
    params: Mapping[str, Tensor],
    c2w: Tensor,  # [C, 4, 4]
    K: Tensor,  # [3, 3] or [C, 3, 3]
    width: int,
    height: int,
    background: float = 0.0,
    sh_degree: int | None = None,
) -> tuple[Tensor, Tensor, dict]:  # images [C, H, W, D], alphas [C, H, W, 1], meta
    """Render the Gaussians from C cameras in one batched rasteriser call.

    ``sh_degree``: the spherical-harmonic degree to render with, at most the model's (``sh_degree_of``); None: the
    model's. At degree 0 the colours are ``activate``'s, view-independent (the rasteriser's SH path is not used)."""
    import splat_cpu

    C = c2w.shape[0]
    Ks = K.float().expand(C, 3, 3) if K.ndim == 2 else K.float()
    degree = sh_degree_of(params) if sh_degree is None else min(int(sh_degree), sh_degree_of(params))
    a = activate(params)
    D = a["colors"].shape[1]
    bg = torch.full((D,), float(background))
    viewmats = viewmat_from_c2w(c2w.float())
    colors = a["colors"]
    if degree > 0:  # [N, K, D]: the DC coefficients, then those of degrees 1..degree
        k = (degree + 1) ** 2
        colors = torch.cat([params["colors"][:, None, :], params["sh_rest"][:, : k - 1]], dim=1)
    return splat_cpu.rasterize(
        a["means"],
        a["quats"],
        a["scales"],
        a["opacities"],
        colors,
        viewmats,
        Ks,
        int(width),
        int(height),
        background=bg,
        sh_degree=degree if degree > 0 else None,
    )


def plane_sweep_points(
    frames: np.ndarray,  # [F, H, W, D]
    c2w: np.ndarray,  # [F, 4, 4]
    K: np.ndarray,  # [3, 3]
    n: int,
    depth_range: tuple[float, float],
    n_depths: int = 32,
    neighbours: int = 2,
    patch: int = 5,
    scale_px: float = 1.0,
    seed: int = 0,
) -> tuple[Tensor, Tensor, Tensor]:  # points [n, 3], colors [n, D], scales [n]
    """Initial points from plane-sweep stereo between the posed frames (no SfM needed).

    For every frame and every pixel, ``n_depths`` fronto-parallel planes uniform in inverse
    depth over ``depth_range`` are tried; a depth's cost is the patch-averaged absolute
    difference to the ``neighbours`` nearest frames (by camera centre) warped onto it. Each
    pixel keeps its cheapest depth; pixels are then drawn with probability growing with
    their confidence (mean cost / best cost) and local contrast, and back-projected.
    """
    import torch.nn.functional as tF

    near, far = depth_range
    if not 0 < near < far:
        raise ValueError(f"depth_range must satisfy 0 < near < far, got {depth_range}")
    F, H, W, D = frames.shape
    if F < 2:
        return points_from_frames(frames, c2w, K, n, depth_range, scale_px * 1.5, seed)
    cam = c2w[:, :3, 3]
    baseline = float(np.linalg.norm(cam[:, None] - cam[None], axis=-1).max())
    parallax = float(K[0, 0]) * baseline * (1.0 / near - 1.0 / far)  # pixels, widest pair, over the depth range
    if parallax < MIN_PARALLAX_PX:
        log.warning(
            "plane-sweep initialisation skipped: the cameras do not move (baseline %.3g, %.3g px of parallax over "
            "depths %.3g..%.3g); Gaussians start at random depths in that range (--model.init_depth sets it)",
            baseline,
            parallax,
            near,
            far,
        )
        return points_from_frames(frames, c2w, K, n, depth_range, scale_px * 1.5, seed)
    img = torch.from_numpy(np.ascontiguousarray(frames)).float().permute(0, 3, 1, 2)  # [F, D, H, W]
    c2w_t = torch.from_numpy(c2w).float()
    K_t = torch.from_numpy(K).float()
    Kinv = torch.linalg.inv(K_t)
    depths = 1.0 / torch.linspace(1.0 / near, 1.0 / far, n_depths)
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    rays = Kinv @ torch.stack([xs, ys, torch.ones_like(xs)]).reshape(3, -1)  # [3, HW], z = 1
    centres = c2w_t[:, :3, 3]
    all_pts, all_cols, all_w, all_z = [], [], [], []
    for f in range(F):
        dist = (centres - centres[f]).norm(dim=1)
        dist[f] = float("inf")
        nb = torch.argsort(dist)[: min(neighbours, F - 1)]
        cost_maps = []
        for d0 in range(0, n_depths, SWEEP_DEPTHS_AT_ONCE):  # a few depths at once: one call per neighbour for them
            ds = depths[d0 : d0 + SWEEP_DEPTHS_AT_ONCE]
            pws = [c2w_t[f, :3, :3] @ (rays * d) + c2w_t[f, :3, 3:] for d in ds]  # [3, HW] each
            cost = torch.zeros(len(ds), 1, H, W)
            for g in nb.tolist():
                R, t = c2w_t[g, :3, :3], c2w_t[g, :3, 3:]
                pcs = [R.T @ (pw - t) for pw in pws]
                uvs = [(K_t @ pc)[:2] / pc[2:].clamp_min(1e-6) for pc in pcs]
                grid = torch.stack([torch.stack([uv[0] / W * 2 - 1, uv[1] / H * 2 - 1], -1) for uv in uvs])
                grid = grid.reshape(len(ds), H, W, 2)
                warped = tF.grid_sample(
                    img[g : g + 1].expand(len(ds), -1, -1, -1), grid, align_corners=False, padding_mode="border"
                )
                diff = (warped - img[f : f + 1]).abs().mean(1, keepdim=True)  # [depths, 1, H, W]
                behind = torch.stack([pc[2] <= 0 for pc in pcs]).reshape(len(ds), H, W)
                outside = ((grid.abs() > 1).any(-1) | behind)[:, None]
                cost = cost + torch.where(outside, torch.full_like(diff, 0.25), diff)
            cost_maps.append(tF.avg_pool2d(cost, patch, 1, patch // 2, count_include_pad=False)[:, 0])
        costs = torch.cat(cost_maps)  # [n_depths, H, W]
        best, arg = costs.min(0)
        conf = costs.mean(0) / best.clamp_min(1e-4)
        gy, gx = torch.gradient(img[f].mean(0))
        contrast = gx.abs() + gy.abs()
        z = depths[arg]  # [H, W]
        all_pts.append((c2w_t[f, :3, :3] @ (rays * z.reshape(1, -1)) + c2w_t[f, :3, 3:]).T)
        all_cols.append(img[f].reshape(D, -1).T)
        all_w.append(((conf - 1).clamp_min(0) * (contrast + 0.02)).reshape(-1))
        all_z.append(z.reshape(-1))
    pts, cols, w, zz = torch.cat(all_pts), torch.cat(all_cols), torch.cat(all_w), torch.cat(all_z)
    g = torch.Generator().manual_seed(seed)
    w = w + 1e-6
    idx = torch.multinomial(w / w.sum(), min(n, len(w)), replacement=False, generator=g)
    return pts[idx], cols[idx], scale_px * zz[idx] / float(K[0, 0])
