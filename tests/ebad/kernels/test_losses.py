"""ebad.kernels.losses against the torch reference: values, gradients, gradcheck, float32.

The public losses of ``ebad.losses`` run the kernels on CPU tensors (``test_the_kernels_run_on_cpu_tensors``
checks that the dispatch takes them); each is compared here with a reference that shares none of
its code: kornia's SSIM, L_ev written out in torch, the three losses composed.
"""

from __future__ import annotations

import math

import pytest
import torch

from ebad.losses import blur_loss, edi_loss, event_loss, l1_ssim, luminance, ssim_map


@pytest.mark.parametrize(
    "shape,window",
    [
        ((2, 20, 24, 1), 7),
        ((1, 12, 9, 3), 11),
        ((1, 5, 6, 1), 11),
        ((1, 61, 30, 1), 7),
        ((2, 49, 8, 3), 11),  # several bands of rows
        ((1, 3, 8, 1), 7),
        ((1, 40, 33, 1), 9),
    ],
)  # windows 5 and 9 inside blocks of 7 taps
def test_ssim_matches_kornia_reference(shape, window):
    from ebad.losses import ssim_map, ssim_map_kornia

    g = torch.Generator().manual_seed(0)
    a = torch.rand(shape, generator=g, dtype=torch.float64)
    b = (a + 0.2 * torch.rand(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    assert torch.allclose(ssim_map(a, b, window), ssim_map_kornia(a, b, window), atol=1e-9)


def test_ssim_gradcheck():
    from ebad.losses import ssim_map

    g = torch.Generator().manual_seed(1)
    a = torch.rand(1, 6, 7, 1, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.rand(1, 6, 7, 1, generator=g, dtype=torch.float64)
    torch.autograd.gradcheck(lambda x: ssim_map(x, b, 5).mean(), (a,))


def test_ssim_gradcheck_both_inputs_any_upstream_gradient():
    # the fused backward is the adjoint of both passes and of the reflect padding: checked
    # against finite differences for both inputs at once, several channels, a non-uniform
    # upstream gradient (gradcheck draws it), and a window as wide as the padding allows
    from ebad.losses import ssim_map

    g = torch.Generator().manual_seed(2)
    a = torch.rand(2, 6, 9, 3, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.rand(2, 6, 9, 3, generator=g, dtype=torch.float64, requires_grad=True)
    for win in (1, 3, 11):
        torch.autograd.gradcheck(lambda x, y, win=win: ssim_map(x, y, win), (a, b))


def test_ssim_float32_close_to_the_float64_reference_and_gradient_matches_kornia():
    from ebad.losses import ssim_map, ssim_map_kornia

    g = torch.Generator().manual_seed(3)
    a64 = torch.rand(3, 40, 52, 1, generator=g, dtype=torch.float64)
    b64 = (a64 + 0.3 * torch.rand(3, 40, 52, 1, generator=g, dtype=torch.float64)).clamp(0, 1)
    s32 = ssim_map(a64.float(), b64.float())
    assert s32.dtype == torch.float32
    assert (s32.double() - ssim_map_kornia(a64, b64)).abs().max() < 1e-5
    a = a64.float().requires_grad_()
    ssim_map(a, b64.float()).mean().backward()
    ref = a64.clone().requires_grad_()
    ssim_map_kornia(ref, b64).mean().backward()
    assert (a.grad.double() - ref.grad).abs().max() < 1e-5 * ref.grad.abs().max()


def test_ssim_dark_and_saturated_images_give_finite_values_and_gradients():
    # constant black against constant white, black against black, and a saturated patch: the
    # denominators stay at c1 c2 > 0, so the map and its gradient are finite, and the values
    # match a float64 evaluation
    from ebad.losses import ssim_map, ssim_map_kornia

    black, white = torch.zeros(1, 12, 14, 1), torch.ones(1, 12, 14, 1)
    patchy = white.clone()
    patchy[:, 3:8, 4:9] = 0.0
    for x, y in ((black, white), (black, black), (patchy, white), (white, patchy)):
        a = x.clone().requires_grad_()
        s = ssim_map(a, y)
        s.mean().backward()
        assert torch.isfinite(s).all() and torch.isfinite(a.grad).all()
        truth = ssim_map_kornia(x.double(), y.double())
        assert torch.allclose(ssim_map(x.double(), y.double()), truth, atol=1e-9)
        # near a flat patch the variance is a difference of nearly equal float32 numbers (about
        # 3e-5 of error in both implementations here): float32 must be no worse than kornia's own
        err, err_kornia = ((m.double() - truth).abs().max() for m in (s, ssim_map_kornia(x, y)))
        assert err <= 1.25 * err_kornia + 1e-6


def _l1_ssim_reference(pred, target, w, window):
    from ebad.losses import ssim_map_kornia

    return (1 - w) * (pred - target).abs().mean() + w * (1 - ssim_map_kornia(pred, target, window).mean())


@pytest.mark.parametrize(
    "shape,window,w",
    [((1, 20, 24, 1), 7, 0.2), ((2, 53, 17, 1), 7, 0.5), ((1, 30, 26, 3), 11, 0.8), ((3, 4, 5, 1), 7, 0.2)],
)
def test_l1_ssim_in_one_kernel_equals_l1_plus_kornia_ssim_in_value_and_gradient(shape, window, w):
    # the fused loss (no SSIM map, the L1 term inside the kernel, a constant upstream gradient in
    # the adjoint) against torch's L1 plus kornia's SSIM, for both inputs, across several bands of
    # rows (the kernels' tasks) and a window wider than a tiny image allows
    g = torch.Generator().manual_seed(5)
    a = torch.rand(shape, generator=g, dtype=torch.float64)
    b = (a + 0.3 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    b[..., :2, :3, :] = a[..., :2, :3, :]  # some pixels equal: the L1 gradient there is 0, as torch's
    x, y = a.clone().requires_grad_(), b.clone().requires_grad_()
    xr, yr = a.clone().requires_grad_(), b.clone().requires_grad_()
    loss, ref = l1_ssim(x, y, w, window), _l1_ssim_reference(xr, yr, w, window)
    assert float(loss.detach()) == pytest.approx(float(ref.detach()), abs=1e-12)
    (3.0 * loss).backward()
    (3.0 * ref).backward()
    assert torch.allclose(x.grad, xr.grad, atol=1e-12) and torch.allclose(y.grad, yr.grad, atol=1e-12)
    small = (a[:, :9, :7].clone().requires_grad_(), b[:, :9, :7].clone().requires_grad_())
    torch.autograd.gradcheck(lambda p, t: l1_ssim(p, t, w, window), small)


def test_l1_ssim_float32_matches_the_float64_loss():
    g = torch.Generator().manual_seed(6)
    a = torch.rand(5, 65, 87, 1, generator=g, dtype=torch.float64)
    b = (a + 0.2 * torch.randn(5, 65, 87, 1, generator=g, dtype=torch.float64)).clamp(0, 1)
    x = a.float().requires_grad_()
    loss = l1_ssim(x, b.float())
    assert loss.dtype == torch.float32
    loss.backward()
    xr = a.clone().requires_grad_()
    ref = _l1_ssim_reference(xr, b, 0.2, 7)
    ref.backward()
    assert abs(float(loss.detach()) - float(ref.detach())) < 1e-6
    assert (x.grad.double() - xr.grad).abs().max() < 1e-5 * xr.grad.abs().max()


def test_float32_images_run_the_float32_ssim_backward_only():
    # a float64 array among a float32 call's arguments makes numba compute the float32 loops in
    # float64 (the loss's per-image gradient constants once made the backward 1.5x slower)
    from ebad.kernels import _numba_ssim as K

    a = torch.rand(2, 20, 24, 1, requires_grad=True)
    l1_ssim(a, torch.rand(2, 20, 24, 1)).backward()
    ssim_map(a, torch.rand(2, 20, 24, 1)).sum().backward()
    arrays = [[str(t.dtype) for t in sig if hasattr(t, "ndim")] for sig in K.ssim_backward.signatures]
    float32_calls = [dt for dt in arrays if dt[0] == "float32"]
    assert float32_calls and all(set(dt) == {"float32"} for dt in float32_calls), arrays


def test_l1_ssim_each_in_one_call_equals_each_pair_alone():
    # the trainer's L_blur and L_EDI come from one kernel call: each loss and its gradients must be
    # what the pair gives alone (colour, [H, W, D] and [B, H, W, D] pairs, different weights)
    from ebad.losses import l1_ssim_each

    g = torch.Generator().manual_seed(7)
    shapes = [(30, 26, 3), (4, 30, 26, 3), (2, 30, 26, 3)]
    preds = [torch.rand(sh, generator=g, dtype=torch.float64, requires_grad=True) for sh in shapes]
    targets = [torch.rand(sh, generator=g, dtype=torch.float64) for sh in shapes]
    weights = torch.tensor([1.0, 0.3, 2.0], dtype=torch.float64)
    together = l1_ssim_each(list(zip(preds, targets)), 0.2, 7)
    (torch.stack(together) * weights).sum().backward()
    grads = [p.grad.clone() for p in preds]
    for i, (p, t) in enumerate(zip(preds, targets)):
        p.grad = None
        alone = l1_ssim(p, t, 0.2, 7)
        (weights[i] * alone).backward()
        assert float(together[i].detach()) == pytest.approx(float(alone.detach()), abs=1e-13)
        assert torch.allclose(grads[i], p.grad, atol=1e-14)
    with pytest.raises(ValueError, match="one image size"):
        l1_ssim_each([(preds[0], targets[0]), (preds[1][:, :20], targets[1][:, :20])])


def test_ssim_takes_non_contiguous_views_and_refuses_shape_mismatch():
    from ebad.losses import ssim_map, ssim_map_kornia

    g = torch.Generator().manual_seed(4)
    a = torch.rand(2, 3, 20, 16, generator=g, dtype=torch.float64).permute(0, 2, 3, 1)  # [2, 20, 16, 3] strided
    b = torch.rand(2, 20, 16, 3, generator=g, dtype=torch.float64)
    assert torch.allclose(ssim_map(a, b), ssim_map_kornia(a, b), atol=1e-9)
    with pytest.raises(ValueError, match="differ in shape"):
        ssim_map(a, b[:, :10])


def _event_loss_torch(renders, counts, c, eps, norm):
    """L_ev written out in torch operations (the kernels' reference)."""
    logL = torch.log(luminance(renders)[..., 0].clamp_min(0) + eps)
    cc = torch.as_tensor(c, dtype=logL.dtype).reshape(-1)
    r = logL[1:] - logL[:-1] - (cc[0] * counts[:, 0] - cc[-1] * counts[:, 1]).to(logL.dtype)
    return r.abs().mean() if norm == "l1" else r.square().mean()


@pytest.mark.parametrize("norm", ["l1", "l2"])
@pytest.mark.parametrize("D,H,W", [(1, 37, 23), (3, 5, 9)])
def test_event_loss_kernel_equals_torch_in_value_and_gradient_of_renders_and_both_thresholds(norm, D, H, W):
    # more rows than one band of the kernel; negative render values (the clamp: no gradient) and a
    # residual of exactly zero (abs has gradient 0 there) included
    g = torch.Generator().manual_seed(3)
    renders = torch.rand(5, H, W, D, generator=g, dtype=torch.float64) * 1.2 - 0.1
    counts = torch.randint(0, 4, (4, 2, H, W), generator=g).double()
    renders[1, 0, 0] = 0.3
    renders[2, 0, 0] = (0.3 + 1e-3) * math.exp(0.25 * 2) - 1e-3
    counts[1, :, 0, 0] = torch.tensor([2.0, 0.0])
    grads = []
    for fn in (event_loss, _event_loss_torch):
        x = renders.clone().requires_grad_(True)
        log_c = torch.log(torch.tensor([0.25, 0.18], dtype=torch.float64)).requires_grad_(True)
        loss = fn(x, counts, torch.exp(log_c), 1e-3, norm)
        loss.backward()
        grads.append((loss.detach(), x.grad, log_c.grad))
    (l0, gx0, gc0), (l1, gx1, gc1) = grads
    assert torch.allclose(l0, l1, rtol=1e-12, atol=0)
    assert torch.allclose(gx0, gx1, rtol=1e-10, atol=1e-14)
    assert torch.allclose(gc0, gc1, rtol=1e-10, atol=1e-14)
    dark = luminance(renders)[..., 0] < 0  # clamped: no gradient to any channel there
    assert dark.any() and (gx0[dark] == 0).all() and (gx0[~dark] != 0).any()
    # one threshold for both polarities: its gradient is the sum of the two
    c1 = torch.tensor([0.2], dtype=torch.float64, requires_grad=True)
    c2 = torch.tensor([0.2], dtype=torch.float64, requires_grad=True)
    event_loss(renders, counts, c1, 1e-3, norm).backward()
    _event_loss_torch(renders, counts, c2, 1e-3, norm).backward()
    assert torch.allclose(c1.grad, c2.grad, rtol=1e-10)


def test_event_loss_float32_close_to_float64_and_gradcheck():
    g = torch.Generator().manual_seed(4)
    renders = torch.rand(3, 20, 17, 1, generator=g, dtype=torch.float64) * 0.9 + 0.05
    counts = torch.randint(0, 3, (2, 2, 20, 17), generator=g).double()
    x32 = renders.float().requires_grad_(True)
    l32 = event_loss(x32, counts.float(), (0.22, 0.19), norm="l2")
    l32.backward()
    x64 = renders.clone().requires_grad_(True)
    l64 = event_loss(x64, counts, (0.22, 0.19), norm="l2")
    l64.backward()
    assert l32.dtype == torch.float32 and x32.grad.dtype == torch.float32
    assert float(l32.detach()) == pytest.approx(float(l64.detach()), rel=1e-5)
    assert torch.allclose(x32.grad.double(), x64.grad, rtol=1e-4, atol=1e-9)
    c = torch.tensor([0.22, 0.19], dtype=torch.float64, requires_grad=True)
    x = (renders[:, :6, :5]).clone().requires_grad_(True)
    torch.autograd.gradcheck(lambda x, c: event_loss(x, counts[:, :, :6, :5], c, norm="l2"), (x, c))


@pytest.mark.parametrize("D", [1, 3])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("edi", ["views", "mid", "none"])
@pytest.mark.parametrize("windows", ["consecutive", "pair", "none"])
def test_exposure_losses_in_one_node_equal_the_three_losses_composed(D, dtype, edi, windows):
    """exposure_losses against blur_loss + edi_loss + event_loss: values, the gradient of the
    renders and of both thresholds, and the mean render."""
    from ebad.losses import exposure_losses

    gen = torch.Generator().manual_seed(3)
    V, H, W = 4, 17, 23
    Vp = V + 1 if edi == "mid" else V  # an even V renders its mid-exposure view last
    img = (torch.rand(Vp, H, W, D, generator=gen, dtype=dtype) * 0.9 + 0.05).requires_grad_()
    blurry = torch.rand(H, W, D, generator=gen, dtype=dtype)
    lat = {
        "views": torch.rand(V, H, W, D, generator=gen, dtype=dtype),
        "mid": torch.rand(H, W, D, generator=gen, dtype=dtype),
        "none": None,
    }[edi]
    ev = {"consecutive": list(range(V)), "pair": [1, 3], "none": []}[windows]
    counts = torch.randint(0, 3, (len(ev) - 1, 2, H, W), generator=gen).to(dtype) if ev else None
    c = torch.tensor([0.21, 0.17], dtype=dtype, requires_grad=True)
    blur, e, v, mean = exposure_losses(img, V, blurry, lat, V if edi == "mid" else None, counts, ev, c)
    assert (e is None) == (lat is None) and (v is None) == (not ev)
    total = 0.7 * blur + (1.3 * e if e is not None else 0) + (0.4 * v if v is not None else 0)
    g_img, g_c = torch.autograd.grad(total, (img, c), allow_unused=True)

    blur2 = blur_loss(img[:V], blurry)
    e2 = None if lat is None else edi_loss(img[:V] if edi == "views" else img[V], lat)
    v2 = event_loss(img[ev], counts, c) if ev else None
    total2 = 0.7 * blur2 + (1.3 * e2 if e2 is not None else 0) + (0.4 * v2 if v2 is not None else 0)
    g_img2, g_c2 = torch.autograd.grad(total2, (img, c), allow_unused=True)
    tol = dict(rtol=1e-5, atol=1e-7) if dtype == torch.float32 else dict(rtol=1e-12, atol=1e-14)
    for a, b in ((blur, blur2), (e, e2), (v, v2)):
        assert (a is None and b is None) or torch.allclose(a, b, **tol)
    assert torch.allclose(g_img, g_img2, **tol)
    assert (g_c is None and g_c2 is None) or torch.allclose(g_c, g_c2, **tol)
    assert torch.allclose(mean, img[:V].mean(0).detach(), **tol) and not mean.requires_grad


def test_the_kernels_run_on_cpu_tensors_and_the_reference_inside_torch_reference():
    # the one dispatch (ebad.kernels.use_kernels): if it took the reference on the CPU, every
    # comparison above would compare the reference with itself
    from ebad.kernels import torch_reference, use_kernels
    from ebad.losses import exposure_losses, l1_ssim_each

    a = torch.rand(1, 9, 8, 1, requires_grad=True)
    b = torch.rand(1, 9, 8, 1)
    counts = torch.ones(1, 2, 9, 8)

    def nodes():
        return {
            "ssim_map": ssim_map(a, b).grad_fn,
            "l1_ssim": l1_ssim(a, b).grad_fn,
            "l1_ssim_each": l1_ssim_each([(a, b), (a, b)])[1].grad_fn,
            "event_loss": event_loss(torch.cat([a, b]), counts, 0.2).grad_fn,
            "exposure_losses": exposure_losses(torch.cat([a, b]), 2, b[0], counts=counts, event_views=[0, 1])[
                0
            ].grad_fn,
        }

    def kernel_node(fn) -> bool:  # a node of ebad.kernels.losses' autograd Functions (or a view of one)
        while fn is not None:
            if type(fn).__name__.startswith(("_FusedSSIM", "_FusedL1SSIM", "_EventLoss", "_ExposureLosses")):
                return True
            fn = fn.next_functions[0][0] if fn.next_functions else None
        return False

    assert use_kernels(a, None, b) and not use_kernels(a, torch.empty(1, device="meta"))
    assert all(kernel_node(fn) for fn in nodes().values()), nodes()
    with torch_reference():
        assert not use_kernels(a)
        assert not any(kernel_node(fn) for fn in nodes().values()), nodes()
    assert use_kernels(a)  # restored


def _value_and_grads(fn, *inputs):
    """fn(*inputs) and the gradients of a fixed random weighting of its outputs to every input."""
    inputs = [x.detach().clone().requires_grad_() for x in inputs]
    out = fn(*inputs)
    outs = [o for o in (out if isinstance(out, (list, tuple)) else [out]) if o is not None and o.requires_grad]
    g = torch.Generator().manual_seed(9)
    total = sum((torch.rand(o.shape, generator=g, dtype=o.dtype) * o).sum() for o in outs)
    return [o.detach() for o in outs], torch.autograd.grad(total, inputs, allow_unused=True)


def _kernels_and_reference(fn, *inputs):
    from ebad.kernels import torch_reference

    fast = _value_and_grads(fn, *inputs)
    with torch_reference():
        ref = _value_and_grads(fn, *inputs)
    return fast, ref


@pytest.mark.parametrize("shape,window", [((2, 20, 24, 3), 7), ((1, 30, 17, 1), 11), ((1, 4, 6, 1), 7)])
def test_the_ssim_reference_of_ebad_losses_equals_the_kernels(shape, window):
    # ebad.losses' own reference path (kornia's SSIM in [B, H, W, D]), reached through the public
    # functions, against the kernels: the map, l1_ssim and l1_ssim_each, values and gradients
    from ebad.losses import l1_ssim_each

    g = torch.Generator().manual_seed(12)
    a = torch.rand(shape, generator=g, dtype=torch.float64)
    b = (a + 0.3 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    c = torch.rand(shape, generator=g, dtype=torch.float64)
    cases = [
        (lambda x, y: ssim_map(x, y, window), a, b),
        (lambda x, y: l1_ssim(x, y, 0.3, window), a, b),
        (lambda x, y, z: l1_ssim_each([(x, y), (z[:1], y[:1])], 0.2, window), a, b, c),
    ]
    for fn, *inputs in cases:
        (v_fast, g_fast), (v_ref, g_ref) = _kernels_and_reference(fn, *inputs)
        for x, y in zip(v_fast, v_ref):
            assert torch.allclose(x, y, rtol=0, atol=1e-9)
        for x, y in zip(g_fast, g_ref):
            assert torch.allclose(x, y, rtol=1e-7, atol=1e-10)
        assert len(v_fast) == len(v_ref) > 0


@pytest.mark.parametrize("norm", ["l1", "l2"])
@pytest.mark.parametrize("D", [1, 3])
def test_the_event_loss_reference_of_ebad_losses_equals_the_kernel(norm, D):
    g = torch.Generator().manual_seed(13)
    renders = torch.rand(4, 19, 11, D, generator=g, dtype=torch.float64) * 1.2 - 0.1  # some clamped
    counts = torch.randint(0, 4, (3, 2, 19, 11), generator=g).double()
    c = torch.tensor([0.23, 0.17], dtype=torch.float64)
    (v_fast, g_fast), (v_ref, g_ref) = _kernels_and_reference(
        lambda x, cc: event_loss(x, counts, cc, 1e-3, norm), renders, c
    )
    assert torch.allclose(v_fast[0], v_ref[0], rtol=1e-12, atol=0)
    for x, y in zip(g_fast, g_ref):
        assert torch.allclose(x, y, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("edi", ["views", "mid", "none"])
@pytest.mark.parametrize("windows", ["consecutive", "pair", "none"])
def test_the_exposure_losses_reference_is_the_three_losses_composed_and_equals_the_kernels(edi, windows):
    from ebad.kernels import torch_reference
    from ebad.losses import exposure_losses

    gen = torch.Generator().manual_seed(14)
    V, H, W, D = 4, 13, 21, 3
    Vp = V + 1 if edi == "mid" else V
    img = torch.rand(Vp, H, W, D, generator=gen, dtype=torch.float64) * 0.9 + 0.05
    blurry = torch.rand(H, W, D, generator=gen, dtype=torch.float64)
    lat = {
        "views": torch.rand(V, H, W, D, generator=gen, dtype=torch.float64),
        "mid": torch.rand(H, W, D, generator=gen, dtype=torch.float64),
        "none": None,
    }[edi]
    ev = {"consecutive": list(range(V)), "pair": [0, 2], "none": []}[windows]
    counts = torch.randint(0, 3, (len(ev) - 1, 2, H, W), generator=gen).double() if ev else None
    c = torch.tensor([0.21, 0.17], dtype=torch.float64)

    def fn(x, cc):
        blur, e, v, mean = exposure_losses(x, V, blurry, lat, V if edi == "mid" else None, counts, ev, cc)
        assert (e is None) == (lat is None) and (v is None) == (not ev) and not mean.requires_grad
        assert torch.allclose(mean, x[:V].mean(0), rtol=1e-15, atol=0)
        return blur, e, v

    (v_fast, g_fast), (v_ref, g_ref) = _kernels_and_reference(fn, img, c)
    for x, y in zip(v_fast, v_ref):
        assert torch.allclose(x, y, rtol=1e-10, atol=1e-12)
    for x, y in zip(g_fast, g_ref):
        assert (x is None and y is None) or torch.allclose(x, y, rtol=1e-7, atol=1e-12)
    with torch_reference():  # the reference is the composition itself, to the last digit
        composed = [blur_loss(img[:V], blurry)]
        if lat is not None:
            composed.append(edi_loss(img[:V] if edi == "views" else img[V], lat))
        if ev:
            composed.append(event_loss(img[ev], counts, c))
        assert all(torch.equal(x, y) for x, y in zip(v_ref, composed))
