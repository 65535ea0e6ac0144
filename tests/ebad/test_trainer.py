"""ebad.loop.frame_losses: the L_ev options (windows, norm) and the L_EDI prior."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

import edi
import scenes
from ebad.config import preset
from ebad.data import _train_indices, prepare
from ebad.gaussians import render
from ebad.loop import frame_losses
from ebad.losses import event_loss
from ebad.state import TrainState
from ebad.trajectory import virtual_instants
from ebad.virtual_views import random_window, window_counts


@pytest.fixture(scope="module")
def scene():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)


def _config(**loss):
    cfg = preset("ebad")
    for k, v in loss.items():
        setattr(cfg.loss, k, v)
    return cfg


def _renders(data, state, f):  # [V, H, W, D] the frame's virtual views, as frame_losses renders them
    V = int(data.V[f])
    poses = state.trajectories(torch.tensor([f]), virtual_instants(V))[0]
    return render(state.params, poses, data.K, data.width, data.height, 0.0)[0]


@pytest.mark.parametrize("norm", ["l1", "l2"])
def test_frame_losses_random_windows_use_one_pair_drawn_from_the_run_generator(scene, norm):
    cfg = _config(event_windows="random", event_norm=norm)
    data = prepare(scene.capture, cfg)
    state = TrainState.create(data, cfg)
    f = int(np.argmax(data.V))
    V = int(data.V[f])
    assert V >= 3 and data.ev_counts[f] is not None
    with torch.no_grad():
        renders = _renders(data, state, f)
        seen = set()
        for _ in range(6):
            ref_gen = torch.Generator().set_state(state.generator.get_state())
            i, j = random_window(V, ref_gen)
            seen.add((i, j))
            ev = frame_losses(data, state, f, cfg).ev
            ref = event_loss(renders[[i, j]], window_counts(data.ev_counts[f], i, j), data.c, norm=norm)
            assert float(ev) == pytest.approx(float(ref), rel=1e-5)
        consecutive = event_loss(renders, data.ev_counts[f], data.c, norm=norm)
        default = frame_losses(data, state, f, _config(event_norm=norm)).ev
    assert len(seen) > 1  # the window changes from step to step
    assert float(default) == pytest.approx(float(consecutive), rel=1e-5)


def test_medi_prior_gives_the_latents_of_edi_medi(scene):
    cfg = _config(edi_prior="medi")
    data = prepare(scene.capture, cfg)
    cap = scene.capture
    idx = _train_indices(cap)
    ref = edi.medi(np.asarray(cap.frames, np.float32)[idx], np.asarray(cap.exposures)[idx], cap.events, c=data.c)
    assert np.allclose(data.latents.numpy(), np.asarray(ref).reshape(data.latents.shape), atol=1e-6)
    per_frame = prepare(scene.capture, _config())
    assert not torch.allclose(per_frame.latents, data.latents, atol=1e-3)  # a different prior, not a copy


def test_every_step_says_where_its_time_went():
    from ebad.loop import step_profile
    from ebad.run import reconstruct

    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 6, False, 0
    run = reconstruct(sc.capture, cfg)
    for h in run.history:
        p = h.profile
        assert 0 < p["raster_forward"] <= p["forward"] and 0 < p["raster_backward"] <= p["backward"]
        assert p["poses"] > 0 and p["losses"] > 0 and p["poses"] + p["raster_forward"] + p["losses"] <= p["forward"]
        parts = p["forward"] + p["backward"] + p["adam"] + p["densify"]
        assert 0.5 * p["step"] <= parts <= p["step"] + 1e-6  # the parts are inside the step and cover most of it
    mean = step_profile(run.history)
    assert mean["steps"] == 6 and 0 < mean["outside_share"] < 1
    assert mean["step"] == pytest.approx(sum(h.profile["step"] for h in run.history) / 6)
    assert step_profile([]) is None
    old = dataclasses.replace(
        run.history[0], profile={k: v for k, v in run.history[0].profile.items() if k not in ("poses", "losses")}
    )
    mixed = step_profile([old, *run.history[1:]])  # a resumed run's history from before the forward's parts
    assert "poses" not in mixed and mixed["step"] == pytest.approx(mean["step"])


def test_edi_at_every_view_compares_each_virtual_view_with_the_latent_at_its_instant(scene):
    from ebad.config import ConfigError
    from ebad.data import downscale
    from ebad.losses import edi_loss

    cfg = _config(edi_instants="views")
    data = prepare(scene.capture, cfg)
    cap = scene.capture
    idx = _train_indices(cap)
    f = int(np.argmax(data.V))
    V = int(data.V[f])
    assert V >= 3 and data.view_latents[f].shape == (V, data.height, data.width, data.latents.shape[-1])
    assert all((v is None) == (n == 1) for v, n in zip(data.view_latents, data.V))
    t0, t1 = cap.exposures[idx[f]]
    for i, u in enumerate(virtual_instants(V).tolist()):  # each view's latent is EDI at its own instant
        ref = np.clip(
            edi.deblur(
                np.asarray(cap.frames[idx[f]], np.float32), (t0, t1), cap.events, times=t0 + u * (t1 - t0), c=data.c
            ),
            0,
            1,
        )
        assert np.allclose(data.view_latents[f][i].numpy(), np.asarray(ref).reshape(data.latents.shape[1:]), atol=1e-5)
    assert torch.allclose(data.view_latents[f][V // 2], data.latents[f], atol=1e-5)  # odd V: the middle one is mid
    assert not torch.allclose(data.view_latents[f][0], data.latents[f], atol=1e-3)  # the others are not copies of it
    state = TrainState.create(data, cfg)
    with torch.no_grad():
        out = frame_losses(data, state, f, cfg).edi
        ref = edi_loss(state.response(_renders(data, state, f)), data.view_latents[f])
    assert float(out) == pytest.approx(float(ref), rel=1e-5)
    half = downscale(data, 2)
    assert half.view_latents[f].shape == (V, data.height // 2, data.width // 2, data.latents.shape[-1])
    new_V = data.V.copy()
    new_V[f] = 3
    data.set_views(new_V)  # the latents follow a new V
    assert data.view_latents[f].shape[0] == 3
    assert torch.allclose(data.view_latents[f][1], data.latents[f], atol=1e-5)
    bad = _config(edi_instants="views", edi_prior="medi")
    with pytest.raises(ConfigError, match="loss.edi_instants"):
        bad.check()


@pytest.mark.parametrize("instants,views", [("views", 5), ("mid", 4), ("mid", 5)])
def test_frame_losses_in_one_node_equal_the_response_path_with_a_linear_response(scene, instants, views):
    """A linear response takes ``losses.exposure_losses``; the composed path a learnt response takes
    (``_losses_through_response``) gives the same losses and parameter gradients with it, with
    L_EDI at every view or at mid-exposure (an even V renders its mid view last)."""
    from ebad.loop import _losses_through_response, frame_losses

    cfg = _config(edi_instants=instants)
    cfg.trajectory.num_views = views
    data = prepare(scene.capture, cfg)
    state = TrainState.create(data, cfg)
    f = int(np.argmax(data.V))
    assert int(data.V[f]) == views and data.ev_counts[f] is not None
    assert not state.response.learnable
    out = frame_losses(data, state, f, cfg)
    out.total.backward()
    grads = {k: p.grad.clone() for k, p in state.params.items()}
    knots_grad = state.trajectories.knots.grad.clone()
    for p in [*state.params.values(), state.trajectories.knots]:
        p.grad = None

    import ebad.loop as trainer

    def composed(images, V, blurry, latents, mid, counts, event_views, c, w, window, norm, cfa=None):
        return _losses_through_response(
            images, V, blurry, latents, mid, counts, event_views, c, state.response, cfg, cfa
        )

    original = trainer.exposure_losses
    trainer.exposure_losses = composed
    try:
        ref = frame_losses(data, state, f, cfg)
    finally:
        trainer.exposure_losses = original
    ref.total.backward()
    for name in ("blur", "edi", "ev"):
        assert float(getattr(out, name).detach()) == pytest.approx(float(getattr(ref, name).detach()), rel=1e-5)
    assert torch.allclose(out.mean_render, ref.mean_render, atol=1e-6)
    for k, p in state.params.items():
        assert torch.allclose(grads[k], p.grad, rtol=1e-4, atol=1e-7 * float(p.grad.abs().max())), k
    assert torch.allclose(
        knots_grad, state.trajectories.knots.grad, rtol=1e-4, atol=1e-6 * float(knots_grad.abs().max())
    )
