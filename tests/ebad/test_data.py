"""``ebad.data.downscale`` and the coarse phase of training (``train.coarse_scale``)."""
from __future__ import annotations

import pytest
import torch

import scenes
from ebad.config import preset
from ebad.data import downscale, prepare
from ebad.gaussians import render
from ebad.trainer import coarse_data, reconstruct


@pytest.fixture(scope="module")
def tiny_data():
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    return prepare(sc.capture, preset("ebad"))


def test_downscale_averages_blocks_and_scales_intrinsics(tiny_data):
    d = tiny_data
    h = downscale(d, 2)
    assert (h.height, h.width) == (d.height // 2, d.width // 2)
    assert torch.allclose(h.targets.mean(), d.targets.mean(), atol=1e-6)  # 64 x 48 is divisible by 2
    assert torch.allclose(h.targets[0, 0, 0], d.targets[0, :2, :2].mean((0, 1)))
    assert torch.allclose(h.K[:2], d.K[:2] / 2) and torch.equal(h.K[2], d.K[2])
    f = next(i for i, e in enumerate(d.ev_counts) if e is not None)
    assert torch.allclose(h.ev_counts[f].sum() * 4, d.ev_counts[f].sum(), rtol=1e-5)  # mean count per pixel
    assert h.ev_counts[f].shape[-2:] == (h.height, h.width)
    assert downscale(d, 1) is d
    with pytest.raises(ValueError, match="cannot downscale"):
        downscale(d, 8)


def test_a_render_at_the_scaled_intrinsics_is_the_block_average_of_the_full_render(tiny_data):
    """The pixel-centre convention: rendering at K / 2 on half the pixels matches 2 x 2 averages
    of the full render where the image is smooth (wide Gaussians)."""
    d = tiny_data
    g = torch.Generator().manual_seed(0)
    n = 40
    cam = d.c2w[0]
    depth = 0.5 * (d.depth_range[0] + d.depth_range[1])
    pts_cam = torch.cat([(torch.rand(n, 2, generator=g) - 0.5) * depth * 0.8, torch.full((n, 1), depth)], 1)
    means = pts_cam @ cam[:3, :3].T + cam[:3, 3]
    params = {"means": means, "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
              "scales": torch.full((n, 3), float(torch.log(torch.tensor(depth * 0.12)))),
              "opacities": torch.full((n,), 0.0), "colors": torch.rand(n, 1, generator=g)}
    full, _, _ = render(params, cam[None], d.K, d.width, d.height)
    h = downscale(d, 2)
    half, _, _ = render(params, cam[None], h.K, h.width, h.height)
    pooled = torch.nn.functional.avg_pool2d(full[0].permute(2, 0, 1), 2).permute(1, 2, 0)
    assert (half[0] - pooled).abs().max() < 0.02 * float(full.max())
    shifted = torch.roll(pooled, 1, dims=1)  # a half-pixel convention error shows as a shift
    assert (half[0] - pooled).abs().mean() < 0.5 * (half[0] - shifted).abs().mean()


def test_coarse_phase_trains_the_first_part_at_the_coarse_size_then_full_size():
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 10, False, 0
    cfg.train.coarse_scale, cfg.train.coarse_until = 2, 0.4
    run = reconstruct(sc.capture, cfg)
    widths = [h.width for h in run.history]
    assert widths == [32] * 4 + [64] * 6
    cfg.train.coarse_scale = 1
    assert [h.width for h in reconstruct(sc.capture, cfg).history] == [64] * 10
    cfg.train.coarse_scale = 8  # 8 x 6 pixels: too small to train on, so no coarse phase
    assert coarse_data(prepare(sc.capture, cfg), cfg) is None
