"""ebad.losses: known values, the losses' SSIM pinned to kornia's, bad inputs (the kernels against the
reference: tests/ebad/kernels)."""

from __future__ import annotations

import math

import pytest
import torch

from ebad.losses import blur_loss, edi_loss, event_loss, l1_ssim, luminance, ssim_map


def test_losses_known_values():
    a = torch.full((8, 8, 1), 0.5)
    assert float(l1_ssim(a, a)) == pytest.approx(0.0, abs=1e-6)
    b = a + 0.1
    assert float(l1_ssim(b, a, ssim_weight=0.0)) == pytest.approx(0.1, abs=1e-6)
    renders = torch.stack([torch.full((8, 8, 1), v) for v in (0.2, 0.4, 0.6)])
    assert float(blur_loss(renders, torch.full((8, 8, 1), 0.4))) == pytest.approx(0.0, abs=1e-5)
    assert float(edi_loss(b[..., :], b)) == pytest.approx(0.0, abs=1e-6)
    # events matching the log ratio exactly give zero L_ev; one event short gives c
    c, eps = 0.2, 1e-3
    I0 = torch.full((4, 4, 1), 0.3)
    I1 = (I0 + eps) * math.exp(2 * c) - eps
    E = torch.zeros(1, 2, 4, 4)
    E[:, 0] = 2.0  # two ON events
    assert float(event_loss(torch.stack([I0, I1]), E, c, eps)) == pytest.approx(0.0, abs=1e-5)
    short = E.clone()
    short[:, 0] = 1.0
    assert float(event_loss(torch.stack([I0, I1]), short, c, eps)) == pytest.approx(c, abs=1e-5)
    # separate thresholds: three ON at 0.3 and two OFF at 0.2 are a rise of 0.5
    I2 = (I0 + eps) * math.exp(0.5) - eps
    mixed = torch.zeros(1, 2, 4, 4)
    mixed[:, 0], mixed[:, 1] = 3.0, 2.0
    assert float(event_loss(torch.stack([I0, I2]), mixed, (0.3, 0.2), eps)) == pytest.approx(0.0, abs=1e-5)
    assert float(event_loss(torch.stack([I0, I2]), mixed, 0.3, eps)) == pytest.approx(
        0.2, abs=1e-5
    )  # 0.9 - 0.6 predicted
    with pytest.raises(ValueError, match="counts"):
        event_loss(torch.stack([I0, I1]), torch.zeros(2, 4, 4), c)


@pytest.mark.parametrize("reference", [False, True])
def test_the_losses_ssim_is_kornias_with_a_7_pixel_window(reference):
    # kornia.metrics.ssim called here on a fixed pair with the 7-pixel window of the paper's L_EDI:
    # the kernels and ebad.losses' reference share the window-size rule (_window_for), so they
    # agree with each other whatever it gives; this pins both to the window they should use
    import contextlib

    from kornia.metrics import ssim as kornia_ssim

    from ebad.kernels import torch_reference

    g = torch.Generator().manual_seed(21)
    a = torch.rand(2, 1, 36, 44, generator=g, dtype=torch.float64)  # [B, D, H, W], kornia's layout
    b = (a + 0.25 * torch.randn(2, 1, 36, 44, generator=g, dtype=torch.float64)).clamp(0, 1)
    truth = kornia_ssim(a, b, 7)
    l1 = float((a - b).abs().mean())
    pred, target = a.permute(0, 2, 3, 1), b.permute(0, 2, 3, 1)  # [B, H, W, D]
    with torch_reference() if reference else contextlib.nullcontext():
        assert torch.allclose(ssim_map(pred, target), truth.permute(0, 2, 3, 1), rtol=0, atol=1e-9)
        assert float(l1_ssim(pred, target)) == pytest.approx(0.8 * l1 + 0.2 * (1 - float(truth.mean())), abs=1e-12)
        assert float(edi_loss(pred, target)) == pytest.approx(0.8 * l1 + 0.2 * (1 - float(truth.mean())), abs=1e-12)
        blurry = target[0]
        assert float(blur_loss(pred[:1], blurry)) == pytest.approx(
            0.8 * float((a[0] - b[0]).abs().mean()) + 0.2 * (1 - float(truth[0].mean())), abs=1e-12
        )


def test_luminance_grey_passthrough_and_rgb():
    g = torch.rand(3, 4, 1, generator=torch.Generator().manual_seed(3))
    assert torch.equal(luminance(g), g)
    rgb = torch.ones(2, 2, 3)
    assert torch.allclose(luminance(rgb), torch.ones(2, 2, 1))
    with pytest.raises(ValueError, match="D = 1 or 3"):
        luminance(torch.ones(2, 2, 2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_event_loss_l2_is_the_mean_squared_residual_and_l1_the_mean_absolute(seed):
    g = torch.Generator().manual_seed(seed)
    renders = torch.rand(4, 5, 6, 1, generator=g)
    counts = torch.randint(0, 4, (3, 2, 5, 6), generator=g).float()
    c = (0.25, 0.18)
    logL = torch.log(renders[..., 0] + 1e-3).double()
    r = logL[1:] - logL[:-1] - (c[0] * counts[:, 0] - c[1] * counts[:, 1]).double()
    assert float(event_loss(renders, counts, c, norm="l2")) == pytest.approx(float(r.square().mean()), rel=1e-5)
    assert float(event_loss(renders, counts, c, norm="l1")) == pytest.approx(float(r.abs().mean()), rel=1e-5)
    assert float(event_loss(renders, counts, c)) == float(event_loss(renders, counts, c, norm="l1"))  # default
    with pytest.raises(ValueError, match="norm"):
        event_loss(renders, counts, c, norm="l3")


def test_event_loss_of_one_window_compares_its_two_instants_with_the_summed_counts():
    from ebad.virtual_views import window_counts

    c, eps = 0.2, 1e-3
    I0 = torch.full((4, 4, 1), 0.3)
    rises = [1.0, 2.0, -1.0]  # ON, ON ON, OFF between the four instants
    renders = torch.stack([(I0 + eps) * math.exp(c * sum(rises[:k])) - eps for k in range(4)])
    counts = torch.zeros(3, 2, 4, 4)
    for k, n in enumerate(rises):
        counts[k, 0 if n > 0 else 1] = abs(n)
    for i, j in [(0, 1), (0, 2), (1, 3), (0, 3)]:
        assert float(event_loss(renders[[i, j]], window_counts(counts, i, j), c, eps)) == pytest.approx(0.0, abs=1e-5)
    # the window (0, 3) with one ON event dropped from its middle: off by c
    short = counts.clone()
    short[1, 0] = 1.0
    assert float(event_loss(renders[[0, 3]], window_counts(short, 0, 3), c, eps, norm="l1")) == pytest.approx(
        c, abs=1e-5
    )
    assert float(event_loss(renders[[0, 3]], window_counts(short, 0, 3), c, eps, norm="l2")) == pytest.approx(
        c * c, abs=1e-5
    )


def test_exposure_losses_refuse_mismatched_inputs_naming_them():
    from ebad.losses import exposure_losses

    img = torch.rand(3, 8, 9, 1, requires_grad=True)
    with pytest.raises(ValueError, match="blurry must be"):
        exposure_losses(img, 3, torch.rand(8, 9, 3))
    with pytest.raises(ValueError, match="latents must be"):
        exposure_losses(img, 3, torch.rand(8, 9, 1), torch.rand(2, 8, 9, 1))
    with pytest.raises(ValueError, match="mid must index"):
        exposure_losses(img, 3, torch.rand(8, 9, 1), torch.rand(8, 9, 1), mid=3)
    with pytest.raises(ValueError, match="counts must be"):
        exposure_losses(img, 3, torch.rand(8, 9, 1), counts=torch.rand(1, 2, 8, 9), event_views=[0, 1, 2])
    with pytest.raises(ValueError, match="event_views must be distinct"):
        exposure_losses(img, 3, torch.rand(8, 9, 1), counts=torch.rand(1, 2, 8, 9), event_views=[1, 1])
    with pytest.raises(ValueError, match="V must be in"):
        exposure_losses(img, 4, torch.rand(8, 9, 1))
