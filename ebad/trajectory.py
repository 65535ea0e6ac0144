"""Camera trajectories over each exposure, as a registry of pure pose functions.

A trajectory model maps per-frame knots ``[F, K, 6]`` (rotation vector ``w`` then translation
``d``, both corrections relative to the frame's mid-exposure pose; ``d`` in units of the scene
scale) and normalised instants ``u`` in [0, 1] (0 = exposure start, 1 = end) to camera-to-world
poses ``[F, V, 4, 4]``:

- ``linear`` (K = 2): start pose T0 = (R_mid exp(w0), t_mid + d0) and end pose T1 likewise;
  rotation R0 exp(u log(R0^T R1)), translation (1 - u) t0 + u t1 (BAD-Gaussians).
- ``cubic`` (K = 4): a uniform cubic B-spline segment through four knots in the tangent
  space at the mid pose: R_mid exp(sum B_i(u) w_i), t_mid + sum B_i(u) d_i.
- ``offset`` (K = 1): one correction (R_mid exp(w), t_mid + d) at every instant: a sharp
  camera whose pose is not trusted (gsplat's ``pose_opt``).
- ``fixed`` (K = 0): the mid pose at every instant (trusted poses, sharp frames).

``ExposureTrajectories`` is the stateful shell (an ``nn.Module`` holding the knots); it evaluates
its poses through ``trajectory_poses``, which adds the anchoring and is the one place that chooses
the path: on the CPU the same poses in closed form with their derivatives (``ebad.kernels.poses``,
one autograd node instead of a few dozen small ones, chosen by ``ebad.kernels.use_kernels``); the
torch functions here are their reference.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .kernels import poses as closed_form
from .kernels import use_kernels
from .lie import compose_pose, rigid_inverse, so3_exp, so3_log

__all__ = [
    "TrajectoryModel",
    "TRAJECTORIES",
    "linear_poses",
    "cubic_poses",
    "offset_poses",
    "fixed_poses",
    "trajectory_poses",
    "ExposureTrajectories",
    "virtual_instants",
]


def virtual_instants(V: int, dtype=torch.float32, device=None) -> Tensor:  # -> [V]
    """V uniform instants in (0, 1): the midpoints of V equal sub-intervals (V = 1 -> 0.5)."""
    if V < 1:
        raise ValueError(f"V must be >= 1, got {V}")
    return (torch.arange(V, dtype=dtype, device=device) + 0.5) / V


def _split(c2w_mid: Tensor):
    return c2w_mid[..., :3, :3], c2w_mid[..., :3, 3]


def linear_poses(
    c2w_mid: Tensor,  # [F, 4, 4]
    knots: Tensor,  # [F, 2, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
) -> Tensor:  # [F, V, 4, 4]
    """Linear SE(3) interpolation between the start and end poses (see module docstring)."""
    R_mid, t_mid = _split(c2w_mid)
    R01 = R_mid[:, None] @ so3_exp(knots[:, :, :3])  # [F, 2, 3, 3]: start and end in one call
    R0, R1 = R01[:, 0], R01[:, 1]
    t0 = t_mid + scale * knots[:, 0, 3:]
    t1 = t_mid + scale * knots[:, 1, 3:]
    rel = so3_log(R0.transpose(-1, -2) @ R1)  # [F, 3]
    uu = u[None, :, None]  # [1, V, 1]
    R = R0[:, None] @ so3_exp(uu * rel[:, None, :])  # [F, V, 3, 3]
    t = (1 - uu) * t0[:, None] + uu * t1[:, None]
    return compose_pose(R, t)


def bspline_weights(u: Tensor) -> Tensor:  # [V] -> [V, 4]
    """Uniform cubic B-spline basis on one segment (weights sum to 1)."""
    u2, u3 = u * u, u * u * u
    return torch.stack(
        [
            (1 - u) ** 3 / 6,
            (3 * u3 - 6 * u2 + 4) / 6,
            (-3 * u3 + 3 * u2 + 3 * u + 1) / 6,
            u3 / 6,
        ],
        -1,
    )


def cubic_poses(
    c2w_mid: Tensor,  # [F, 4, 4]
    knots: Tensor,  # [F, 4, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
) -> Tensor:  # [F, V, 4, 4]
    """Cubic B-spline in the tangent space at the mid pose (see module docstring)."""
    R_mid, t_mid = _split(c2w_mid)
    B = bspline_weights(u).to(knots.dtype)  # [V, 4]
    xi = B @ knots  # [F, V, 6]
    R = R_mid[:, None] @ so3_exp(xi[..., :3])
    t = t_mid[:, None] + scale * xi[..., 3:]
    return compose_pose(R, t)


def offset_poses(
    c2w_mid: Tensor,  # [F, 4, 4]
    knots: Tensor,  # [F, 1, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
) -> Tensor:  # [F, V, 4, 4]
    """One corrected pose at every instant (pose optimisation without motion)."""
    R_mid, t_mid = _split(c2w_mid)
    pose = compose_pose(R_mid @ so3_exp(knots[:, 0, :3]), t_mid + scale * knots[:, 0, 3:])  # [F, 4, 4]
    return pose[:, None].expand(-1, u.shape[0], -1, -1)


def fixed_poses(
    c2w_mid: Tensor,  # [F, 4, 4]
    knots: Tensor,  # [F, 0, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
) -> Tensor:  # [F, V, 4, 4]
    """The mid pose at every instant."""
    return c2w_mid[:, None].expand(-1, u.shape[0], -1, -1)


@dataclass(frozen=True)
class TrajectoryModel:
    """A registered trajectory: its number of knots and its pose function."""

    name: str
    num_knots: int
    poses: Callable[..., Tensor]


TRAJECTORIES: dict[str, TrajectoryModel] = {
    "linear": TrajectoryModel("linear", 2, linear_poses),
    "cubic": TrajectoryModel("cubic", 4, cubic_poses),
    "offset": TrajectoryModel("offset", 1, offset_poses),
    "fixed": TrajectoryModel("fixed", 0, fixed_poses),
}


def trajectory_poses(
    kind: str,
    c2w_mid: Tensor,  # [F, 4, 4]
    knots: Tensor,  # [F, K, 6]
    u: Tensor,  # [V]
    scale: float = 1.0,
    anchored: bool = False,
) -> Tensor:  # [F, V, 4, 4]
    """The poses of the registered trajectory ``kind`` (a key of ``TRAJECTORIES``), anchored or not
    (see ``ExposureTrajectories``): the pose function's, then left-multiplied by
    c2w_mid T(0.5)^-1 when ``anchored``. On CPU tensors the closed form computes them
    (``ebad.kernels.poses``) except near a logarithm of pi, where it refuses and this torch code
    runs (``so3_log`` takes kornia's path there)."""
    model = TRAJECTORIES[kind]
    if closed_form.available(kind) and use_kernels(knots):
        try:
            return closed_form.trajectory_poses(kind, c2w_mid, knots, u, scale, anchored)
        except closed_form.NearPi:
            pass
    if not (anchored and model.num_knots > 0):
        return model.poses(c2w_mid, knots, u, scale)
    both = model.poses(c2w_mid, knots, torch.cat([u, u.new_tensor([0.5])]), scale)  # u and mid-exposure in one call
    poses, at_half = both[:, :-1], both[:, -1]  # [F, V, 4, 4], [F, 4, 4]
    return (c2w_mid @ rigid_inverse(at_half))[:, None] @ poses


class ExposureTrajectories(nn.Module):
    """Per-frame exposure trajectories around fixed mid-exposure poses.

    Args:
        c2w_mid: [F, 4, 4] initial (mid-exposure) camera-to-world poses.
        kind: a key of ``TRAJECTORIES``.
        moving: [F] bool; frames marked False keep their mid pose (sharp frames, V = 1).
        scale: scene scale; translations are learnt in these units.
        init_noise: std of the random initial knots (breaks the zero-motion symmetry).
        anchored: keep every pose at u = 0.5 equal to ``c2w_mid`` (trusted mid-exposure poses):
            the poses are left-multiplied by c2w_mid T(0.5)^-1, so only the motion inside the
            exposure is learnt and the scene cannot drift away from the trusted cameras.
    """

    c2w_mid: Tensor  # registered buffers (nn.Module's __getattr__ types them Tensor | Module)
    moving: Tensor

    def __init__(
        self,
        c2w_mid: Tensor,
        kind: str = "linear",
        moving: Tensor | None = None,
        scale: float = 1.0,
        init_noise: float = 0.0,
        generator: torch.Generator | None = None,
        anchored: bool = False,
    ):
        super().__init__()
        if kind not in TRAJECTORIES:
            raise ValueError(f"unknown trajectory kind '{kind}'; choose one of {sorted(TRAJECTORIES)}")
        if c2w_mid.ndim != 3 or c2w_mid.shape[1:] != (4, 4):
            raise ValueError(f"c2w_mid must be [F, 4, 4], got {tuple(c2w_mid.shape)}")
        F = c2w_mid.shape[0]
        self.kind = kind
        self.model = TRAJECTORIES[kind]
        self.scale = float(scale)
        self.anchored = bool(anchored)
        self.register_buffer("c2w_mid", c2w_mid.detach().clone().float())
        if moving is None:
            moving = torch.ones(F, dtype=torch.bool)
        self.register_buffer("moving", moving.detach().clone().bool())
        K = self.model.num_knots
        noisy = init_noise > 0 and kind != "offset"  # a pose correction starts at zero: no symmetry to break
        knots = torch.randn(F, K, 6, generator=generator) * init_noise if noisy else torch.zeros(F, K, 6)
        if K == 2:  # symmetric start: the mid pose stays where it was
            knots[:, 1] = -knots[:, 0]
        self.knots = nn.Parameter(knots * self.moving[:, None, None])

    @property
    def num_frames(self) -> int:
        return int(self.c2w_mid.shape[0])

    def forward(self, frames: Tensor, u: Tensor) -> Tensor:  # [B] long, [V] -> [B, V, 4, 4]
        """Poses of ``frames`` at normalised instants ``u``."""
        knots = self.knots[frames] * self.moving[frames, None, None]
        mid = self.c2w_mid[frames]
        return trajectory_poses(self.kind, mid, knots, u, self.scale, self.anchored)

    def mid_poses(self) -> Tensor:  # [F, 4, 4]
        """Every frame's pose at mid-exposure (u = 0.5)."""
        idx = torch.arange(self.num_frames)
        with torch.no_grad():
            return self.forward(idx, torch.tensor([0.5]))[:, 0]
