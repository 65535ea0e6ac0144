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
    traj = ExposureTrajectories(
        c2w, "linear", moving, scale=1.0, init_noise=1e-2, generator=torch.Generator().manual_seed(0)
    )
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
