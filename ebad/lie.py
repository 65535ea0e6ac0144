"""Small so(3)/SE(3) helpers in torch, differentiable and stable at the identity.

Convention: rotation vectors ``w`` [..., 3] in radians (axis x angle); ``exp``/``log`` map
between them and rotation matrices [..., 3, 3]. Angles are expected below pi (camera motion
inside one exposure); near pi the log loses accuracy.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["hat", "so3_exp", "so3_log", "compose_pose", "viewmat_from_c2w", "quat_to_rotmat"]

_SMALL = 1e-8


def hat(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3]
    """Skew-symmetric matrix of ``w`` [..., 3]."""
    z = torch.zeros_like(w[..., 0])
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    return torch.stack([
        torch.stack([z, -wz, wy], -1),
        torch.stack([wz, z, -wx], -1),
        torch.stack([-wy, wx, z], -1),
    ], -2)


def so3_exp(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3]
    """Rodrigues' formula; Taylor series below 1e-4 rad so gradients stay finite at 0."""
    th2 = (w * w).sum(-1, keepdim=True)[..., None]  # [..., 1, 1]
    small = th2 < _SMALL
    th2s = torch.where(small, torch.ones_like(th2), th2)
    th = th2s.sqrt()
    a = torch.where(small, 1 - th2 / 6 + th2 * th2 / 120, torch.sin(th) / th)
    b = torch.where(small, 0.5 - th2 / 24 + th2 * th2 / 720, (1 - torch.cos(th)) / th2s)
    K = hat(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def so3_log(R: Tensor) -> Tensor:  # [..., 3, 3] -> [..., 3]
    """Inverse of ``so3_exp`` for angles below pi; exact gradient at the identity."""
    v = 0.5 * torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                           R[..., 1, 0] - R[..., 0, 1]], -1)  # sin(theta) * axis
    cos = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1)
    s2 = (v * v).sum(-1)
    small = s2 < _SMALL
    s = torch.where(small, torch.ones_like(s2), s2).sqrt()
    th = torch.atan2(s, cos)
    factor = torch.where(small, 1 + s2 / 6, th / s)
    return v * factor[..., None]


def compose_pose(R: Tensor, t: Tensor) -> Tensor:  # [..., 3, 3], [..., 3] -> [..., 4, 4]
    """4x4 homogeneous matrices from rotations and translations."""
    top = torch.cat([R, t[..., None]], -1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1
    return torch.cat([top, bottom], -2)


def viewmat_from_c2w(c2w: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """World-to-camera matrices from camera-to-world ones (rigid inverse, differentiable)."""
    R = c2w[..., :3, :3]
    t = c2w[..., :3, 3]
    Rt = R.transpose(-1, -2)
    return compose_pose(Rt, -(Rt @ t[..., None])[..., 0])


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [N, 4] (w, x, y, z) -> [N, 3, 3]
    """Rotation matrices from (not necessarily unit) quaternions, real part first."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(*quats.shape[:-1], 3, 3)
