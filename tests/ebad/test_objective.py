"""What the loop optimises, as a whole: ``frame_losses``' weighted total and its gradient.

The per-loss tests compare L_blur, L_ev and L_EDI one by one; these check the sum they are
optimised as, on both paths (the one-node ``exposure_losses`` of a linear response and the
composed path of a learnt one): the total is w_blur L_blur + w_event L_ev + w_edi L_EDI, and each
weight moves the parameters' gradient by its own loss's gradient.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import scenes
from ebad.config import preset
from ebad.data import prepare
from ebad.loop import frame_losses
from ebad.state import TrainState

WEIGHTS = (0.7, 0.3, 1.9)  # w_blur, w_event, w_edi: none is a preset's, so no term can hide behind a 1


@pytest.fixture(scope="module")
def scene():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)


def _problem(scene, response: str, instants: str):
    cfg = preset("ebad")
    cfg.model.response = response
    cfg.loss.edi_instants = instants
    data = prepare(scene.capture, cfg)
    state = TrainState.create(data, cfg)
    f = int(np.argmax(data.V))
    assert int(data.V[f]) >= 3 and data.ev_counts[f] is not None and data.latents is not None
    assert state.response.learnable == (response != "linear")
    return cfg, data, state, f


def _grads(cfg, data, state, f, weights) -> tuple[object, dict[str, torch.Tensor]]:
    cfg.loss.w_blur, cfg.loss.w_event, cfg.loss.w_edi = weights
    leaves = {**state.params, "knots": state.trajectories.knots}
    for p in leaves.values():
        p.grad = None
    out = frame_losses(data, state, f, cfg)
    out.total.backward()
    return out, {k: p.grad.detach().clone() if p.grad is not None else torch.zeros_like(p) for k, p in leaves.items()}


@pytest.mark.parametrize("response,instants", [("linear", "views"), ("linear", "mid"), ("gamma", "views")])
def test_the_total_is_the_weighted_sum_of_the_three_losses(scene, response, instants):
    cfg, data, state, f = _problem(scene, response, instants)
    out, _ = _grads(cfg, data, state, f, WEIGHTS)
    assert out.ev is not None and out.edi is not None
    blur, ev, edi, total = (float(x.detach()) for x in (out.blur, out.ev, out.edi, out.total))
    wb, we, wd = WEIGHTS
    assert total == pytest.approx(wb * blur + we * ev + wd * edi, rel=1e-6)
    assert min(blur, ev, edi) > 1e-4  # every term counts in the sum


@pytest.mark.parametrize("response", ["linear", "gamma"])
def test_each_weight_moves_the_gradient_by_its_own_loss_s_gradient(scene, response):
    """The gradient at weights (a, b, c) is a g_blur + b g_ev + c g_edi, where g_x is the gradient
    with that loss's weight 1 and the others 0, and each g_x reaches the parameters (a loss left
    out of the total has a zero g_x)."""
    cfg, data, state, f = _problem(scene, response, "views")
    _, g_blur = _grads(cfg, data, state, f, (1.0, 0.0, 0.0))
    _, g_ev = _grads(cfg, data, state, f, (0.0, 1.0, 0.0))
    _, g_edi = _grads(cfg, data, state, f, (0.0, 0.0, 1.0))
    _, g = _grads(cfg, data, state, f, WEIGHTS)
    wb, we, wd = WEIGHTS
    for k in g:
        for name, part in (("blur", g_blur), ("ev", g_ev), ("edi", g_edi)):
            if k != "quats":  # isotropic initial Gaussians: no rotation gradient by symmetry
                assert float(part[k].abs().max()) > 0, f"L_{name} gives no gradient to {k}"
        combined = wb * g_blur[k] + we * g_ev[k] + wd * g_edi[k]
        scale = float(combined.abs().max())
        assert torch.allclose(g[k], combined, rtol=1e-4, atol=1e-5 * scale), k
    # and a weight's change alone changes the gradient of the Gaussians' colours and the knots
    for i in range(3):
        w = list(WEIGHTS)
        w[i] *= 2
        _, g2 = _grads(cfg, data, state, f, tuple(w))
        for k in ("colors", "knots"):
            assert not torch.allclose(g2[k], g[k], rtol=1e-3, atol=0), (i, k)
