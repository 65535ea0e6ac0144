"""The losses of a colour DAVIS capture (``cfa``): L_ev on each pixel's own channel of the render,
L_blur and L_EDI against raw mosaics through ``cfa_project``; kernels against the torch reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebad.kernels import torch_reference
from ebad.losses import blur_loss, cfa_project, cfa_weights, edi_loss, event_loss, exposure_losses
from edi.cfa import channel_map, mosaic


def test_cfa_weights_are_one_hot_at_full_size_and_block_fractions_when_pooled():
    F = cfa_weights("GRBG", 6, 8)
    assert F.shape == (6, 8, 3)
    assert np.array_equal(F.argmax(-1).numpy(), channel_map("GRBG", 6, 8)) and torch.equal(F.sum(-1), torch.ones(6, 8))
    for s in (2, 4):
        Fs = cfa_weights("RGGB", 16, 24, s)
        assert Fs.shape == (16 // s, 24 // s, 3)
        assert torch.allclose(Fs, torch.tensor([0.25, 0.5, 0.25]).expand_as(Fs))
    img = torch.rand(2, 6, 8, 3, dtype=torch.float64)
    assert torch.equal(cfa_project(img, F.double())[..., 0], mosaic(img, "GRBG"))  # the render's mosaic


@pytest.mark.parametrize("norm", ["l1", "l2"])
@pytest.mark.parametrize("factor", [1, 2])
def test_cfa_event_loss_kernel_equals_reference_in_value_and_gradients(norm, factor):
    g = torch.Generator().manual_seed(21)
    H, W = 37, 10  # more rows than one band of the kernel
    F = cfa_weights("BGGR", H * factor, W * factor, factor, torch.float64)
    renders = torch.rand(4, H, W, 3, generator=g, dtype=torch.float64) * 1.2 - 0.1  # some clamped channels
    counts = torch.randint(0, 4, (3, 2, H, W), generator=g).double()
    c = torch.tensor([0.23, 0.17], dtype=torch.float64)

    def vg():
        x, cc = renders.clone().requires_grad_(), c.clone().requires_grad_()
        loss = event_loss(x, counts, cc, 1e-3, norm, cfa=F)
        return (loss.detach(), *torch.autograd.grad(loss, (x, cc)))

    fast = vg()
    with torch_reference():
        ref = vg()
    assert torch.allclose(fast[0], ref[0], rtol=1e-12, atol=0)
    for x, y in zip(fast[1:], ref[1:]):
        assert torch.allclose(x, y, rtol=1e-10, atol=1e-14)
    gx = fast[1]
    assert (gx[renders < 0] == 0).all()
    if factor == 1:  # a channel the pixel does not see gets no gradient
        assert (gx[:, F == 0] == 0).all() and (gx[:, (F == 1) & (renders[0] > 0)] != 0).any()


def test_cfa_event_loss_gradcheck_kernel_and_float32():
    g = torch.Generator().manual_seed(22)
    F = cfa_weights("RGGB", 12, 10, 2, torch.float64)  # pooled fractions [6, 5, 3]
    x = (torch.rand(3, 6, 5, 3, generator=g, dtype=torch.float64) * 0.9 + 0.05).requires_grad_()
    counts = torch.randint(0, 3, (2, 2, 6, 5), generator=g).double()
    c = torch.tensor([0.22, 0.19], dtype=torch.float64, requires_grad=True)
    torch.autograd.gradcheck(lambda x, c: event_loss(x, counts, c, norm="l2", cfa=F), (x, c))
    x32 = x.detach().float().requires_grad_()
    l32 = event_loss(x32, counts.float(), (0.22, 0.19), norm="l2", cfa=F.float())
    l32.backward()
    x64 = x.detach().clone().requires_grad_()
    l64 = event_loss(x64, counts, (0.22, 0.19), norm="l2", cfa=F)
    l64.backward()
    assert l32.dtype == torch.float32 and float(l32.detach()) == pytest.approx(float(l64.detach()), rel=1e-5)
    assert torch.allclose(x32.grad.double(), x64.grad, rtol=1e-4, atol=1e-9)


def test_cfa_event_loss_at_full_size_is_the_grey_loss_of_the_render_mosaic():
    g = torch.Generator().manual_seed(23)
    renders = torch.rand(4, 9, 12, 3, generator=g, dtype=torch.float64) + 0.05
    counts = torch.randint(0, 3, (3, 2, 9, 12), generator=g).double()
    grey = mosaic(renders, "GBRG")[..., None]
    a = event_loss(renders, counts, 0.2, cfa=cfa_weights("GBRG", 9, 12, dtype=torch.float64))
    assert torch.allclose(a, event_loss(grey, counts, 0.2), rtol=1e-13, atol=0)


def _bayer_world(factor: int):
    """Renders [3, H, W, 3] whose channels change differently (R up, G still, B down by whole thresholds),
    constant over factor x factor blocks, and the sensor's exact counts per pixel at full size."""
    c = 0.2
    H, W = 8 * factor, 10 * factor
    g = torch.Generator().manual_seed(24)
    base = (
        (torch.rand(H // factor, W // factor, 3, generator=g, dtype=torch.float64) * 0.5 + 0.2)
        .repeat_interleave(factor, 0)
        .repeat_interleave(factor, 1)
    )
    steps = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, -1.0], [3.0, 1.0, -3.0]], dtype=torch.float64)  # events
    irr = base[None] * torch.exp(c * steps[:, None, None, :])  # [3, H, W, 3], log steps of whole thresholds
    own = mosaic(irr, "RGGB")  # [3, H, W]: what each sensor pixel sees
    dl = torch.log(own[1:]) - torch.log(own[:-1])
    counts = torch.stack([(dl / c).clamp_min(0), (-dl / c).clamp_min(0)], 1).round()  # [2, 2, H, W]
    return irr, counts, c


def test_cfa_event_loss_is_zero_on_the_sensors_own_events_and_luminance_is_not():
    irr, counts, c = _bayer_world(1)
    H, W = irr.shape[1:3]
    F = cfa_weights("RGGB", H, W, dtype=torch.float64)
    eps = 1e-9
    assert float(event_loss(irr, counts, c, eps, cfa=F)) == pytest.approx(0.0, abs=1e-8)
    # today's model (events of the channel mean) cannot explain them
    assert float(event_loss(irr, counts, c, eps)) == pytest.approx(0.2047, abs=1e-3)
    assert float(event_loss(irr, counts, c, eps, cfa=cfa_weights("BGGR", H, W, dtype=torch.float64))) > 0.2


@pytest.mark.parametrize("factor", [2, 4])
def test_pooled_cfa_event_loss_compares_the_blocks_mean_count_with_its_channel_fractions(factor):
    # ebad.data.downscale pools counts as the mean per sensor pixel of a block: with the block's channel
    # fractions (1/4 R, 1/2 G, 1/4 B) the loss of the pooled render is exactly 0 on exact events
    irr, counts, c = _bayer_world(factor)
    H, W = irr.shape[1:3]
    pool = torch.nn.functional.avg_pool2d
    counts_s = pool(counts.reshape(-1, 1, H, W), factor).reshape(2, 2, H // factor, W // factor)
    irr_s = irr[:, ::factor, ::factor]  # blocks are constant
    Fs = cfa_weights("RGGB", H, W, factor, torch.float64)
    for use_ref in (False, True):
        with torch_reference() if use_ref else torch.enable_grad():
            assert float(event_loss(irr_s, counts_s, c, 1e-9, cfa=Fs)) == pytest.approx(0.0, abs=1e-8)
    # the channel mean of the block does not explain its mean count
    lum = float(event_loss(irr_s, counts_s, c, 1e-9))
    assert lum == pytest.approx(0.0465, abs=1e-3)


@pytest.mark.parametrize("raw", [True, False])
@pytest.mark.parametrize("edi", ["views", "mid", "none"])
@pytest.mark.parametrize("windows", ["consecutive", "pair"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_cfa_exposure_losses_equal_the_losses_composed_and_the_reference(raw, edi, windows, dtype):
    gen = torch.Generator().manual_seed(25)
    V, H, W = 4, 17, 22
    Vp = V + 1 if edi == "mid" else V
    Dt = 1 if raw else 3
    F = cfa_weights("GRBG", 2 * H, 2 * W, 2, dtype) if windows == "pair" else cfa_weights("GRBG", H, W, dtype=dtype)
    img = torch.rand(Vp, H, W, 3, generator=gen, dtype=dtype) * 0.9 + 0.05
    blurry = torch.rand(H, W, Dt, generator=gen, dtype=dtype)
    lat = {
        "views": torch.rand(V, H, W, Dt, generator=gen, dtype=dtype),
        "mid": torch.rand(H, W, Dt, generator=gen, dtype=dtype),
        "none": None,
    }[edi]
    ev = {"consecutive": list(range(V)), "pair": [1, 3]}[windows]
    counts = torch.randint(0, 3, (len(ev) - 1, 2, H, W), generator=gen).to(dtype)
    mid = V if edi == "mid" else None

    def run(x, cc):
        blur, e, v, mean = exposure_losses(x, V, blurry, lat, mid, counts, ev, cc, cfa=F)
        assert mean.shape == (H, W, Dt) and not mean.requires_grad
        return [t for t in (blur, e, v) if t is not None], mean

    def composed(x, cc):
        cmp = cfa_project(x, F) if raw else x
        out = [blur_loss(cmp[:V], blurry)]
        if lat is not None:
            out.append(edi_loss(cmp[:V] if edi == "views" else cmp[V], lat))
        out.append(event_loss(x[ev], counts, cc, cfa=F))
        return out, cmp[:V].mean(0)

    tol = dict(rtol=1e-5, atol=1e-7) if dtype == torch.float32 else dict(rtol=1e-10, atol=1e-12)
    results = []
    for fn, ref in ((run, False), (run, True), (composed, False)):
        x = img.clone().requires_grad_()
        cc = torch.tensor([0.21, 0.17], dtype=dtype, requires_grad=True)
        with torch_reference() if ref else torch.enable_grad():
            losses, mean = fn(x, cc)
            total = sum(w * t for w, t in zip((0.7, 1.3, 0.4), losses))
            results.append((losses, mean.detach(), *torch.autograd.grad(total, (x, cc))))
    (l0, m0, gx0, gc0) = results[0]
    for l1, m1, gx1, gc1 in results[1:]:
        assert len(l0) == len(l1) and all(torch.allclose(a, b, **tol) for a, b in zip(l0, l1))
        assert torch.allclose(m0, m1, **tol)
        assert torch.allclose(gx0, gx1, **tol) and torch.allclose(gc0, gc1, **tol)


def test_cfa_exposure_losses_refuse_grey_renders_and_misshapen_weights():
    img = torch.rand(2, 6, 8, 1, dtype=torch.float64)
    with pytest.raises(ValueError, match="colour renders"):
        exposure_losses(img, 2, img[0], cfa=cfa_weights("RGGB", 6, 8, dtype=torch.float64))
    img3 = torch.rand(2, 6, 8, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"cfa must be \[H, W, 3\]"):
        event_loss(img3, torch.zeros(1, 2, 6, 8), 0.2, cfa=cfa_weights("RGGB", 12, 16, dtype=torch.float64))
    assert math.isfinite(float(exposure_losses(img3, 2, img3[0, ..., :1], cfa=cfa_weights("RGGB", 6, 8))[0]))
