"""Densification by what it does to the Gaussians, not by counts: a split's children are smaller
than their parent and drawn from it, a clone is a copy, the cap keeps the strongest gradients,
pruning removes exactly the transparent ones."""

from __future__ import annotations

import math

import torch

from ebad import config as C
from ebad.gaussians import init_params
from ebad.lie import quat_to_rotmat
from ebad.strategy import DefaultStrategy, RenderInfo, split


def _params(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return init_params(torch.randn(n, 3, generator=g), torch.rand(n, 1, generator=g), opacity=0.5)


def _optims(params):
    return {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}


def _info(grad: torch.Tensor, C: int = 2, W: int = 64, H: int = 48) -> RenderInfo:  # grad [N] along x
    N = grad.shape[0]
    m2d = torch.zeros(C, N, 2, requires_grad=True)
    m2d.grad = torch.zeros(C, N, 2)
    m2d.grad[:, :, 0] = grad
    return RenderInfo(means2d=m2d, radii=torch.ones(C, N, 2, dtype=torch.int32), width=W, height=H)


def _random_quats(n: int, seed: int) -> torch.Tensor:
    q = torch.randn(n, 4, generator=torch.Generator().manual_seed(seed))
    return q / q.norm(dim=-1, keepdim=True)


def test_split_children_are_shrink_times_smaller_and_drawn_from_the_parent():
    n, shrink = 4000, 1.6
    params = _params(n)
    with torch.no_grad():
        params["scales"][:] = torch.log(torch.tensor([0.3, 0.1, 0.02]))  # anisotropic
        params["quats"][:] = _random_quats(n, 1)
    parent = {k: v.detach().clone() for k, v in params.items()}
    keep = torch.zeros(n, dtype=torch.bool)
    keep[:3] = True  # three stay as they are
    split(params, _optims(params), ~keep, generator=torch.Generator().manual_seed(0), shrink=shrink)
    S = n - 3
    assert params["means"].shape[0] == 3 + 2 * S
    for k in params:  # the kept ones first, unchanged
        assert torch.equal(params[k][:3], parent[k][:3]), k
    idx = torch.arange(3, n)
    for c in range(2):  # the two children of parent idx[i] at rows 3 + c S + i
        rows = slice(3 + c * S, 3 + (c + 1) * S)
        assert torch.allclose(torch.exp(params["scales"][rows]), torch.exp(parent["scales"][idx]) / shrink, rtol=1e-6)
        for k in ("quats", "opacities", "colors"):
            assert torch.equal(params[k][rows], parent[k][idx]), k
        # each child's offset, in its parent's frame and units, is a standard normal draw
        R = quat_to_rotmat(parent["quats"][idx])
        local = torch.einsum("sji,sj->si", R, params["means"][rows] - parent["means"][idx])
        z = local / torch.exp(parent["scales"][idx])
        assert z.mean(0).abs().max() < 0.1 and ((z.std(0) - 1).abs() < 0.1).all(), z.std(0)
    first, second = params["means"][3 : 3 + S], params["means"][3 + S :]
    assert not torch.allclose(first, second)  # two draws, not one child twice


def test_refine_splits_big_gaussians_into_smaller_children_and_clones_small_ones_in_place():
    cfg = C.StrategyConfig(
        grad_threshold=1e-3,
        refine_start=0,
        refine_every=1,
        reset_every=0,
        split_scale=0.1,
        split_shrink=1.6,
        prune_opacity=0.01,
    )
    params = _params(4)
    with torch.no_grad():
        params["scales"][0] = math.log(0.01)  # small, high gradient: cloned
        params["scales"][1] = math.log(0.5)  # big, high gradient: split
        params["scales"][2:] = math.log(0.5)  # big, no gradient: kept
    before = {k: v.detach().clone() for k, v in params.items()}
    strat = DefaultStrategy(cfg, scene_scale=1.0, generator=torch.Generator().manual_seed(0))
    state = strat.initialize_state(4)
    rep = strat.step_post_backward(params, _optims(params), state, 1, _info(torch.tensor([1.0, 1.0, 0.0, 0.0])))
    assert (rep.cloned, rep.split, rep.pruned) == (1, 1, 0)
    scales = torch.exp(params["scales"]).max(-1).values
    # rows: kept 0, 2, 3, the clone of 0, then the two children of 1
    assert params["means"].shape[0] == 6
    assert torch.allclose(scales[4:], torch.full((2,), 0.5 / 1.6))
    assert torch.equal(params["means"][3], before["means"][0]) and torch.equal(params["scales"][3], before["scales"][0])
    assert not (scales == 0.5).sum() > 2  # the split parent is gone; only 2 and 3 keep 0.5
    assert (torch.linalg.norm(params["means"][4:] - before["means"][1], dim=-1) < 5 * 0.5).all()


def test_at_the_cap_the_strongest_gradients_densify():
    cfg = C.StrategyConfig(grad_threshold=1e-3, refine_start=0, refine_every=1, reset_every=0, split_scale=0.1)
    params = _params(6)
    with torch.no_grad():
        params["scales"][:] = math.log(0.001)  # all small: clones
    means = params["means"].detach().clone()
    strat = DefaultStrategy(cfg, 1.0, max_gaussians=8)  # room for 2 of the 5 above the threshold
    state = strat.initialize_state(6)
    grad = torch.tensor([0.5, 2.0, 0.01, 3.0, 1.0, 0.0])  # strongest: 3 then 1
    rep = strat.step_post_backward(params, _optims(params), state, 1, _info(grad))
    assert rep.cloned == 2 and params["means"].shape[0] == 8
    clones = params["means"][6:]
    assert {int(torch.nonzero((means == c).all(-1))[0]) for c in clones} == {1, 3}


def test_the_cap_ranks_by_the_mean_gradient_over_the_cameras_that_saw_each_gaussian():
    cfg = C.StrategyConfig(grad_threshold=1e-3, refine_start=0, refine_every=1, reset_every=0, split_scale=0.1)
    params = _params(3)
    with torch.no_grad():
        params["scales"][:] = math.log(0.001)
    means = params["means"].detach().clone()
    strat = DefaultStrategy(cfg, 1.0, max_gaussians=4)
    state = strat.initialize_state(3)
    info = _info(torch.tensor([1.0, 2.0, 0.0]), C=4)
    info.radii[1:, 1] = 0  # Gaussian 1 seen by one camera of four: a lower sum (2 < 4), the higher mean (2 > 1)
    rep = strat.step_post_backward(params, _optims(params), state, 1, info)
    assert rep.cloned == 1 and torch.equal(params["means"][3], means[1])


def test_pruning_removes_exactly_the_gaussians_below_the_opacity_threshold():
    cfg = C.StrategyConfig(grad_threshold=1.0, refine_start=0, refine_every=1, reset_every=0, prune_opacity=0.05)
    params = _params(5)

    def logit(o):
        return math.log(o / (1 - o))

    with torch.no_grad():
        for i, o in enumerate((0.049, 0.051, 0.5, 0.01, 0.9)):
            params["opacities"][i] = logit(o)
    means = params["means"].detach().clone()
    strat = DefaultStrategy(cfg, 1.0)
    rep = strat.step_post_backward(params, _optims(params), strat.initialize_state(5), 1, _info(torch.zeros(5)))
    assert rep.pruned == 2
    assert torch.equal(params["means"], means[[1, 2, 4]])
