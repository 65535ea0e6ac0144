"""ebad.trajectory: trajectory models and the module."""
from __future__ import annotations

import pytest
import torch

from ebad.lie import so3_exp, so3_log
from ebad.trajectory import TRAJECTORIES, ExposureTrajectories, bspline_weights, virtual_instants
from tests.ebad._helpers import random_c2w



def test_linear_trajectory_endpoints_and_midpoint():
    c2w = random_c2w(3).double()
    knots = torch.randn(3, 2, 6, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 0.1
    poses = TRAJECTORIES["linear"].poses(c2w, knots, torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64), 2.0)
    R0 = c2w[:, :3, :3] @ so3_exp(knots[:, 0, :3])
    R1 = c2w[:, :3, :3] @ so3_exp(knots[:, 1, :3])
    assert torch.allclose(poses[:, 0, :3, :3], R0, atol=1e-10)
    assert torch.allclose(poses[:, 2, :3, :3], R1, atol=1e-10)
    assert torch.allclose(poses[:, 0, :3, 3], c2w[:, :3, 3] + 2.0 * knots[:, 0, 3:], atol=1e-10)
    assert torch.allclose(poses[:, 2, :3, 3], c2w[:, :3, 3] + 2.0 * knots[:, 1, 3:], atol=1e-10)
    # the middle is the geodesic midpoint: equal rotation angle to both ends
    a = so3_log(R0.transpose(-1, -2) @ poses[:, 1, :3, :3]).norm(dim=-1)
    b = so3_log(poses[:, 1, :3, :3].transpose(-1, -2) @ R1).norm(dim=-1)
    assert torch.allclose(a, b, atol=1e-9)


def test_cubic_and_fixed_trajectories():
    B = bspline_weights(torch.linspace(0, 1, 7, dtype=torch.float64))
    assert torch.allclose(B.sum(-1), torch.ones(7, dtype=torch.float64))
    c2w = random_c2w(2).double()
    zero = torch.zeros(2, 4, 6, dtype=torch.float64)
    u = torch.linspace(0, 1, 5, dtype=torch.float64)
    assert torch.allclose(TRAJECTORIES["cubic"].poses(c2w, zero, u), c2w[:, None].expand(-1, 5, -1, -1))
    knots = zero.clone()
    knots[..., 3] = 1.0  # every knot moved by +1 in x: the whole segment moves by +1
    p = TRAJECTORIES["cubic"].poses(c2w, knots, u)
    assert torch.allclose(p[..., 0, 3] - c2w[:, None, 0, 3], torch.ones(2, 5, dtype=torch.float64))
    f = TRAJECTORIES["fixed"].poses(c2w, torch.zeros(2, 0, 6, dtype=torch.float64), u)
    assert f.shape == (2, 5, 4, 4) and torch.equal(f[:, 3], c2w)


def test_exposure_trajectories_module():
    c2w = random_c2w(4)
    moving = torch.tensor([True, False, True, True])
    traj = ExposureTrajectories(c2w, "linear", moving, scale=1.0, init_noise=1e-2,
                                generator=torch.Generator().manual_seed(0))
    u = virtual_instants(5)
    assert torch.allclose(u, torch.tensor([0.1, 0.3, 0.5, 0.7, 0.9]))
    p = traj(torch.arange(4), u)
    assert p.shape == (4, 5, 4, 4)
    assert torch.allclose(p[1], c2w[1].expand(5, 4, 4), atol=1e-6)  # non-moving frame: mid pose
    assert not torch.allclose(p[0, 0], p[0, -1])  # symmetric noise: start != end
    assert torch.allclose(traj.mid_poses(), c2w, atol=1e-5)  # symmetric init keeps the mid pose
    p.sum().backward()
    assert traj.knots.grad[1].abs().max() == 0 and traj.knots.grad[0].abs().max() > 0
    with pytest.raises(ValueError, match="kind"):
        ExposureTrajectories(c2w, "zigzag")
    with pytest.raises(ValueError, match="c2w_mid"):
        ExposureTrajectories(c2w[:, :3], "linear")


@pytest.mark.parametrize("kind", ["linear", "cubic"])
def test_anchored_trajectory_keeps_mid_pose(kind):
    c2w = random_c2w(3)
    traj = ExposureTrajectories(c2w, kind, scale=0.5, init_noise=0.0, anchored=True)
    with torch.no_grad():
        traj.knots.normal_(0, 0.05)
    p = traj(torch.arange(3), torch.tensor([0.0, 0.5, 1.0]))
    assert torch.allclose(p[:, 1], c2w, atol=1e-5)
    assert not torch.allclose(p[:, 0], p[:, 2], atol=1e-3)
    free = ExposureTrajectories(c2w, kind, scale=0.5)
    with torch.no_grad():
        free.knots.copy_(traj.knots)
    assert not torch.allclose(free(torch.arange(3), torch.tensor([0.5]))[:, 0], c2w, atol=1e-3)
    # the docstring's formula: the free poses left-multiplied by c2w_mid T(0.5)^-1, at every instant
    u = torch.tensor([0.1, 0.3, 0.5, 0.7, 0.9])
    with torch.no_grad():
        at_half = free(torch.arange(3), torch.tensor([0.5]))[:, 0]
        expected = (c2w @ torch.linalg.inv(at_half))[:, None] @ free(torch.arange(3), u)
        assert torch.allclose(traj(torch.arange(3), u), expected, atol=1e-5)


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
    """ebad._fast_poses against the trajectory functions, float64, from knots at the identity's
    series to rotations of about a radian, under a random upstream gradient."""
    from ebad._fast_poses import TrajectoryPoses

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
    from ebad._fast_poses import TrajectoryPoses

    knots = (torch.randn(2, 2, 6, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.3)
    mid = _rigid64(2)
    u = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    for kind, k in (("linear", knots), ("cubic", torch.cat([knots, -knots], 1)), ("offset", knots[:, :1])):
        assert torch.autograd.gradcheck(lambda x: TrajectoryPoses.apply(x, mid, u, kind, 1.3, True),
                                        (k.clone().requires_grad_(),))


def test_trajectories_near_pi_take_the_torch_path():
    """A linear trajectory whose start and end differ by nearly pi: the closed form refuses the
    logarithm (NearPi) and the module gives the torch composition's poses and gradients."""
    from ebad._fast_poses import NearPi, TrajectoryPoses

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
