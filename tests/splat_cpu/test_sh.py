"""View-dependent colour (spherical harmonics up to degree 3): the numba path against the torch reference,
gradients to the coefficients, the means and the poses, gradcheck, and per-camera colours."""

from __future__ import annotations

import math

import pytest
import torch

import splat_cpu
from splat_cpu._numba_impl import rasterize_numba
from splat_cpu._sh import SH_C0, camera_centres, num_sh_bases, sh_basis, sh_colors
from splat_cpu._torch_impl import rasterize_reference as _reference

from .conftest import make_scene

PATHS = {"numba": rasterize_numba, "torch": _reference}


def _coeffs(n: int, d: int, degree: int, dtype=torch.float64, seed: int = 0) -> torch.Tensor:  # [N, K, D]
    g = torch.Generator().manual_seed(seed)
    c = 0.4 * torch.randn(n, num_sh_bases(3), d, generator=g, dtype=torch.float64)
    c[:, 0] = (torch.rand(n, d, generator=g, dtype=torch.float64) - 0.5) / SH_C0
    c[:, num_sh_bases(degree) :] = 0.0
    return c.to(dtype)


def _sloan_basis(dirs: torch.Tensor) -> torch.Tensor:  # [M, 3] unit -> [M, 16]: gsplat's form (Sloan 2013)
    x, y, z = dirs.unbind(-1)
    z2 = z * z
    fc1, fs1 = x * x - y * y, 2 * x * y
    fc2, fs2 = x * fc1 - y * fs1, x * fs1 + y * fc1
    a, tb2, tc3 = -0.48860251190292, -1.092548430592079 * z, -2.285228997322329 * z2 + 0.4570457994644658
    b = [torch.full_like(x, 0.2820947917738781), a * y, -a * z, a * x]
    b += [0.5462742152960395 * fs1, tb2 * y, 0.9461746957575601 * z2 - 0.3153915652525201, tb2 * x]
    b += [0.5462742152960395 * fc1, -0.5900435899266435 * fs2, 1.445305721320277 * z * fs1, tc3 * y]
    b += [z * (1.865881662950577 * z2 - 1.119528997770346), tc3 * x, 1.445305721320277 * z * fc1]
    b += [-0.5900435899266435 * fc2]
    return torch.stack(b, -1)


def test_basis_is_inrias_and_equals_gsplats_form_on_the_sphere():
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, generator=torch.Generator().manual_seed(1)).double())
    ours = sh_basis(3, dirs)
    assert ours.shape == (500, 16)
    assert float((ours - _sloan_basis(dirs)).abs().max()) < 1e-12
    for deg in range(3):  # lower degrees are the leading columns
        assert torch.equal(sh_basis(deg, dirs), ours[:, : num_sh_bases(deg)])
    # orthonormal on the sphere: the Monte-Carlo Gram matrix of 4 pi E[b b^T] is the identity
    big = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=torch.Generator().manual_seed(2)).double())
    bb = sh_basis(3, big)
    gram = 4 * math.pi * bb.T @ bb / big.shape[0]
    assert float((gram - torch.eye(16, dtype=torch.float64)).abs().max()) < 0.03


def test_degree_zero_is_the_dc_colour_and_directions_are_from_the_camera_centre():
    means, _, _, _, _, viewmats, _ = make_scene(20, n_cams=2)
    coeffs = _coeffs(20, 3, 0)
    cols = sh_colors(means, coeffs, viewmats, 0)
    assert cols.shape == (2, 20, 3)
    assert torch.allclose(cols, (SH_C0 * coeffs[None, :, 0] + 0.5).clamp_min(0).expand(2, -1, -1), atol=1e-15)
    # camera centre: the translation of the inverse viewmat
    assert torch.allclose(camera_centres(viewmats), torch.linalg.inv(viewmats)[:, :3, 3], atol=1e-12)
    # degree 1 with a single coefficient on -C1 x: the colour is 0.5 + C1 * c * (-x) of the unit direction
    c1 = torch.zeros(20, 4, 1, dtype=torch.float64)
    c1[:, 3, 0] = 0.7
    col = sh_colors(means, c1, viewmats, 1)
    d = torch.nn.functional.normalize(means[None] - camera_centres(viewmats)[:, None], dim=-1)
    assert torch.allclose(col[..., 0], (0.5 - 0.4886025119029199 * 0.7 * d[..., 0]).clamp_min(0), atol=1e-14)


def _grads(fn, inputs, coeffs, degree, bg, width, height, cot_img, cot_alpha):
    ins = [t.detach().clone().requires_grad_() for t in inputs[:4]]
    co = coeffs.detach().clone().requires_grad_()
    vm = inputs[5].detach().clone().requires_grad_()
    img, alpha, _ = fn(*ins, co, vm, inputs[6], width, height, background=bg, sh_degree=degree)
    loss = (img.double() * cot_img).sum() + (alpha.double() * cot_alpha).sum()
    return img, torch.autograd.grad(loss, ins + [co, vm])


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("d", [1, 3])
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-10)])
def test_numba_matches_reference_forward_and_gradients(degree, d, dtype, tol):
    width, height = 37, 29
    inputs = make_scene(120, d=d, n_cams=3, width=width, height=height, seed=d + degree, dtype=dtype)
    coeffs = _coeffs(120, d, degree, dtype, seed=degree)
    bg = torch.linspace(0.2, 0.7, d, dtype=dtype)
    gen = torch.Generator().manual_seed(7)
    cot_img = torch.randn(3, height, width, d, generator=gen, dtype=torch.float64)
    cot_alpha = torch.randn(3, height, width, 1, generator=gen, dtype=torch.float64)
    img, grads = _grads(rasterize_numba, inputs, coeffs, degree, bg, width, height, cot_img, cot_alpha)
    ref_in = [t.double() for t in inputs]
    img_r, grads_r = _grads(_reference, ref_in, coeffs.double(), degree, bg.double(), width, height, cot_img, cot_alpha)
    assert img.dtype == dtype
    img, img_r = img.detach(), img_r.detach()
    scale = max(1.0, float(img_r.abs().max()))
    assert float((img.double() - img_r).abs().max()) <= tol * scale
    for name, g, gr in zip(["means", "quats", "scales", "opacities", "coeffs", "viewmats"], grads, grads_r):
        s = max(1.0, float(gr.abs().max()))
        err = float((g.double() - gr).abs().max())
        assert err <= (10 * tol if dtype == torch.float32 else tol) * s, (name, err)
    if degree > 0:  # the view direction's gradient reaches the poses beyond the projection's
        assert float(grads_r[4][:, num_sh_bases(degree) - 1].abs().max()) > 0
    assert float(grads_r[4][:, num_sh_bases(degree) :].abs().sum()) == 0  # unused coefficients get none


def _tiny(seed=3):
    return make_scene(6, d=2, n_cams=2, width=9, height=7, seed=seed, dense=False)


@pytest.mark.parametrize("path", list(PATHS))
def test_gradcheck_sh_degree_3(path):
    means, quats, scales, opac, _, viewmats, ks = _tiny()
    opac = opac.clamp(0.2, 0.9)
    coeffs = _coeffs(6, 2, 3, seed=5)
    fn = PATHS[path]

    def f(means, coeffs, top):
        vm = torch.cat([top, viewmats[:, 3:]], dim=1)
        img, alpha, _ = fn(means, quats, scales, opac, coeffs, vm, ks, 9, 7, sh_degree=3)
        return img, alpha

    args = [t.clone().requires_grad_() for t in (means, coeffs, viewmats[:, :3])]
    _, alpha = f(*args)
    assert float(alpha.detach().amax(dim=(1, 2, 3)).min()) > 0.3
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=path == "torch")


def test_gradcheck_of_the_sh_colours_alone_through_the_clamp_and_the_direction():
    from splat_cpu._numba_impl import _SHColors

    means, *_, viewmats, _ = make_scene(8, n_cams=2, seed=4)
    coeffs = _coeffs(8, 3, 3, seed=6)
    coeffs[0, 0, 0] = -3.0  # a clamped colour: no gradient
    args = [t.clone().requires_grad_() for t in (means, coeffs, viewmats)]
    assert float(_SHColors.apply(*args, 3, {}).detach()[:, 0, 0].max()) == 0.0
    assert torch.autograd.gradcheck(lambda m, c, v: _SHColors.apply(m, c, v, 3, {}), args, eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("d", [1, 3])
def test_per_camera_colours_equal_shared_ones_bit_for_bit(d):
    inputs = make_scene(80, d=d, n_cams=3, dtype=torch.float32)
    cols = inputs[4].clone().requires_grad_()
    img, alpha, _ = splat_cpu.rasterize(*inputs[:4], cols, *inputs[5:], 37, 29)
    per = cols.detach()[None].repeat(3, 1, 1).requires_grad_()
    img2, alpha2, _ = splat_cpu.rasterize(*inputs[:4], per, *inputs[5:], 37, 29)
    assert torch.equal(img, img2) and torch.equal(alpha, alpha2)
    w = torch.rand(img.shape, generator=torch.Generator().manual_seed(0))
    (img * w).sum().backward()
    (img2 * w).sum().backward()
    assert per.grad is not None and cols.grad is not None
    assert torch.allclose(per.grad.sum(0), cols.grad, atol=1e-6)
    # and each camera's colours are its own: changing camera 1's changes only its image
    per2 = per.detach().clone()
    per2[1] = 1 - per2[1]
    img3, _, _ = splat_cpu.rasterize(*inputs[:4], per2, *inputs[5:], 37, 29)
    assert torch.equal(img3[0], img[0]) and torch.equal(img3[2], img[2]) and not torch.equal(img3[1], img[1])


def test_sh_timings_are_reported():
    inputs = make_scene(40, d=3, n_cams=2, dtype=torch.float32)
    co = _coeffs(40, 3, 2, torch.float32).requires_grad_()
    img, _, meta = splat_cpu.rasterize(*inputs[:4], co, *inputs[5:], 37, 29, sh_degree=2)
    img.sum().backward()
    assert {"sh_ms", "project_ms", "backward_sh_ms"} <= set(meta["timings"])


@pytest.mark.parametrize(
    "change,match",
    [
        (dict(sh_degree=4), "sh_degree: expected None or an int in 0..3"),
        (dict(sh_degree=True), "sh_degree"),
        (dict(sh_degree=3, colors=torch.zeros(10, 9, 3)), r"colors: SH degree 3 needs \[N, K, D\] coefficients"),
        (dict(sh_degree=1, colors=torch.zeros(10, 3)), "colors: expected 3 dimensions"),
        (dict(colors=torch.zeros(3, 10, 3)), "colors: per-camera colours need 2 cameras"),
        (dict(colors=torch.zeros(2, 9, 3)), "colors: expected 10 Gaussians"),
        (dict(sh_degree=0, colors=torch.zeros(10, 1, 3), background=torch.zeros(1)), "background: expected 3"),
    ],
)
def test_invalid_sh_inputs_name_the_argument(change, match):
    means, quats, scales, opac, colors, viewmats, ks = make_scene(10, d=3, n_cams=2, dtype=torch.float32)
    kw = dict(colors=colors, background=None, sh_degree=None) | change
    with pytest.raises(ValueError, match=match):
        splat_cpu.rasterize(means, quats, scales, opac, kw["colors"], viewmats, ks, 37, 29, kw["background"],
                            kw["sh_degree"])  # fmt: skip


def test_a_singular_rotation_has_no_camera_centre():
    means, quats, scales, opac, _, viewmats, ks = make_scene(10, d=3, n_cams=2, dtype=torch.float32)
    viewmats[1, :3, :3] = 0.0
    with pytest.raises(ValueError, match="viewmats: a rotation part is singular"):
        splat_cpu.rasterize(means, quats, scales, opac, _coeffs(10, 3, 1, torch.float32), viewmats, ks, 37, 29,
                            sh_degree=1)  # fmt: skip
