"""Known values: one Gaussian's footprint, and the "stop before T_MIN" rule."""

from __future__ import annotations

import math

import pytest
import torch

from splat_cpu._numba_impl import rasterize_numba
from splat_cpu._torch_impl import rasterize_reference
from splat_cpu.constants import ALPHA_MAX, COV2D_BLUR, FRUSTUM_MARGIN

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
    return (
        means,
        quats,
        scales,
        torch.tensor(opacities, dtype=torch.float64),
        torch.tensor(colors, dtype=torch.float64)[:, None],
    )


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


def _one_gaussian_at(u, v, width, height, f, z, s, o):
    """An isotropic Gaussian (scale s, opacity o) whose mean projects onto pixel coordinates (u, v) at depth z."""
    viewmats, ks = _camera(width, height, f)
    means, quats, scales, opac, colors = _gaussians([z], [o], [0.6], s)
    means[0, 0] = (u - width / 2) * z / f
    means[0, 1] = (v - height / 2) * z / f
    return means, quats, scales, opac, colors, viewmats, ks


@pytest.mark.parametrize("path", list(PATHS))
def test_gaussian_far_outside_the_image_adds_nothing(path):
    # issue 31: 1500 px right of a 32-px image, spread 16 px on the image plane along each axis at the image's centre;
    # with the Jacobian at the unclamped x/z = 47.4 its x spread would be 758 px and alpha 0.055 on the image's
    # right column; with gsplat's clamp (x/z <= 0.5 + 0.3 * 0.5) it is 19.1 px and the Gaussian is culled
    w = h = 32
    f, z, s, o = 32.0, 1.0, 0.5, 0.39
    u = w + 1500.0
    inputs = _one_gaussian_at(u, h / 2, w, h, f, z, s, o)
    xz = (u - w / 2) / f
    spread_unclamped = math.sqrt((f * s / z) ** 2 * (1 + xz**2) + COV2D_BLUR)
    assert spread_unclamped > 750 and o * math.exp(-0.5 * ((u - (w - 0.5)) / spread_unclamped) ** 2) > 0.054
    bg = torch.tensor([0.25], dtype=torch.float64)
    img, alpha, meta = PATHS[path](*inputs, w, h, background=bg)
    assert float(alpha.abs().max()) == 0.0
    assert bool((img == 0.25).all())
    assert meta["radii"].tolist() == [[[0, 0]]] and meta["n_visible"].tolist() == [0]


@pytest.mark.parametrize("path", list(PATHS))
def test_gaussian_beyond_the_frustum_limit_has_the_clamped_spread(path):
    # 10 px right of a 32-px image: x/z = 26 / 32 is beyond the limit 0.65, y/z = 0 is not; the Jacobian's x/z is
    # 0.65, so Sigma2d = diag((f s / z)^2 (1 + 0.65^2), (f s / z)^2) + 0.3 (no x-y term at y = 0)
    w = h = 32
    f, z, s, o = 32.0, 1.0, 0.5, 0.8
    u, v = w + 10.0, h / 2
    inputs = _one_gaussian_at(u, v, w, h, f, z, s, o)
    lim = 0.5 + FRUSTUM_MARGIN * 0.5
    assert (u - w / 2) / f > lim
    var_x = (f * s / z) ** 2 * (1 + lim**2) + COV2D_BLUR
    var_y = (f * s / z) ** 2 + COV2D_BLUR
    _, alpha, meta = PATHS[path](*inputs, w, h)
    extend = 2 * math.log(255 * o)
    assert meta["radii"][0, 0].tolist() == [math.ceil(math.sqrt(extend * var_x)), math.ceil(math.sqrt(extend * var_y))]
    for px, py in [(31, 16), (31, 3), (20, 16), (12, 25)]:
        dx, dy = u - (px + 0.5), v - (py + 0.5)
        a = o * math.exp(-0.5 * (dx * dx / var_x + dy * dy / var_y))
        a = a if a >= 1 / 255 else 0.0
        assert float(alpha[0, py, px, 0]) == pytest.approx(a, abs=1e-12)
