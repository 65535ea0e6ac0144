"""ebad.lie: so(3)/SE(3) helpers."""

from __future__ import annotations

import pytest
import torch

from ebad.lie import so3_exp, so3_log, viewmat_from_c2w
from tests.ebad._helpers import random_c2w


def test_so3_exp_log_roundtrip_and_identity_gradient():
    g = torch.Generator().manual_seed(0)
    w = torch.randn(64, 3, generator=g, dtype=torch.float64)
    w = w / w.norm(dim=-1, keepdim=True) * torch.rand(64, 1, generator=g, dtype=torch.float64) * 3.0  # angles < pi
    assert torch.allclose(so3_log(so3_exp(w)), w, atol=1e-10)
    R = so3_exp(w)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(64, 3, 3), atol=1e-12)
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    so3_log(so3_exp(z)).sum().backward()
    assert torch.allclose(z.grad, torch.ones(3, dtype=torch.float64))
    x = (torch.randn(4, 3, generator=g, dtype=torch.float64) * 0.3).requires_grad_(True)
    torch.autograd.gradcheck(lambda x: so3_log(so3_exp(x)), (x,))


def test_viewmat_inverts_c2w():
    c2w = random_c2w(3)
    assert torch.allclose(viewmat_from_c2w(c2w) @ c2w, torch.eye(4).expand(3, 4, 4), atol=1e-5)


def test_quaternion_convention_is_real_part_first():
    from ebad.lie import quat_to_rotmat

    half = torch.tensor([[2.0**-0.5, 0.0, 0.0, 2.0**-0.5]])  # (w, x, y, z): 90 degrees about z
    R = quat_to_rotmat(half * 3.0)  # not unit: normalised inside
    assert torch.allclose(R[0], torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), atol=1e-6)
    assert torch.allclose(so3_exp(torch.tensor([0.0, 0.0, torch.pi / 2])), R[0], atol=1e-6)


def test_leading_dimensions_and_finite_gradients_at_identity():
    w = torch.zeros(2, 5, 3, requires_grad=True)
    R = so3_exp(w)
    assert R.shape == (2, 5, 3, 3)
    (R * torch.randn(3, 3)).sum().backward()
    assert torch.isfinite(w.grad).all()
    Rl = torch.eye(3).repeat(2, 5, 1, 1).requires_grad_(True)
    (so3_log(Rl) * torch.randn(3)).sum().backward()
    assert torch.isfinite(Rl.grad).all()


def test_so3_log_closed_form_matches_kornia_from_tiny_angles_to_near_pi():
    from kornia.geometry.liegroup import So3

    g = torch.Generator().manual_seed(1)
    axes = torch.randn(8, 3, generator=g, dtype=torch.float64)
    axes = axes / axes.norm(dim=-1, keepdim=True)
    for angle in (1e-9, 1e-6, 1e-4, 0.01, 0.3, 1.5, 2.5, 2.8, 3.1):  # 2.8 and 3.1 take kornia's path
        w = axes * angle
        R = so3_exp(w)
        assert torch.allclose(so3_log(R), w, rtol=1e-9, atol=1e-12), angle
        R32 = R.float()
        want = So3.from_matrix(R32).log()
        assert torch.allclose(so3_log(R32), want, rtol=1e-4, atol=1e-6), angle
    x = (axes[:3] * 1e-5).clone().requires_grad_(True)  # around the series' threshold in float64
    torch.autograd.gradcheck(lambda x: so3_log(so3_exp(x)), (x,))
    both = torch.stack([so3_exp(axes[0] * 3.1), torch.eye(3, dtype=torch.float64)]).requires_grad_(True)
    (so3_log(both) * torch.randn(2, 3, generator=g, dtype=torch.float64)).sum().backward()  # one row each path
    assert torch.isfinite(both.grad).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rigid_inverse_in_one_node_equals_the_torch_operations_in_value_and_gradient(dtype):
    from ebad.lie import _rigid_inverse_torch, rigid_inverse, so3_exp

    gen = torch.Generator().manual_seed(6)
    T = torch.eye(4, dtype=torch.float64).repeat(2, 3, 1, 1)
    T[..., :3, :3] = so3_exp(torch.randn(2, 3, 3, generator=gen, dtype=torch.float64))
    T[..., :3, 3] = torch.randn(2, 3, 3, generator=gen, dtype=torch.float64)
    T = T.to(dtype).requires_grad_()
    G = torch.randn(2, 3, 4, 4, generator=gen, dtype=dtype)
    fast, ref = rigid_inverse(T), _rigid_inverse_torch(T)
    (g_fast,) = torch.autograd.grad((fast * G).sum(), T)
    (g_ref,) = torch.autograd.grad((ref * G).sum(), T)
    tol = 1e-6 if dtype == torch.float32 else 1e-14
    assert torch.allclose(fast, ref, atol=tol) and torch.allclose(g_fast, g_ref, atol=tol)
    assert torch.allclose(fast @ T, torch.eye(4, dtype=dtype).expand(2, 3, 4, 4), atol=10 * tol)
    T64 = T.detach().double().requires_grad_()
    assert torch.autograd.gradcheck(rigid_inverse, (T64,))
