"""Known values: one Gaussian's footprint, and the "stop before T_MIN" rule."""

from __future__ import annotations

import math

import pytest
import torch

from splat_cpu._numba_impl import rasterize_numba
from splat_cpu._torch_impl import rasterize_reference
from splat_cpu.constants import ALPHA_MAX, COV2D_BLUR

PATHS = {"numba": rasterize_numba, "torch": rasterize_reference}


def _camera(width, height, f=50.0):
    viewmats = torch.eye(4, dtype=torch.float64)[None]
    ks = torch.tensor([[[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]]], dtype=torch.float64)
    return viewmats, ks


def _gaussians(depths, opacities, colors, scale):
    n = len(depths)
    means = torch.zeros(n, 3, dtype=torch.float64)
    means[:, 2] = torch.tensor(depths, dtype=torch.float64)
    quats = torch.tensor([[2.0, 0, 0, 0]], dtype=torch.float64).repeat(n, 1)  # unnormalised identity
    scales = torch.full((n, 3), scale, dtype=torch.float64)
    return (means, quats, scales, torch.tensor(opacities, dtype=torch.float64),
            torch.tensor(colors, dtype=torch.float64)[:, None])


@pytest.mark.parametrize("path", list(PATHS))
def test_single_isotropic_gaussian_footprint(path):
    w, h, f, z, s, o = 9, 7, 50.0, 2.0, 0.04, 0.8
    means, quats, scales, opac, colors = _gaussians([z], [o], [0.6], s)
    viewmats, ks = _camera(w, h, f)
    bg = torch.tensor([0.1], dtype=torch.float64)
    img, alpha, meta = PATHS[path](means, quats, scales, opac, colors, viewmats, ks, w, h, background=bg)
    var = (f * s / z) ** 2 + COV2D_BLUR  # the mean projects onto (4.5, 3.5): the centre of pixel (4, 3)
    for dx, dy in [(0, 0), (1, 0), (0, -2), (3, 2)]:
        a = o * math.exp(-0.5 * (dx * dx + dy * dy) / var)
        a = a if a >= 1 / 255 else 0.0
        assert float(alpha[0, 3 + dy, 4 + dx, 0]) == pytest.approx(a, abs=1e-12)
        assert float(img[0, 3 + dy, 4 + dx, 0]) == pytest.approx(a * 0.6 + (1 - a) * 0.1, abs=1e-12)
    # radius: the box where o exp(-sigma) >= 1/255, rounded up
    r = math.ceil(math.sqrt(2 * math.log(255 * o) * var))
    assert meta["radii"][0, 0].tolist() == [r, r]


@pytest.mark.parametrize("path", list(PATHS))
def test_pixel_stops_before_the_gaussian_that_spends_transmittance(path):
    # front: alpha 0.999 leaves T = 1e-3; the next would bring T to 1e-6 <= T_MIN: it is not composited
    means, quats, scales, opac, colors = _gaussians([2.0, 3.0, 4.0], [1.0, 1.0, 0.5], [0.2, 0.9, 0.7], 0.05)
    viewmats, ks = _camera(9, 7)
    bg = torch.tensor([0.4], dtype=torch.float64)
    img, alpha, _ = PATHS[path](means, quats, scales, opac, colors, viewmats, ks, 9, 7, background=bg)
    assert float(alpha[0, 3, 4, 0]) == pytest.approx(ALPHA_MAX, abs=1e-12)
    assert float(img[0, 3, 4, 0]) == pytest.approx(ALPHA_MAX * 0.2 + (1 - ALPHA_MAX) * 0.4, abs=1e-12)
    # and the gradient reaches only the front Gaussian's colour at that pixel
    colors = colors.clone().requires_grad_()
    img, _, _ = PATHS[path](means, quats, scales, opac, colors, viewmats, ks, 9, 7, background=bg)
    (g,) = torch.autograd.grad(img[0, 3, 4, 0], colors)
    assert g[:, 0].tolist() == pytest.approx([ALPHA_MAX, 0.0, 0.0], abs=1e-12)
