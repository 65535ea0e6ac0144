"""ebad.kernels.poses (the trajectories' poses in closed form) against ebad.trajectory's torch functions."""

from __future__ import annotations

import pytest
import torch

from ebad.lie import so3_exp
from ebad.trajectory import TRAJECTORIES, ExposureTrajectories, virtual_instants


def _rigid64(n: int, seed: int = 0) -> torch.Tensor:  # [n, 4, 4] float64 poses with rotations orthonormal to float64
    gen = torch.Generator().manual_seed(seed)
    T = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    T[:, :3, :3] = so3_exp(torch.randn(n, 3, generator=gen, dtype=torch.float64))
    T[:, :3, 3] = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    return T


def _reference_poses(kind, mid, knots, u, scale, anchored):
    """The torch composition ``ExposureTrajectories`` evaluated before the closed form."""
    from ebad.lie import rigid_inverse

    model = TRAJECTORIES[kind]
    if not anchored:
        return model.poses(mid, knots, u, scale)
    both = model.poses(mid, knots, torch.cat([u, u.new_tensor([0.5])]), scale)
    return (mid @ rigid_inverse(both[:, -1]))[:, None] @ both[:, :-1]


@pytest.mark.parametrize("kind", ["linear", "cubic", "offset"])
@pytest.mark.parametrize("anchored", [False, True])
@pytest.mark.parametrize("size", [1e-7, 1e-2, 0.6])
def test_closed_form_poses_equal_the_torch_composition_in_value_and_gradient(kind, anchored, size):
    """ebad.kernels.poses against the trajectory functions, float64, from knots at the identity's
    series to rotations of about a radian, under a random upstream gradient."""
    from ebad.kernels.poses import TrajectoryPoses

    gen = torch.Generator().manual_seed(5)
    K = TRAJECTORIES[kind].num_knots
    mid = _rigid64(3)
    knots = (torch.randn(3, K, 6, generator=gen, dtype=torch.float64) * size).requires_grad_()
    u = virtual_instants(5, dtype=torch.float64)
    G = torch.randn(3, 5, 4, 4, generator=gen, dtype=torch.float64)
    ref = _reference_poses(kind, mid, knots, u, 0.7, anchored)
    (g_ref,) = torch.autograd.grad((ref * G).sum(), knots)
    fast = TrajectoryPoses.apply(knots, mid, u, kind, 0.7, anchored)
    (g_fast,) = torch.autograd.grad((fast * G).sum(), knots)
    assert torch.allclose(fast, ref, rtol=0, atol=1e-13)
    assert torch.allclose(g_fast, g_ref, rtol=1e-10, atol=1e-12)


def test_closed_form_poses_gradcheck():
    from ebad.kernels.poses import TrajectoryPoses

    knots = torch.randn(2, 2, 6, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.3
    mid = _rigid64(2)
    u = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    for kind, k in (("linear", knots), ("cubic", torch.cat([knots, -knots], 1)), ("offset", knots[:, :1])):
        assert torch.autograd.gradcheck(
            lambda x, kind=kind: TrajectoryPoses.apply(x, mid, u, kind, 1.3, True), (k.clone().requires_grad_(),)
        )


def test_trajectories_near_pi_take_the_torch_path():
    """A linear trajectory whose start and end differ by nearly pi: the closed form refuses the
    logarithm (NearPi) and the module gives the torch composition's poses and gradients."""
    from ebad.kernels.poses import NearPi, TrajectoryPoses

    mid = _rigid64(1)
    knots = torch.zeros(1, 2, 6, dtype=torch.float64)
    knots[0, 0, :3] = torch.tensor([0.0, 0.0, -1.5])
    knots[0, 1, :3] = torch.tensor([0.0, 0.0, 1.55])  # 3.05 rad apart
    u = virtual_instants(4, dtype=torch.float64)
    with pytest.raises(NearPi):
        TrajectoryPoses.apply(knots, mid, u, "linear", 1.0, False)
    traj = ExposureTrajectories(mid, "linear")
    with torch.no_grad():
        traj.knots.copy_(knots.float())
    traj = traj.double()
    poses = traj(torch.tensor([0]), u)
    ref = _reference_poses("linear", traj.c2w_mid, traj.knots, u, 1.0, False)
    assert torch.equal(poses, ref)  # the same torch operations
    poses.sum().backward()
    assert torch.isfinite(traj.knots.grad).all() and traj.knots.grad.abs().sum() > 0


@pytest.mark.parametrize("kind", ["linear", "cubic", "offset", "fixed"])
@pytest.mark.parametrize("anchored", [False, True])
def test_trajectory_poses_dispatch_the_closed_form_on_the_cpu_and_the_torch_composition_otherwise(kind, anchored):
    # ebad.trajectory.trajectory_poses, the one place that chooses: the closed form's node on CPU
    # tensors (for the kinds it has), the torch composition inside torch_reference(), to the last digit
    from ebad.kernels import torch_reference
    from ebad.trajectory import trajectory_poses

    K = TRAJECTORIES[kind].num_knots
    mid = _rigid64(2)
    knots = torch.randn(2, K, 6, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * 0.2
    u = virtual_instants(5, dtype=torch.float64)
    fast = trajectory_poses(kind, mid, knots.requires_grad_(), u, 0.8, anchored)
    assert (type(fast.grad_fn).__name__ == "TrajectoryPosesBackward") == (kind != "fixed")
    with torch_reference():
        ref = trajectory_poses(kind, mid, knots, u, 0.8, anchored)
    assert torch.equal(ref, _reference_poses(kind, mid, knots, u, 0.8, anchored and K > 0))  # no knots: nothing moves
    assert torch.allclose(fast, ref, rtol=0, atol=1e-13)
