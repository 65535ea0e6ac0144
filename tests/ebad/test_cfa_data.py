"""A colour DAVIS capture (``Capture.cfa``) through ``prepare``, ``downscale`` and one training step:
the model renders RGB whatever the frames, L_ev sees each pixel's own channel, raw frames compare
the render's mosaic."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebad.config import preset
from ebad.data import downscale, prepare
from ebad.gaussians import render
from ebad.loop import frame_losses
from ebad.losses import cfa_project, cfa_weights, event_loss, exposure_losses
from ebad.state import TrainState
from ebad.trajectory import virtual_instants
from edi import EventStream
from edi.cfa import channel_map, mosaic
from scenes import Capture

H, W, F = 24, 32, 3


def _capture(raw: bool, pattern: str | None = "GRBG") -> Capture:
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0.2, 0.8, (F, H, W, 3)).astype(np.float32)
    frames = mosaic(rgb, pattern)[..., None] if raw and pattern else rgb
    M = 6000
    t = np.sort(rng.integers(0, 40_000 * F, M))
    events = EventStream(t, rng.integers(0, W, M), rng.integers(0, H, M), rng.choice([-1, 1], M), W, H)
    c2w = np.repeat(np.eye(4)[None], F, 0)
    c2w[:, 0, 3] = np.linspace(-0.3, 0.3, F)
    exposures = np.stack([np.arange(F) * 0.04, np.arange(F) * 0.04 + 0.03], 1)
    K = np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1]])
    return Capture(frames=frames, exposures=exposures, events=events, K=K, c2w=c2w, cfa=pattern)


def _cfg(**loss):
    cfg = preset("ebad")
    cfg.loss.contrast = (0.2, 0.2)
    cfg.loss.w_edi = 0.0  # the EDI latents of a cfa capture are another part's
    cfg.trajectory.adaptive_views = False
    cfg.trajectory.num_views = 3
    cfg.model.init_points = 300
    cfg.model.init = "random"
    cfg.loss.cfa_frames = "rgb"  # RGB frames compared as RGB unless a test says otherwise
    for k, v in loss.items():
        setattr(cfg.loss, k, v)
    return cfg


@pytest.mark.parametrize("raw", [True, False])
def test_prepare_carries_the_filter_and_the_model_renders_rgb(raw):
    data = prepare(_capture(raw), _cfg())
    assert data.cfa == "GRBG" and data.channels == 3 and data.report.channels == 3 and data.raw_mosaic == raw
    assert data.cfa_weights is not None and np.array_equal(data.cfa_weights.argmax(-1), channel_map("GRBG", H, W))
    assert data.targets.shape[-1] == (1 if raw else 3)
    assert data.init_images.shape == (F, H, W, 3)
    state = TrainState.create(data, _cfg())
    assert state.params["colors"].shape[1] == 3
    half = downscale(data, 2)
    assert torch.allclose(half.cfa_weights, torch.tensor([0.25, 0.5, 0.25]).expand(H // 2, W // 2, 3))


def test_grey_and_luminance_captures_keep_their_losses():
    grey = prepare(_capture(False, None), _cfg())
    assert grey.cfa is None and grey.cfa_weights is None and grey.channels == 3
    lum = prepare(_capture(False), _cfg(cfa_events="luminance"))
    assert lum.cfa == "GRBG" and lum.cfa_weights is None  # today's events of the channel mean
    raw = prepare(_capture(True), _cfg(cfa_events="luminance"))
    assert raw.cfa_weights is not None  # raw frames compare the render's mosaic whatever the events


def test_cfa_frames_mosaic_compares_each_pixels_own_channel_of_rgb_frames():
    cap = _capture(False)
    data = prepare(cap, _cfg(cfa_frames="mosaic"))
    assert data.raw_mosaic and data.channels == 3
    assert torch.equal(data.frames[..., 0], torch.from_numpy(mosaic(cap.frames, "GRBG")))


@pytest.mark.parametrize("raw", [True, False])
@pytest.mark.parametrize("response", ["linear", "gamma"])
def test_a_training_step_compares_each_pixels_own_channel(raw, response):
    cfg = _cfg()
    cfg.model.response = response
    data = prepare(_capture(raw), cfg)
    state = TrainState.create(data, cfg)
    f = next(i for i, e in enumerate(data.ev_counts) if e is not None)
    out = frame_losses(data, state, f, cfg)
    assert out.mean_render.shape == (H, W, 1 if raw else 3) and out.ev is not None
    # the same step's losses from the renders, through the filter
    V = int(data.V[f])
    poses = state.trajectories(torch.tensor([f]), virtual_instants(V))[0]
    images, _, _ = render(state.params, poses, data.K, data.width, data.height, cfg.model.background)
    images = images.detach()
    assert data.cfa_weights is not None
    ev = event_loss(images, data.ev_counts[f], data.c, norm=cfg.loss.event_norm, cfa=data.cfa_weights)
    assert float(out.ev.detach()) == pytest.approx(float(ev), rel=1e-5)
    lum = event_loss(images, data.ev_counts[f], data.c, norm=cfg.loss.event_norm)  # the channel mean's
    assert abs(float(lum) - float(ev)) > 1e-4  # so the equality above tells them apart
    if response == "linear":
        blur, *_ = exposure_losses(images, V, data.targets[f], cfa=data.cfa_weights)
        assert float(out.blur.detach()) == pytest.approx(float(blur), rel=1e-5)
        if raw:
            assert torch.allclose(out.mean_render, cfa_project(images, data.cfa_weights).mean(0), atol=1e-6)
    out.total.backward()
    assert state.params["colors"].grad is not None and state.params["colors"].grad.abs().sum() > 0


def test_cfa_weights_refuse_a_pattern_that_is_not_one():
    from edi.errors import InputError

    with pytest.raises(InputError, match="not a Bayer pattern"):
        cfa_weights("RGBG", 4, 4)


def test_view_latents_made_again_for_a_new_V_follow_the_filter(monkeypatch):
    """``set_views`` rebuilds a frame's view latents with the capture's cfa (per-pixel EDI on the
    mosaic), exactly as ``prepare`` made them (the "latents" colour, where the cfa shows with a given c)."""
    import sys

    import scenes

    monkeypatch.setattr(sys.modules["edi.deblur"], "COLOUR_FROM_MOSAIC", "latents")
    from ebad.config import preset
    from ebad.data import prepare, view_latents

    cap = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, cfa="RGGB").capture
    cfg = preset("ebad")
    cfg.loss.edi_instants = "views"
    cfg.loss.cfa_frames = "rgb"  # RGB latents, where the filter shows (on the mosaic both are per pixel)
    data = prepare(cap, cfg)
    f = int(np.flatnonzero(data.V > 1)[0])
    new_V = data.V.copy()
    new_V[f] = data.V[f] + 2
    data.set_views(new_V)
    assert data.c is not None and data.view_latents is not None
    frame, exposure = data.frames[f].numpy(), data.exposures[f]
    want = view_latents(frame, exposure, cap.events, int(new_V[f]), data.c, cfa="RGGB")
    assert torch.equal(data.view_latents[f], want)
    assert not torch.allclose(data.view_latents[f], view_latents(frame, exposure, cap.events, int(new_V[f]), data.c))


def test_the_ebad_preset_compares_rgb_frames_through_the_mosaic_and_the_baselines_do_not():
    assert preset("ebad").loss.cfa_frames == "mosaic"
    assert {preset(p).loss.cfa_frames for p in ("3dgs", "bad", "edi-3dgs")} == {"rgb"}
    cap = _capture(False)
    cfg = preset("ebad")
    cfg.loss.contrast, cfg.loss.w_edi, cfg.model.init, cfg.model.init_points = (0.2, 0.2), 0.0, "random", 300
    data = prepare(cap, cfg)
    assert data.raw_mosaic and data.targets.shape == (F, H, W, 1)
    assert torch.equal(data.frames[..., 0], torch.from_numpy(mosaic(cap.frames, "GRBG")))
