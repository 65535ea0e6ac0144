"""EWA projection of 3D Gaussians into C pinhole cameras (pure torch, differentiable).

Shared by both compositing paths: gradients to means, quats, scales, opacities and the
camera poses (viewmats) flow through torch autograd from the 2D quantities below.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .constants import ALPHA_MIN, COV2D_BLUR, FRUSTUM_MARGIN, NEAR


@dataclass
class Projected:
    """Per-camera screen-space Gaussians. Invalid (culled) entries hold finite dummies."""

    means2d: Tensor  # [C, N, 2] pixel coordinates of the projected mean
    conics: Tensor  # [C, N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]]
    depths: Tensor  # [C, N] camera-space z of the mean (no gradient)
    radii: Tensor  # [C, N, 2] int32 half-extent in px of the box where alpha >= ALPHA_MIN; 0 if culled
    pix_box: Tensor  # [C, N, 4] int64 (x0, x1, y0, y1) inclusive pixel range in the image
    valid: Tensor  # [C, N] bool: in front of the near plane, on screen, opacity >= ALPHA_MIN


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [N, 4] (w, x, y, z) -> [N, 3, 3]
    """Rotation matrices from (not necessarily unit) quaternions, real part first."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(*quats.shape[:-1], 3, 3)


def covariances3d(quats: Tensor, scales: Tensor) -> Tensor:  # [N, 4], [N, 3] -> [N, 3, 3]
    """Sigma = R S S^T R^T."""
    m = quat_to_rotmat(quats) * scales[:, None, :]
    return m @ m.transpose(-1, -2)


def frustum_limits(Ks: Tensor, width: int, height: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:  # [C, 3, 3]
    """gsplat's limits of x/z and y/z for the projection's Jacobian, each [C, 1]: (x neg, x pos, y neg, y pos).

    The image's extent on each side of the principal point, in units of z, plus FRUSTUM_MARGIN of the half
    field of view (1.3 half fields of view each way for a centred principal point).
    """
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    return (
        cx / fx + FRUSTUM_MARGIN * tan_x,
        (width - cx) / fx + FRUSTUM_MARGIN * tan_x,
        cy / fy + FRUSTUM_MARGIN * tan_y,
        (height - cy) / fy + FRUSTUM_MARGIN * tan_y,
    )


def project(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
) -> Projected:
    """EWA splatting with the Jacobian at the mean, + COV2D_BLUR on the 2D diagonal.

    The Jacobian is gsplat's: x/z and y/z in it are clamped to `frustum_limits` (the mean itself
    is not), so a Gaussian far outside the image does not spread over it.

    Computed in float64 (except on MPS, which has none) and returned in the input dtype, as
    the numba twin does: in float32 the 2D covariance of a Gaussian a few thousand pixels
    wide overflows its determinant.

    Convention: OpenCV camera axes, pixel centres at (i + 0.5, j + 0.5). A Gaussian is
    kept in camera c when z > NEAR, its 2D covariance is positive definite, its opacity is
    at least ALPHA_MIN, and the exact box of pixels where o exp(-sigma) >= ALPHA_MIN
    (half-extent sqrt(2 ln(o / ALPHA_MIN) Sigma_xx), rounded up) meets the image.
    """
    out_dtype = means.dtype
    if means.device.type != "mps":
        means, quats, scales, viewmats, Ks = (x.double() for x in (means, quats, scales, viewmats, Ks))
    rot = viewmats[:, :3, :3]  # [C, 3, 3]
    trans = viewmats[:, :3, 3]  # [C, 3]
    p = torch.einsum("cij,nj->cni", rot, means) + trans[:, None, :]  # [C, N, 3]
    x, y, z = p.unbind(-1)
    valid = z > NEAR
    zs = torch.where(valid, z, torch.ones_like(z))
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # [C, 1]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    xz, yz = x / zs, y / zs
    # Jacobian of (fx x/z + cx, fy y/z + cy) at the mean, rows [C, N, 3], with x/z and y/z clamped to the
    # frustum's limits (gsplat's clamp: beyond them the Jacobian stops growing, and passes no gradient to x, y)
    lim_x_neg, lim_x_pos, lim_y_neg, lim_y_pos = frustum_limits(Ks, width, height)
    xzc = torch.clamp(xz, min=-lim_x_neg, max=lim_x_pos)
    yzc = torch.clamp(yz, min=-lim_y_neg, max=lim_y_pos)
    zero = torch.zeros_like(zs)
    j0 = torch.stack([fx / zs, zero, -fx * xzc / zs], dim=-1)
    j1 = torch.stack([zero, fy / zs, -fy * yzc / zs], dim=-1)
    jac = torch.stack([j0, j1], dim=-2)  # [C, N, 2, 3]
    jw = jac @ rot[:, None]  # [C, N, 2, 3]: J W
    cov3 = covariances3d(quats, scales)  # [N, 3, 3]
    cov2 = jw @ cov3[None] @ jw.transpose(-1, -2)  # [C, N, 2, 2]
    a = cov2[..., 0, 0] + COV2D_BLUR
    b = 0.5 * (cov2[..., 0, 1] + cov2[..., 1, 0])
    c = cov2[..., 1, 1] + COV2D_BLUR
    det = a * c - b * b
    valid = valid & (det > 0) & torch.isfinite(det)
    det_s = torch.where(valid, det, torch.ones_like(det))
    a_s = torch.where(valid, a, torch.ones_like(a))
    b_s = torch.where(valid, b, torch.zeros_like(b))
    c_s = torch.where(valid, c, torch.ones_like(c))
    conics = torch.stack([c_s / det_s, -b_s / det_s, a_s / det_s], dim=-1)
    u = fx * xz + cx
    v = fy * yz + cy
    means2d = torch.stack([torch.where(valid, u, zero), torch.where(valid, v, zero)], dim=-1)

    with torch.no_grad():
        op = opacities.detach().to(torch.float64)[None, :].expand_as(z)
        valid = valid & (op >= ALPHA_MIN)
        extend = torch.sqrt(2.0 * torch.log(torch.clamp(op, min=ALPHA_MIN) / ALPHA_MIN))
        rx = torch.ceil(extend * a_s.detach().double().sqrt())  # float64: no overflow for huge Gaussians
        ry = torch.ceil(extend * c_s.detach().double().sqrt())
        um, vm = means2d[..., 0].detach().double(), means2d[..., 1].detach().double()
        # pixel i is inside when |i + 0.5 - u| <= rx
        x0 = torch.clamp(torch.ceil(um - rx - 0.5), min=0, max=width)
        x1 = torch.clamp(torch.floor(um + rx - 0.5), min=-1, max=width - 1)
        y0 = torch.clamp(torch.ceil(vm - ry - 0.5), min=0, max=height)
        y1 = torch.clamp(torch.floor(vm + ry - 0.5), min=-1, max=height - 1)
        valid = valid & (x0 <= x1) & (y0 <= y1)
        radii = torch.clamp(torch.stack([rx, ry], dim=-1), max=2**31 - 1).to(torch.int32) * valid[..., None]
        pix_box = torch.stack([x0, x1, y0, y1], dim=-1).to(torch.int64)
        pix_box = torch.where(valid[..., None], pix_box, torch.tensor([0, -1, 0, -1], device=pix_box.device))
        depths = torch.where(valid, z.detach(), torch.zeros_like(z)).to(out_dtype)
    return Projected(means2d.to(out_dtype), conics.to(out_dtype), depths, radii, pix_box, valid)


def depth_order(proj: Projected, cam: int) -> Tensor:  # -> [n_valid] int64
    """Indices of camera `cam`'s valid Gaussians, front to back; ties keep index order."""
    idx = torch.nonzero(proj.valid[cam], as_tuple=False).squeeze(1)
    order = torch.sort(proj.depths[cam, idx], stable=True).indices
    return idx[order]
