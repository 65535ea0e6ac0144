"""``ebad.data.downscale`` and the coarse phase of training (``train.coarse_scale``)."""

from __future__ import annotations

import pytest
import torch

import scenes
from ebad.config import preset
from ebad.data import downscale, prepare
from ebad.gaussians import render
from ebad.loop import coarse_data
from ebad.run import reconstruct


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
    params = {
        "means": means,
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "scales": torch.full((n, 3), float(torch.log(torch.tensor(depth * 0.12)))),
        "opacities": torch.full((n,), 0.0),
        "colors": torch.rand(n, 1, generator=g),
    }
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


def test_set_views_counts_the_events_again_between_the_new_instants(tiny_data):
    import copy

    import numpy as np

    from ebad.virtual_views import event_counts

    d = copy.copy(tiny_data)
    d.report = copy.copy(tiny_data.report)
    blurry = np.flatnonzero(d.V > 1)
    assert len(blurry) and d.events is not None
    V = d.V.copy()
    V[blurry[0]] = 3
    d.set_views(V)
    f = int(blurry[0])
    assert d.V[f] == 3 and d.report.views[f] == 3 and d.report.renders_per_pass == int(V.sum())
    assert torch.equal(d.ev_counts[f], event_counts(d.events, d.exposures[f], 3))
    assert d.ev_counts[f].sum() < tiny_data.ev_counts[f].sum()  # 2 of 3 windows span less of the exposure than 4 of 5
    assert tiny_data.V[f] == 5 and tiny_data.ev_counts[f].shape[0] == 4  # the original is untouched
    bad = V.copy()
    bad[f] = 1
    with pytest.raises(ValueError, match="sharp"):
        d.set_views(bad)


def test_views_from_the_blur_length_take_effect_where_the_coarse_phase_ends(monkeypatch):
    import ebad.loop as T
    from ebad.errors import ConfigError

    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 8, False, 0
    cfg.train.coarse_until = 0.5
    cfg.loss.edi_instants = "mid"  # an even V then renders the mid view as well
    cameras, in_step = [], []  # cameras of each training step's render
    inner_render, inner_losses = T.render, T.frame_losses

    def counting_render(params, c2w, *args, **kwargs):
        if in_step:
            cameras.append(int(c2w.shape[0]))
        return inner_render(params, c2w, *args, **kwargs)

    def step_losses(*args, **kwargs):
        in_step.append(True)
        try:
            return inner_losses(*args, **kwargs)
        finally:
            in_step.clear()

    monkeypatch.setattr(T, "render", counting_render)
    monkeypatch.setattr(T, "frame_losses", step_losses)
    runs, per_step = {}, {}
    for spacing in (1e6, 1e-6):  # any blur is longer than 1e-6 pixels and shorter than 1e6
        cfg.trajectory.view_spacing = spacing
        cameras.clear()
        runs[spacing] = reconstruct(sc.capture, cfg)
        per_step[spacing] = list(cameras)
    assert (runs[1e6].V > 1).all()  # every frame of this scene is blurry
    assert runs[1e6].V.tolist() == [2] * 4 and runs[1e-6].V.tolist() == [cfg.trajectory.max_views] * 4
    assert runs[1e6].metrics.prepare.views == [2] * 4
    # 4 steps at the configured V = 5, then V = 2 (+ the mid view L_EDI needs when V is even) or 9
    assert per_step[1e6] == [5] * 4 + [3] * 4 and per_step[1e-6] == [5] * 4 + [9] * 4
    cfg.loss.edi_instants, cfg.trajectory.view_spacing = "views", 1e6  # every view has its latent: no extra mid view
    cameras.clear()
    reconstruct(sc.capture, cfg)
    assert cameras == [5] * 4 + [2] * 4
    cfg.train.coarse_until = 0.0
    with pytest.raises(ConfigError, match="view_spacing"):
        cfg.check()
