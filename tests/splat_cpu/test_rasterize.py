"""splat_cpu.rasterize: both paths against a float64 brute-force compositor, gradients,
batching, invalid input, stress cases (kornia-style battery)."""

from __future__ import annotations

import pytest
import torch

import splat_cpu
from splat_cpu._numba_impl import rasterize_numba
from splat_cpu._torch_impl import rasterize_reference as _reference
from splat_cpu.constants import T_MIN

from .brute import brute_render
from .conftest import make_scene

PATHS = {"numba": rasterize_numba, "torch": _reference}


def _close(x: torch.Tensor, ref: torch.Tensor, tol: float, what: str) -> None:
    """max |x - ref| <= tol * max(1, max |ref|): an absolute check scaled to the quantity."""
    x, ref = x.detach(), ref.detach()
    scale = max(1.0, float(ref.abs().max())) if ref.numel() else 1.0
    err = float((x.double() - ref.double()).abs().max()) if ref.numel() else 0.0
    assert err <= tol * scale, f"{what}: max error {err:.3g} > {tol:g} * {scale:.3g}"


def _grads(fn, inputs, bg, width, height, cot_img, cot_alpha):
    ins = [t.detach().clone().requires_grad_() for t in inputs]
    b = bg.detach().clone().requires_grad_()
    out = fn(*ins, width, height, background=b)
    img, alpha = out[0], out[1]
    loss = (img.double() * cot_img).sum() + (alpha.double() * cot_alpha).sum()
    return img, alpha, torch.autograd.grad(loss, ins + [b], allow_unused=True)


NAMES = ["means", "quats", "scales", "opacities", "colors", "viewmats", "Ks", "background"]


@pytest.mark.parametrize("path", list(PATHS))
@pytest.mark.parametrize("d", [1, 3])
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-10)])
def test_matches_brute_force_forward_and_gradients(path, d, dtype, tol):
    width, height = 37, 29  # not tile multiples: 3 x 2 tiles, partial edges
    inputs = make_scene(120, d=d, n_cams=3, width=width, height=height, seed=d, dtype=dtype)
    bg = torch.linspace(0.2, 0.7, d, dtype=dtype)
    gen = torch.Generator().manual_seed(7)
    cot_img = torch.randn(3, height, width, d, generator=gen, dtype=torch.float64)
    cot_alpha = torch.randn(3, height, width, 1, generator=gen, dtype=torch.float64)
    img, alpha, grads = _grads(PATHS[path], inputs, bg, width, height, cot_img, cot_alpha)
    inputs64 = [t.double() for t in inputs]
    img_b, alpha_b, grads_b = _grads(brute_render, inputs64, bg.double(), width, height, cot_img, cot_alpha)
    # the scene exercises the rules: opaque pixels stop on T_MIN, some Gaussians saturate
    assert float(alpha_b.detach().max()) > 1 - 10 * T_MIN and float(alpha_b.detach().min()) < 0.5
    assert img.dtype == dtype and alpha.dtype == dtype
    assert img.shape == (3, height, width, d) and alpha.shape == (3, height, width, 1)
    _close(img, img_b, tol, "images")
    _close(alpha, alpha_b, tol, "alphas")
    for name, g, gb in zip(NAMES, grads, grads_b):
        if name == "Ks":
            continue  # intrinsics are not a promised gradient
        assert g is not None, name
        assert bool(torch.isfinite(g).all()), name
        _close(g, gb, 10 * tol if dtype == torch.float32 else tol, f"d/d{name}")
    assert float(grads_b[5].abs().max()) > 0  # pose gradients are really exercised


def test_public_rasterize_picks_the_fast_path_and_agrees_with_reference():
    inputs = make_scene(60, d=3, n_cams=2, dtype=torch.float32)
    img, alpha, meta = splat_cpu.rasterize(*inputs, 37, 29)
    img_r, alpha_r, meta_r = splat_cpu.rasterize_reference(*inputs, 37, 29)
    assert meta["path"] == "numba" and meta_r["path"] == "torch"
    _close(img, img_r, 1e-5, "images")
    _close(alpha, alpha_r, 1e-5, "alphas")
    assert torch.equal(meta["radii"], meta_r["radii"])
    assert meta["radii"].shape == (2, 60, 2) and meta["radii"].dtype == torch.int32
    assert torch.equal(meta["n_visible"], (meta["radii"][..., 0] > 0).sum(dim=1))
    assert meta["means2d"].shape == (2, 60, 2)
    assert set(meta["timings"]) >= {"project_ms", "composite_ms"}


def test_screen_space_gradients_through_meta_means2d():
    inputs = [t.clone().requires_grad_() for t in make_scene(40, d=1, n_cams=2, dtype=torch.float32)]
    img, _, meta = splat_cpu.rasterize(*inputs, 37, 29)
    meta["means2d"].retain_grad()
    img.sum().backward()
    g = meta["means2d"].grad
    visible = meta["radii"][..., 0] > 0
    assert g is not None and g.shape == (2, 40, 2)
    assert bool((g[visible].abs().sum(-1) > 0).any()) and bool((g[~visible] == 0).all())


def _tiny(seed=3):
    return make_scene(6, d=2, n_cams=2, width=9, height=7, seed=seed, dense=False)


@pytest.mark.parametrize("path", list(PATHS))
def test_gradcheck_tiny_scene(path):
    means, quats, scales, opac, colors, viewmats, ks = _tiny()
    opac = opac.clamp(0.2, 0.9)  # away from the ALPHA_MAX kink
    bg = torch.tensor([0.3, 0.6], dtype=torch.float64)
    fn = PATHS[path]

    def f(means, quats, scales, opac, colors, top, bg):
        vm = torch.cat([top, viewmats[:, 3:]], dim=1)
        img, alpha, _ = fn(means, quats, scales, opac, colors, vm, ks, 9, 7, background=bg)
        return img, alpha

    args = [t.clone().requires_grad_() for t in (means, quats, scales, opac, colors, viewmats[:, :3], bg)]
    _, alpha = f(*args)
    assert float(alpha.detach().amax(dim=(1, 2, 3)).min()) > 0.3  # every camera sees Gaussians
    # full Jacobians for the numba path; the slower reference is checked along random directions
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=path == "torch")


def _beyond_the_frustum(n: int, width: int, height: int, seed: int = 0) -> list[torch.Tensor]:
    """n Gaussians whose x/z or y/z lies beyond the Jacobian's frustum limits (1.3 half fields of view),
    wide enough to reach into the image, seen by two cameras (the second turned a little), float64."""
    g = torch.Generator().manual_seed(seed)
    f = 0.9 * width
    z = 2.0 + torch.rand(n, generator=g, dtype=torch.float64)
    side = torch.where(torch.arange(n) % 2 == 0, 1.0, -1.0).double()
    beyond = 0.7 + 0.4 * torch.rand(n, generator=g, dtype=torch.float64)  # |offset| / half image: 1.4 .. 2.2
    inside = 0.6 * torch.rand(n, generator=g, dtype=torch.float64) - 0.3
    on_x = torch.arange(n) % 3 != 0  # every third one beyond the y limits instead
    u = torch.where(on_x, side * beyond * width, inside * width)
    v = torch.where(on_x, inside * height, side * beyond * height)
    means = torch.stack([u / f * z, v / f * z, z], -1)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = 0.25 + 0.3 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    opac = 0.3 + 0.5 * torch.rand(n, generator=g, dtype=torch.float64)
    colors = torch.rand(n, 1, generator=g, dtype=torch.float64)
    viewmats = torch.eye(4, dtype=torch.float64)[None].repeat(2, 1, 1)
    viewmats[1, 0, 0], viewmats[1, 0, 2], viewmats[1, 2, 0], viewmats[1, 2, 2] = 0.995, 0.0998, -0.0998, 0.995
    viewmats[1, :3, 3] = torch.tensor([0.05, -0.03, 0.1], dtype=torch.float64)
    ks = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]], dtype=torch.float64)[None].repeat(2, 1, 1)
    return [means, quats, scales, opac, colors, viewmats, ks]


@pytest.mark.parametrize("path", list(PATHS))
def test_beyond_the_frustum_limits_matches_brute_force(path):
    # gsplat's clamp of x/z, y/z in the Jacobian, forward and gradients (zero through the clamped coordinate)
    width, height = 24, 18
    inputs = _beyond_the_frustum(12, width, height)
    bg = torch.tensor([0.3], dtype=torch.float64)
    gen = torch.Generator().manual_seed(2)
    cot_img = torch.randn(2, height, width, 1, generator=gen, dtype=torch.float64)
    cot_alpha = torch.randn(2, height, width, 1, generator=gen, dtype=torch.float64)
    img, alpha, grads = _grads(PATHS[path], inputs, bg, width, height, cot_img, cot_alpha)
    img_b, alpha_b, grads_b = _grads(brute_render, inputs, bg, width, height, cot_img, cot_alpha)
    assert float(alpha_b.detach().amax(dim=(1, 2, 3)).min()) > 0.2  # the clamped Gaussians reach the image
    _close(img, img_b, 1e-10, "images")
    _close(alpha, alpha_b, 1e-10, "alphas")
    for name, gr, gb in zip(NAMES, grads, grads_b):
        if name != "Ks":
            _close(gr, gb, 1e-10, f"d/d{name}")


@pytest.mark.parametrize("path", list(PATHS))
def test_gradcheck_beyond_the_frustum_limits(path):
    means, quats, scales, opac, colors, viewmats, ks = _beyond_the_frustum(4, 10, 8, seed=1)
    fn = PATHS[path]

    def f(means, quats, scales, top):
        vm = torch.cat([top, viewmats[:, 3:]], dim=1)
        img, alpha, _ = fn(means, quats, scales, opac, colors, vm, ks, 10, 8)
        return img, alpha

    args = [t.clone().requires_grad_() for t in (means, quats, scales, viewmats[:, :3])]
    _, alpha = f(*args)
    assert float(alpha.detach().amax(dim=(1, 2, 3)).min()) > 0.2
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=path == "torch")


def _se3_exp(xi: torch.Tensor) -> torch.Tensor:  # [6] (rho, omega) -> [4, 4]
    m = torch.zeros(4, 4, dtype=xi.dtype)
    w = xi[3:]
    m[0, 1], m[0, 2], m[1, 2] = -w[2], w[1], -w[0]
    m[1, 0], m[2, 0], m[2, 1] = w[2], -w[1], w[0]
    m[:3, 3] = xi[:3]
    return torch.linalg.matrix_exp(m)


@pytest.mark.parametrize("path", list(PATHS))
def test_pose_gradient_matches_se3_finite_differences(path):
    inputs = make_scene(80, d=1, n_cams=1, seed=5)
    means, quats, scales, opac, colors, viewmats, ks = inputs
    cot = torch.randn(1, 29, 37, 1, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    fn = PATHS[path]

    def loss(xi):
        vm = (_se3_exp(xi) @ viewmats[0])[None]
        img, _, _ = fn(means, quats, scales, opac, colors, vm, ks, 37, 29)
        return (img * cot).sum()

    xi = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(loss(xi), xi)
    h = 1e-6
    fd = torch.stack([(loss(h * e) - loss(-h * e)) / (2 * h) for e in torch.eye(6, dtype=torch.float64)])
    assert float(g.abs().max()) > 1e-2
    _close(g, fd, 1e-4, "d loss / d xi")


def test_batched_cameras_equal_one_by_one():
    inputs = make_scene(100, d=3, n_cams=4, dtype=torch.float64)
    *gs, viewmats, ks = inputs
    bg = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    img, alpha, _ = splat_cpu.rasterize(*gs, viewmats, ks, 37, 29, background=bg)
    for c in range(4):
        img_c, alpha_c, _ = splat_cpu.rasterize(*gs, viewmats[c : c + 1], ks[c : c + 1], 37, 29, background=bg)
        # equal up to rounding of the batched projection matmuls
        _close(img[c], img_c[0], 1e-12, "images")
        _close(alpha[c], alpha_c[0], 1e-12, "alphas")
    # gradients of the batch are the sum of the gradients one by one
    cot = torch.randn_like(img)
    leaves = [t.clone().requires_grad_() for t in gs]
    g_batch = torch.autograd.grad((splat_cpu.rasterize(*leaves, viewmats, ks, 37, 29)[0] * cot).sum(), leaves)
    g_sum = [torch.zeros_like(t) for t in gs]
    for c in range(4):
        img_c = splat_cpu.rasterize(*leaves, viewmats[c : c + 1], ks[c : c + 1], 37, 29)[0]
        for acc, g in zip(g_sum, torch.autograd.grad((img_c * cot[c : c + 1]).sum(), leaves)):
            acc += g
    for name, a, b in zip(NAMES, g_batch, g_sum):
        _close(a, b, 1e-12, name)


@pytest.mark.parametrize("path", list(PATHS))
def test_grey_equals_one_channel_of_rgb(path):
    means, quats, scales, opac, colors, viewmats, ks = make_scene(90, d=3, n_cams=2, dtype=torch.float32)
    fn = PATHS[path]
    rgb, alpha_rgb, _ = fn(means, quats, scales, opac, colors, viewmats, ks, 37, 29, torch.tensor([0.2, 0.4, 0.6]))
    grey, alpha_grey, _ = fn(means, quats, scales, opac, colors[:, 1:2], viewmats, ks, 37, 29, torch.tensor([0.4]))
    assert grey.shape[-1] == 1
    if path == "numba":  # per-channel loops: bit-identical
        assert torch.equal(grey[..., 0], rgb[..., 1])
        assert torch.equal(alpha_grey, alpha_rgb)
    else:  # the reference's matmul over channels rounds differently for D = 1 and D = 3
        _close(grey[..., 0], rgb[..., 1], 1e-6, "grey")
        _close(alpha_grey, alpha_rgb, 1e-6, "alpha")


@pytest.mark.parametrize("path", list(PATHS))
def test_no_gaussians_renders_the_background(path):
    z = torch.zeros(0, 3)
    viewmats, ks = make_scene(1, n_cams=2, dtype=torch.float32)[5:]
    bg = torch.tensor([0.25, 0.5], requires_grad=True)
    colors = torch.zeros(0, 2, requires_grad=True)
    img, alpha, meta = PATHS[path](z, torch.zeros(0, 4), z, torch.zeros(0), colors, viewmats, ks, 5, 3, bg)
    assert img.shape == (2, 3, 5, 2) and torch.equal(img, bg.detach().expand(2, 3, 5, 2))
    assert torch.equal(alpha, torch.zeros(2, 3, 5, 1))
    img.sum().backward()
    assert torch.equal(bg.grad, torch.full((2,), 30.0))


def test_public_functions_with_no_gaussians_and_no_background():
    viewmats, ks = make_scene(1, n_cams=1, dtype=torch.float32)[5:]
    for fn in (splat_cpu.rasterize, splat_cpu.rasterize_reference):
        img, alpha, _ = fn(
            torch.zeros(0, 3),
            torch.zeros(0, 4),
            torch.zeros(0, 3),
            torch.zeros(0),
            torch.zeros(0, 1),
            viewmats,
            ks,
            4,
            4,
        )
        assert torch.equal(img, torch.zeros(1, 4, 4, 1)) and torch.equal(alpha, torch.zeros(1, 4, 4, 1))


# ---------------------------------------------------------------------------------------------
# invalid input


def _valid_args():
    means, quats, scales, opac, colors, viewmats, ks = make_scene(5, d=3, n_cams=1, dtype=torch.float32)
    return dict(
        means=means,
        quats=quats,
        scales=scales,
        opacities=opac,
        colors=colors,
        viewmats=viewmats,
        Ks=ks,
        width=37,
        height=29,
        background=torch.zeros(3),
    )


def _nan_at(t):
    t = t.clone()
    t.view(-1)[0] = float("nan")
    return t


BAD = [
    ("means", lambda a: a["means"][:, :2]),
    ("scales", lambda a: a["scales"].double()),
    ("means", lambda a: a["means"].long()),
    ("means", lambda a: _nan_at(a["means"])),
    ("means", lambda a: a["means"].numpy()),
    ("quats", lambda a: a["quats"][:4]),
    ("quats", lambda a: torch.zeros_like(a["quats"])),
    ("quats", lambda a: a["quats"] * (torch.arange(len(a["quats"])) != 1)[:, None]),  # one zero row among others
    ("quats", lambda a: a["quats"].double()),
    ("scales", lambda a: -a["scales"]),
    ("scales", lambda a: a["scales"].log().clamp(max=-0.1) * 0 - 1),
    ("scales", lambda a: a["scales"][None]),
    ("scales", lambda a: a["scales"] * 0 + 1e20),  # issue 13: silent NaN gradients before
    ("opacities", lambda a: a["opacities"] + 1.5),
    ("opacities", lambda a: a["opacities"][:, None]),
    ("opacities", lambda a: torch.full_like(a["opacities"], float("inf"))),
    ("colors", lambda a: a["colors"][0]),
    ("colors", lambda a: a["colors"][:, :0]),
    ("colors", lambda a: a["colors"].half()),
    ("viewmats", lambda a: a["viewmats"][0]),
    ("viewmats", lambda a: a["viewmats"][:, :3]),
    ("viewmats", lambda a: a["viewmats"][:0]),
    ("viewmats", lambda a: a["viewmats"] * 2),
    ("viewmats", lambda a: _nan_at(a["viewmats"])),
    ("Ks", lambda a: a["Ks"].repeat(2, 1, 1)),
    ("Ks", lambda a: a["Ks"][:, :2]),
    ("Ks", lambda a: -a["Ks"]),
    ("Ks", lambda a: a["Ks"] + torch.tensor([[0, 1.0, 0], [0, 0, 0], [0, 0, 0]])),
    ("width", lambda a: 0),
    ("width", lambda a: 37.0),
    ("height", lambda a: -3),
    ("height", lambda a: True),
    ("background", lambda a: torch.zeros(2)),
    ("background", lambda a: torch.zeros(3, dtype=torch.float64)),
    ("background", lambda a: torch.full((3,), float("nan"))),
]


@pytest.mark.parametrize("fn", [splat_cpu.rasterize, splat_cpu.rasterize_reference])
@pytest.mark.parametrize("name,bad", BAD)
def test_invalid_input_raises_naming_the_argument(fn, name, bad):
    args = _valid_args()
    args[name] = bad(args)
    with pytest.raises(ValueError, match=rf"^{name}:"):
        fn(**args)


def test_device_mismatch_raises_on_meta_device():
    args = _valid_args()
    args["colors"] = args["colors"].to("meta")
    with pytest.raises(ValueError, match="^colors:"):
        splat_cpu.rasterize(**args)
