"""so(3)/SE(3) helpers for the trajectories and the renderer, on kornia's Lie groups and torch.

Convention: rotation vectors ``w`` [..., 3] in radians (axis x angle); quaternions (w, x, y, z),
real part first; poses are 4x4 homogeneous matrices. kornia (``kornia.geometry.liegroup.So3``,
``kornia.geometry.conversions``) does the quaternions and the logarithm near pi; the exponential
is torch's ``matrix_exp`` of the skew matrix (see ``so3_exp``), the logarithm a closed form
elsewhere (see ``so3_log``). All have finite gradients at the
identity; these wrappers only fix the shapes ebad uses ([..., 3] and [..., 3, 3] with any
leading dimensions).
"""

from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix
from kornia.geometry.liegroup import So3
from torch import Tensor

__all__ = ["so3_exp", "so3_log", "compose_pose", "rigid_inverse", "viewmat_from_c2w", "quat_to_rotmat"]


_GENERATORS = torch.tensor(
    [  # [3, 9]: w -> the skew matrix [w]x, row-major
        [0, 0, 0, 0, 0, -1, 0, 1, 0],
        [0, 0, 1, 0, 0, 0, -1, 0, 0],
        [0, -1, 0, 1, 0, 0, 0, 0, 0],
    ],
    dtype=torch.float64,
)


def so3_exp(w: Tensor) -> Tensor:  # [..., 3] -> [..., 3, 3]
    """Rotation matrices from rotation vectors: ``torch.linalg.matrix_exp`` of the skew matrix
    [w]x. The same map as kornia's ``So3.exp`` in two operations, where that one takes over a
    hundred small ones (through quaternions), which made most of a training step's trajectory
    cost."""
    lead = w.shape[:-1]
    skew = w.reshape(-1, 3) @ _GENERATORS.to(w.dtype)
    return torch.linalg.matrix_exp(skew.reshape(-1, 3, 3)).reshape(*lead, 3, 3)


_NEAR_PI_COS = -0.9  # below this cos(angle) (angles above 2.69 rad) so3_log takes kornia's path


def so3_log(R: Tensor) -> Tensor:  # [..., 3, 3] -> [..., 3]
    """Rotation vectors of rotation matrices, angles below pi.

    In closed form: with v = vee(R - R^T) / 2 = sin(angle) axis and cos(angle) = (tr R - 1) / 2,
    w = v angle / sin(angle), the angle from atan2 (no arccos, whose slope is infinite at the
    identity) and angle / sin(angle) from its series where sin(angle)^2 is below the dtype's
    epsilon, so that values and gradients stay finite at the identity. About fifteen
    operations, where kornia's ``So3.log`` (through quaternions) takes over a hundred. Near pi,
    where v loses its digits,
    the rotations take kornia's path."""
    lead = R.shape[:-2]
    M = R.reshape(-1, 3, 3)
    v = 0.5 * torch.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], -1)
    c = 0.5 * (M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1)
    s2 = (v * v).sum(-1)
    small = s2 < torch.finfo(M.dtype).eps
    s = torch.sqrt(torch.where(small, torch.ones_like(s2), s2))
    factor = torch.where(small, 1 + s2 / 6, torch.atan2(s, c) / s)  # angle / sin(angle)
    w = v * factor[:, None]
    near_pi = c < _NEAR_PI_COS
    if bool(near_pi.any()):
        w = torch.where(near_pi[:, None], So3.from_matrix(M).log(), w)
    return w.reshape(*lead, 3)


_BOTTOM_ROW = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)


def compose_pose(R: Tensor, t: Tensor) -> Tensor:  # [..., 3, 3], [..., 3] -> [..., 4, 4]
    """4x4 homogeneous matrices from rotations and translations."""
    top = torch.cat([R, t[..., None]], -1)
    bottom = _BOTTOM_ROW.to(top.dtype).expand(*top.shape[:-2], 1, 4)
    return torch.cat([top, bottom], -2)


def rigid_inverse(T: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """Inverse of rigid transforms, differentiable (R^T, -R^T t); on the CPU one autograd node
    (``_RigidInverse``: about 25 against 78 us forward and backward for six poses, as eight torch
    operations and their backward took)."""
    if T.device.type == "cpu" and T.dtype in (torch.float32, torch.float64):
        return _RigidInverse.apply(T)
    return _rigid_inverse_torch(T)


def _rigid_inverse_torch(T: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """``rigid_inverse`` in torch operations (its reference, and the path off the CPU)."""
    Rt = T[..., :3, :3].transpose(-1, -2)
    return compose_pose(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


class _RigidInverse(torch.autograd.Function):
    """(R, t) -> (R^T, -R^T t) on [..., 4, 4] in numpy; the backward: dR = G_RR^T - t G_t^T,
    dt = -R G_t (G_RR, G_t: the upstream gradient's rotation block and translation column)."""

    @staticmethod
    def forward(ctx, T: Tensor) -> Tensor:
        A = T.detach().numpy()
        R, t = A[..., :3, :3], A[..., :3, 3]
        out = np.zeros(A.shape, A.dtype)
        out[..., :3, :3] = R.swapaxes(-1, -2)
        out[..., :3, 3] = -(R.swapaxes(-1, -2) @ t[..., None])[..., 0]
        out[..., 3, 3] = 1
        ctx.A = A
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:
        A = ctx.A
        G = grad.detach().numpy()
        R, t, Gt = A[..., :3, :3], A[..., :3, 3], G[..., :3, 3]
        out = np.zeros(A.shape, A.dtype)
        out[..., :3, :3] = G[..., :3, :3].swapaxes(-1, -2) - t[..., :, None] * Gt[..., None, :]
        out[..., :3, 3] = -(R @ Gt[..., None])[..., 0]
        return torch.from_numpy(out)


def viewmat_from_c2w(c2w: Tensor) -> Tensor:  # [..., 4, 4] -> [..., 4, 4]
    """World-to-camera matrices from camera-to-world ones."""
    return rigid_inverse(c2w)


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [..., 4] (w, x, y, z) -> [..., 3, 3]
    """Rotation matrices from (not necessarily unit) quaternions, real part first."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return quaternion_to_rotation_matrix(q)
