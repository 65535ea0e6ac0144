"""Seeded tiny scenes for the splat_cpu tests."""

from __future__ import annotations

import math

import pytest
import torch


def make_scene(
    n: int,
    d: int = 1,
    n_cams: int = 2,
    width: int = 37,
    height: int = 29,
    seed: int = 0,
    dtype: torch.dtype = torch.float64,
    dense: bool = True,
) -> list[torch.Tensor]:
    """Gaussians around the origin seen by n_cams cameras about 4 units away, looking down +z.

    `dense` makes the scene opaque enough that many pixels stop on T_MIN, some Gaussians
    saturate ALPHA_MAX, and some are culled (behind the camera, too faint, off screen).
    """
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 0.8, 0.6], dtype=torch.float64)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = torch.exp(torch.empty(n, 3, dtype=torch.float64).uniform_(math.log(0.03), math.log(0.4), generator=g))
    opac = torch.rand(n, generator=g, dtype=torch.float64)
    if dense and n >= 10:
        opac[: n // 5] = 1.0  # saturate ALPHA_MAX at their centres
        opac[n // 5 : n // 5 + 2] = 0.002  # below ALPHA_MIN everywhere
        means[-1, 2] = -10.0  # behind every camera
        means[-2, 0] = 40.0  # far off screen
    colors = torch.rand(n, d, generator=g, dtype=torch.float64)
    viewmats = torch.eye(4, dtype=torch.float64)[None].repeat(n_cams, 1, 1)
    for c in range(n_cams):
        ang = 0.15 * c
        viewmats[c, 0, 0], viewmats[c, 0, 2] = math.cos(ang), math.sin(ang)
        viewmats[c, 2, 0], viewmats[c, 2, 2] = -math.sin(ang), math.cos(ang)
        viewmats[c, :3, 3] = torch.tensor([0.2 * c, -0.1 * c, 4.0], dtype=torch.float64)
    ks = torch.tensor([[40.0, 0, width / 2], [0, 42.0, height / 2], [0, 0, 1]], dtype=torch.float64)
    ks = ks[None].repeat(n_cams, 1, 1)
    return [t.to(dtype) for t in (means, quats, scales, opac, colors, viewmats, ks)]


@pytest.fixture
def scene():
    return make_scene
