"""ebad.gaussians: initialisation and activation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebad.gaussians import SH_C0, activate, init_params, points_from_frames


def _params(n=10, D=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    return init_params(torch.randn(n, 3, generator=g), torch.rand(n, D, generator=g), opacity=0.5)


def test_points_from_frames_lie_on_their_rays():
    frames = np.random.default_rng(0).random((2, 12, 16, 1)).astype(np.float32)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, :3, 3] = [1, 0, 0]
    K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    pts, cols, sc = points_from_frames(frames, c2w, K, 200, (1.0, 4.0), seed=1)
    assert pts.shape == (200, 3) and cols.shape == (200, 1) and sc.shape == (200,)
    z = pts[:, 2]
    assert (z >= 1.0 - 1e-5).all() and (z <= 4.0 + 1e-5).all()
    with pytest.raises(ValueError, match="depth_range"):
        points_from_frames(frames, c2w, K, 5, (2.0, 1.0))


def test_activation_conventions():
    p = _params(5, D=3)
    a = activate(p)
    assert torch.allclose(a["opacities"], torch.full((5,), 0.5))
    assert torch.allclose(a["colors"], (0.5 + SH_C0 * p["colors"]).clamp_min(0))
    with pytest.raises(ValueError, match="points"):
        init_params(torch.zeros(3, 2), torch.zeros(3, 1))


def test_knn_scale_matches_brute_force():
    from ebad.gaussians import knn_scale

    g = torch.Generator().manual_seed(0)
    pts = torch.randn(300, 3, generator=g)
    d = torch.cdist(pts, pts)
    d.fill_diagonal_(float("inf"))
    ref = d.topk(3, largest=False).values.mean(-1)
    assert torch.allclose(knn_scale(pts), ref, atol=1e-5)
    assert knn_scale(pts[:1]).shape == (1,) and knn_scale(pts[:2]).shape == (2,)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_normalise_quats_in_place_equals_dividing_by_the_clamped_norm(dtype):
    from ebad.gaussians import normalise_quats_

    q = torch.randn(50, 4, generator=torch.Generator().manual_seed(0), dtype=dtype) * 3
    q[7] = 0.0  # clamped: stays zero, no nan
    ref = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    p = torch.nn.Parameter(q.clone())
    normalise_quats_(p)
    assert torch.allclose(p.data, ref, rtol=2e-7 if dtype == torch.float32 else 1e-15, atol=0)
    assert torch.isfinite(p.data).all() and not p.data[7].any()
    t = q.clone().t().contiguous().t()  # a non-contiguous view takes the torch expression
    normalise_quats_(t)
    assert torch.allclose(t, ref)
