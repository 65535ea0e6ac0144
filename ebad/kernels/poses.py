"""The exposure trajectories' poses from the closed-form kernel (``_numba_poses``), as one autograd node.

``trajectory_poses`` is what ``ebad.trajectory.trajectory_poses`` dispatches to for the kinds in
``KINDS``; the torch functions of ``ebad.trajectory`` are the reference it is tested against.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ._numba_poses import _KIND_ID, KINDS, NEAR_PI_COS, _poses

__all__ = ["KINDS", "NEAR_PI_COS", "NearPi", "TrajectoryPoses", "available", "poses_with_tangents", "trajectory_poses"]


class NearPi(ValueError):
    """A rotation whose logarithm is wanted is within ``NEAR_PI_COS`` of pi."""


def available(kind: str) -> bool:
    """Whether ``poses_with_tangents`` has the kind (``fixed`` needs no derivative at all)."""
    return kind in KINDS


def poses_with_tangents(
    kind: str, c2w_mid: np.ndarray, knots: np.ndarray, u: np.ndarray, scale: float, anchored: bool
) -> tuple[np.ndarray, np.ndarray]:
    """c2w [B, V, 4, 4] of a trajectory kind with knots (``ebad.trajectory``'s ``linear``, ``cubic``,
    ``offset`` on c2w_mid [B, 4, 4], knots [B, K, 6], u [V]), anchored or not, and its tangents
    along every knot coordinate: dC [B, P, V, 3, 4] (the top three rows), P = K x 6 in the knots'
    [K, 6] order. float64 throughout; raises ``NearPi`` (see ``_numba_poses``)."""
    B, K, _ = knots.shape
    V = len(u)
    c2w = np.empty((B, V, 4, 4))
    dC = np.empty((B, 6 * K, V, 3, 4))
    if not _poses(
        _KIND_ID[kind],
        np.ascontiguousarray(c2w_mid, np.float64),
        np.ascontiguousarray(knots, np.float64),
        np.ascontiguousarray(u, np.float64),
        float(scale),
        bool(anchored),
        c2w,
        dC,
    ):
        raise NearPi("a rotation whose logarithm a linear trajectory needs is near pi")
    return c2w, dC


class TrajectoryPoses(torch.autograd.Function):
    """c2w [B, V, 4, 4] from knots [B, K, 6] (``poses_with_tangents``), the gradient of the knots
    by one contraction of the tangents with the upstream gradient."""

    @staticmethod
    def forward(ctx, knots: Tensor, c2w_mid: Tensor, u: Tensor, kind: str, scale: float, anchored: bool) -> Tensor:
        c2w, dC = poses_with_tangents(
            kind, c2w_mid.detach().numpy(), knots.detach().numpy(), u.detach().numpy(), scale, anchored
        )
        ctx.dC, ctx.knot_shape = dC, knots.shape
        return torch.from_numpy(c2w).to(knots.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):  # [B, V, 4, 4]
        G = grad.detach().numpy()[..., :3, :].astype(np.float64)
        gk = np.einsum("bpvij,bvij->bp", ctx.dC, G).reshape(ctx.knot_shape)
        return torch.from_numpy(gk).to(grad.dtype), None, None, None, None, None


def trajectory_poses(
    kind: str,
    c2w_mid: Tensor,  # [B, 4, 4]
    knots: Tensor,  # [B, K, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
    anchored: bool = False,
) -> Tensor:  # [B, V, 4, 4]
    """``ebad.trajectory.trajectory_poses`` in closed form, one autograd node (gradients to the
    knots); raises ``NearPi`` where a logarithm is near pi (the caller then takes the torch path)."""
    return TrajectoryPoses.apply(knots, c2w_mid, u, kind, scale, anchored)
