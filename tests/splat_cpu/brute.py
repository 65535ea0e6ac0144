"""A float64 brute-force compositor for the tests: every Gaussian at every pixel.

Written independently of splat_cpu (own projection, own quaternion formula, a plain loop
over depth-sorted Gaussians), following the same rules (gsplat classic mode):
EWA with the Jacobian at the mean (x/z, y/z in it clamped as gsplat does), +0.3 px^2 on the 2D diagonal, z > 0.01,
alpha = min(0.999, o exp(-sigma)), skip sigma < 0 or alpha < 1/255, stop a pixel before the
Gaussian that would bring T to 1e-4 or below, background added as T_final * bg.
"""

from __future__ import annotations

import torch
from torch import Tensor


def _rotmat(q: Tensor) -> Tensor:  # [N, 4] -> [N, 3, 3]
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    r = torch.empty(q.shape[0], 3, 3, dtype=q.dtype)
    rows = [
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ]
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2) if q.shape[0] else r


def brute_render(means, quats, scales, opacities, colors, viewmats, Ks, width, height, background=None):
    """Float64 images [C, H, W, D] and alphas [C, H, W, 1], differentiable by autograd."""
    means, quats, scales, opacities, colors, viewmats, Ks = (
        t.double() for t in (means, quats, scales, opacities, colors, viewmats, Ks)
    )
    bg = None if background is None else background.double()
    n, d = colors.shape
    jj, ii = torch.meshgrid(
        torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64), indexing="ij"
    )
    px, py = ii + 0.5, jj + 0.5
    cov3 = _rotmat(quats) @ torch.diag_embed(scales**2) @ _rotmat(quats).transpose(1, 2) if n else None
    images, alphas = [], []
    for cam in range(viewmats.shape[0]):
        w2c, k = viewmats[cam], Ks[cam]
        img = torch.zeros(height, width, d, dtype=torch.float64)
        T = torch.ones(height, width, dtype=torch.float64)
        done = torch.zeros(height, width, dtype=torch.bool)
        if n:
            pc = means @ w2c[:3, :3].T + w2c[:3, 3]
            order = sorted(range(n), key=lambda i: (float(pc[i, 2].detach()), i))
        else:
            order = []
        for i in order:
            x, y, z = pc[i]
            if not z > 0.01:
                continue
            fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
            # gsplat's frustum clamp: x/z, y/z inside the Jacobian limited to the image plus 0.3 half fields of view
            tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
            xj = z * torch.clamp(x / z, min=-(cx / fx + 0.3 * tan_x), max=(width - cx) / fx + 0.3 * tan_x)
            yj = z * torch.clamp(y / z, min=-(cy / fy + 0.3 * tan_y), max=(height - cy) / fy + 0.3 * tan_y)
            jac = torch.stack(
                [torch.stack([fx / z, 0 * z, -fx * xj / z**2]), torch.stack([0 * z, fy / z, -fy * yj / z**2])]
            )
            cov2 = jac @ w2c[:3, :3] @ cov3[i] @ w2c[:3, :3].T @ jac.T + 0.3 * torch.eye(2, dtype=torch.float64)
            if not torch.linalg.det(cov2) > 0:
                continue
            conic = torch.linalg.inv(cov2)
            u, v = fx * x / z + cx, fy * y / z + cy
            dx, dy = u - px, v - py
            sigma = 0.5 * (conic[0, 0] * dx * dx + conic[1, 1] * dy * dy) + conic[0, 1] * dx * dy
            alpha = torch.clamp(opacities[i] * torch.exp(-sigma), max=0.999)
            use = (sigma >= 0) & (alpha >= 1.0 / 255.0) & ~done
            nxt = T * (1 - alpha)
            stop = use & (nxt <= 1e-4)
            done = done | stop
            use = use & ~stop
            a = torch.where(use, alpha, torch.zeros_like(alpha))
            img = img + (a * T)[..., None] * colors[i]
            T = torch.where(use, nxt, T)
        if bg is not None:
            img = img + T[..., None] * bg
        images.append(img)
        alphas.append((1 - T)[..., None])
    return torch.stack(images), torch.stack(alphas)
