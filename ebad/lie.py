"""so(3)/SE(3) helpers for the trajectories and the renderer, on kornia's Lie groups.

Convention: rotation vectors ``w`` [..., 3] in radians (axis x angle); quaternions (w, x, y, z),
real part first; poses are 4x4 homogeneous matrices. kornia (``kornia.geometry.liegroup.So3``,
``kornia.geometry.conversions``) does the maths, with finite gradients at the identity; these
wrappers only fix the shapes ebad uses ([..., 3] and [..., 3, 3] with any leading dimensions).
"""
from __future__ import annotations

import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix
from kornia.geometry.liegroup import So3
from torch import Tensor

__all__ = ["so3_exp", "so3_log", "compose_pose", "rigid_inverse", "viewmat_from_c2w", "quat_to_rotmat"]


def so3_exp(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3]
    """Rotation matrices from rotation vectors (kornia's ``So3.exp``)."""
    lead = w.shape[:-1]
    return So3.exp(w.reshape(-1, 3)).matrix().reshape(*lead, 3, 3)


def so3_log(R: Tensor) -> Tensor:  # [..., 3, 3] -> [..., 3]
    """Rotation vectors of rotation matrices, angles below pi (kornia's ``So3.log``)."""
    lead = R.shape[:-2]
    return So3.from_matrix(R.reshape(-1, 3, 3)).log().reshape(*lead, 3)


def compose_pose(R: Tensor, t: Tensor) -> Tensor:  # [..., 3, 3], [..., 3] -> [..., 4, 4]
    """4x4 homogeneous matrices from rotations and translations."""
    top = torch.cat([R, t[..., None]], -1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1
    return torch.cat([top, bottom], -2)


def rigid_inverse(T: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """Inverse of rigid transforms, differentiable (R^T, -R^T t)."""
    Rt = T[..., :3, :3].transpose(-1, -2)
    return compose_pose(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


def viewmat_from_c2w(c2w: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """World-to-camera matrices from camera-to-world ones."""
    return rigid_inverse(c2w)


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [..., 4] (w, x, y, z) -> [..., 3, 3]
    """Rotation matrices from (not necessarily unit) quaternions, real part first."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return quaternion_to_rotation_matrix(q)
