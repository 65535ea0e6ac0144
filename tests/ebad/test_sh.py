"""View-dependent colour in the method: the SH degree's schedule, rendering, densification, checkpoints, PLY."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData
from torch import nn

import scenes
from ebad.config import preset
from ebad.data import prepare
from ebad.errors import ConfigError
from ebad.gaussians import SH_C0, SH_REST_LR_RATIO, init_params, render, resize_sh, sh_degree_of
from ebad.io import read_ply, write_ply
from ebad.loop import train_step
from ebad.schedule import Schedule
from ebad.state import TrainState, max_gaussians
from ebad.strategy import duplicate, make_strategy, remove, split

from ._helpers import random_c2w


def _params(n=50, d=3, degree=3, seed=0) -> dict[str, nn.Parameter]:
    g = torch.Generator().manual_seed(seed)
    pts = torch.randn(n, 3, generator=g) * 0.5 + torch.tensor([0.0, 0.0, 4.0])
    params = init_params(pts, torch.rand(n, d, generator=g), scales=torch.full((n,), 0.2), opacity=0.6)
    resize_sh(params, degree)
    if degree:
        with torch.no_grad():
            params["sh_rest"].normal_(0, 0.3, generator=g)
    return params


# --------------------------------------------------------------------------- schedule


def _schedule(iters, degree=3, interval=1000, max_seconds=None) -> Schedule:
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = iters, max_seconds
    cfg.model.sh_degree, cfg.model.sh_degree_interval = degree, interval
    return Schedule.from_config(cfg, 1.0)


def test_the_degree_rises_every_interval_or_at_gsplats_fraction_of_a_short_budget():
    s = _schedule(3000)  # 3000 steps: gsplat's 1000 of 30000 is 100 steps here
    assert [s.at(k, 0.0).sh_degree for k in (0, 99, 100, 199, 200, 300, 2999)] == [0, 0, 1, 1, 2, 3, 3]
    long = _schedule(60000)  # longer than gsplat's run: every 1000 steps (gsplat's rule)
    assert [long.at(k, 0.0).sh_degree for k in (999, 1000, 2000, 2999, 3000)] == [0, 1, 2, 2, 3]
    timed = _schedule(10**6, max_seconds=100.0)  # a time budget: a tenth of it to degree 3
    assert [timed.at(5, t).sh_degree for t in (0.0, 3.4, 6.7, 10.0)] == [0, 1, 2, 3]
    assert _schedule(3000, degree=1).at(2999, 0.0).sh_degree == 1
    assert _schedule(3000, degree=0).at(2999, 0.0).sh_degree == 0


@pytest.mark.parametrize("field,value", [("sh_degree", 4), ("sh_degree", -1), ("sh_degree_interval", 0)])
def test_config_names_a_bad_sh_option(field, value):
    cfg = preset("ebad")
    setattr(cfg.model, field, value)
    with pytest.raises(ConfigError, match=f"--model.{field}"):
        cfg.check()


# --------------------------------------------------------------------------- render


def test_degree_zero_renders_exactly_as_a_model_without_sh():
    params = _params()
    plain = {k: v for k, v in params.items() if k != "sh_rest"}
    c2w = random_c2w(2, seed=1)
    c2w[:, :3, :3] = torch.eye(3)
    c2w[:, :3, 3] = torch.tensor([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0]])
    K = torch.tensor([[30.0, 0, 20], [0, 30, 15], [0, 0, 1]])
    a, _, _ = render(plain, c2w, K, 40, 30)
    b, _, _ = render(params, c2w, K, 40, 30, sh_degree=0)
    assert torch.equal(a, b)
    c, _, _ = render(params, c2w, K, 40, 30)  # the model's degree: view-dependent, different
    assert sh_degree_of(params) == 3 and float((c - a).detach().abs().max()) > 0.01
    zero = dict(params)
    zero["sh_rest"] = nn.Parameter(torch.zeros_like(params["sh_rest"]))
    z, _, _ = render(zero, c2w, K, 40, 30)  # zero higher coefficients: the DC colour up to rounding
    assert float((z - a).detach().abs().max()) < 1e-5


def test_resize_sh_pads_cuts_and_removes():
    params = _params(degree=2)
    old = params["sh_rest"].detach().clone()
    resize_sh(params, 3)
    assert params["sh_rest"].shape == (50, 15, 3) and torch.equal(params["sh_rest"][:, :8], old)
    assert float(params["sh_rest"][:, 8:].detach().abs().max()) == 0
    resize_sh(params, 1)
    assert params["sh_rest"].shape == (50, 3, 3) and torch.equal(params["sh_rest"], old[:, :3])
    resize_sh(params, 0)
    assert "sh_rest" not in params and sh_degree_of(params) == 0


# --------------------------------------------------------------------------- densification


def test_densification_carries_the_sh_coefficients_and_their_moments():
    params = _params(n=6)
    opts = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    for p in params.values():
        p.grad = torch.ones_like(p)
    for o in opts.values():
        o.step()
    rest = params["sh_rest"].detach().clone()
    duplicate(params, opts, torch.tensor([True, False, False, False, False, True]))
    assert params["sh_rest"].shape == (8, 15, 3) and torch.equal(params["sh_rest"][6:], rest[[0, 5]])
    split(params, opts, torch.tensor([False, True] + [False] * 6), generator=torch.Generator().manual_seed(0))
    assert params["sh_rest"].shape == (9, 15, 3) and torch.equal(params["sh_rest"][-2:], rest[[1, 1]])
    remove(params, opts, torch.tensor([True] + [False] * 8))
    n = params["means"].shape[0]
    assert n == 8 and params["sh_rest"].shape[0] == n
    st = opts["sh_rest"].state[params["sh_rest"]]
    assert st["exp_avg"].shape == params["sh_rest"].shape  # the moments stay aligned with the parameter


# --------------------------------------------------------------------------- training and checkpoints


@pytest.fixture(scope="module")
def tiny():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)


def _setup(capture, degree, interval=1):
    cfg = preset("ebad")
    cfg.train.progress = False
    cfg.train.iters = 8
    cfg.strategy.refine_start, cfg.strategy.refine_every = 1, 2
    cfg.model.sh_degree, cfg.model.sh_degree_interval = degree, interval
    data = prepare(capture, cfg)
    state = TrainState.create(data, cfg)
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    state.strategy_state = strategy.initialize_state(state.num_gaussians)
    return cfg, data, state, strategy


def _steps(cfg, data, state, strategy, n):
    for _ in range(n):
        train_step(data, state, strategy, state.next_frame(), cfg)


def test_training_raises_the_degree_and_learns_the_higher_coefficients(tiny):
    cfg, data, state, strategy = _setup(tiny.capture, 3)
    assert state.params["sh_rest"].shape[1:] == (15, data.targets.shape[-1])
    lr = state.optimizers["sh_rest"].param_groups[0]["lr"]
    assert lr == pytest.approx(cfg.train.lr_colors / SH_REST_LR_RATIO)
    _steps(cfg, data, state, strategy, 4)  # interval 1: degree 1 from step 1, 3 from step 3
    rest = state.params["sh_rest"].detach()
    assert float(rest[:, :3].abs().max()) > 0  # degree 1 learnt
    assert float(rest[:, 8:].abs().max()) > 0  # degree 3 learnt from step 3 on
    assert bool(torch.isfinite(rest).all()) and rest.shape[0] == state.num_gaussians


def test_a_model_whose_degree_is_not_raised_yet_trains_exactly_as_degree_zero(tiny):
    runs = []
    for degree in (0, 3):
        cfg, data, state, strategy = _setup(tiny.capture, degree, interval=10**6)  # never raised in 4 steps
        _steps(cfg, data, state, strategy, 4)
        runs.append(state)
    a, b = runs
    for k in a.params:
        assert torch.equal(a.params[k], b.params[k]), k
    assert [h.loss for h in a.history] == [h.loss for h in b.history]
    assert float(b.params["sh_rest"].detach().abs().max()) == 0  # never used: no gradient


def test_checkpoints_carry_sh_and_old_ones_without_it_still_load(tiny, tmp_path):
    cfg, data, state, strategy = _setup(tiny.capture, 3)
    _steps(cfg, data, state, strategy, 3)
    state.save(tmp_path / "a.pt")
    loaded = TrainState.load(tmp_path / "a.pt", data, cfg)
    assert torch.equal(loaded.params["sh_rest"], state.params["sh_rest"])
    assert "sh_rest" in loaded.optimizers and loaded.optimizers["sh_rest"].state
    # an old checkpoint: no SH coefficients anywhere
    cfg0, data0, state0, strategy0 = _setup(tiny.capture, 0)
    _steps(cfg0, data0, state0, strategy0, 2)
    state0.save(tmp_path / "old.pt")
    doc = torch.load(tmp_path / "old.pt", weights_only=True)
    assert "sh_rest" not in doc["params"]
    resumed = TrainState.load(tmp_path / "old.pt", data, cfg)  # resumed with --model.sh_degree 3
    assert resumed.params["sh_rest"].shape == (state0.num_gaussians, 15, data.targets.shape[-1])
    assert float(resumed.params["sh_rest"].detach().abs().max()) == 0
    assert torch.equal(resumed.params["colors"], state0.params["colors"])
    _steps(cfg, data, resumed, make_strategy(cfg.strategy, data.scale, 10**5, resumed.generator), 1)


# --------------------------------------------------------------------------- PLY


def _inria_load_ply(path, max_sh_degree=3):
    """INRIA's ``GaussianModel.load_ply`` property checks and reshapes (graphdeco-inria/gaussian-splatting)."""
    plydata = PlyData.read(str(path))
    el = plydata.elements[0]
    xyz = np.stack([np.asarray(el["x"]), np.asarray(el["y"]), np.asarray(el["z"])], axis=1)
    opacities = np.asarray(el["opacity"])[..., np.newaxis]
    features_dc = np.zeros((xyz.shape[0], 3, 1))
    for i in range(3):
        features_dc[:, i, 0] = np.asarray(el[f"f_dc_{i}"])
    extra_f_names = [p.name for p in el.properties if p.name.startswith("f_rest_")]
    extra_f_names = sorted(extra_f_names, key=lambda x: int(x.split("_")[-1]))
    assert len(extra_f_names) == 3 * (max_sh_degree + 1) ** 2 - 3
    features_extra = np.zeros((xyz.shape[0], len(extra_f_names)))
    for idx, attr_name in enumerate(extra_f_names):
        features_extra[:, idx] = np.asarray(el[attr_name])
    features_extra = features_extra.reshape((features_extra.shape[0], 3, (max_sh_degree + 1) ** 2 - 1))
    scale_names = sorted([p.name for p in el.properties if p.name.startswith("scale_")], key=lambda x: int(x[6:]))
    rot_names = sorted([p.name for p in el.properties if p.name.startswith("rot")], key=lambda x: int(x[4:]))
    scales = np.stack([np.asarray(el[n]) for n in scale_names], 1)
    rots = np.stack([np.asarray(el[n]) for n in rot_names], 1)
    # INRIA's tensors: features_dc [N, 1, 3], features_rest [N, 15, 3]
    return xyz, features_dc.transpose(0, 2, 1), features_extra.transpose(0, 2, 1), opacities, scales, rots


@pytest.mark.parametrize("d,degree", [(3, 3), (1, 3), (3, 1), (3, 0), (1, 0)])
def test_ply_opens_in_inrias_loader_at_degree_3_and_reads_back(tmp_path, d, degree):
    params = _params(n=20, d=d, degree=degree)
    path = write_ply(tmp_path / "point_cloud.ply", params)
    xyz, dc, rest, opac, scales, rots = _inria_load_ply(path)
    assert rest.shape == (20, 15, 3) and dc.shape == (20, 1, 3) and scales.shape == (20, 3) and rots.shape == (20, 4)
    np.testing.assert_array_equal(xyz, params["means"].detach().numpy())
    np.testing.assert_array_equal(dc[:, 0], params["colors"].detach().expand(20, 3).numpy())
    k = (degree + 1) ** 2 - 1
    if degree:  # INRIA's features_rest are ours (a grey model's in each channel), zero above the degree
        np.testing.assert_array_equal(rest[:, :k], params["sh_rest"].detach().expand(20, k, 3).numpy())
    assert float(np.abs(rest[:, k:]).max(initial=0.0)) == 0.0
    back = read_ply(path)
    assert sh_degree_of(back) == degree and back["colors"].shape == (20, d)
    for key, v in params.items():
        assert torch.equal(back[key], v.detach()), key


def test_ply_written_by_inria_at_degree_3_reads_as_degree_3(tmp_path):
    params = _params(n=10, d=3, degree=3)
    path = write_ply(tmp_path / "a.ply", params)
    ply = PlyData.read(str(path))
    ply.comments = []  # INRIA writes no comments
    ply.write(str(tmp_path / "b.ply"))
    back = read_ply(tmp_path / "b.ply")
    assert torch.equal(back["sh_rest"], params["sh_rest"].detach())


def test_sh_colour_is_the_dc_colour_seen_from_where_the_higher_terms_vanish():
    # a single degree-1 term on z: from a camera straight in front (direction +z, dir z = 1) the colour is
    # 0.5 + C0 dc + C1 c; checks the sign convention end to end through render
    params = _params(n=1, d=1, degree=1)
    with torch.no_grad():
        params["means"].copy_(torch.tensor([[0.0, 0.0, 4.0]]))
        params["scales"].fill_(np.log(2.0))
        params["opacities"].fill_(10.0)
        params["colors"].fill_(0.0)
        params["sh_rest"].zero_()
        params["sh_rest"][0, 1, 0] = 0.5  # the coefficient of C1 z
    K = torch.tensor([[10.0, 0, 4], [0, 10, 4], [0, 0, 1]])
    img, alpha, _ = render(params, torch.eye(4)[None], K, 8, 8)
    expected = 0.5 + 0.4886025119029199 * 0.5
    centre = float((img[0, 4, 4, 0] / alpha[0, 4, 4, 0]).detach())
    assert centre == pytest.approx(expected, abs=1e-5) and SH_C0 > 0


def test_a_run_folder_keeps_the_view_dependent_colour(tiny, tmp_path):
    from ebad.run import reconstruct
    from ebad.runfolder import load_run, write_run

    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every, cfg.train.checkpoint_every = 4, False, 0, 0
    cfg.model.sh_degree, cfg.model.sh_degree_interval = 2, 1
    run = reconstruct(tiny.capture, cfg)
    write_run(run, tmp_path / "run")
    back = load_run(tmp_path / "run")
    assert sh_degree_of(back.params) == 2 and float(back.params["sh_rest"].detach().abs().max()) > 0
    assert torch.equal(back.params["sh_rest"], run.params["sh_rest"].detach())
    pose = run.trajectories.mid_poses().numpy()[:2]
    a, b = run.render(pose), back.render(pose)
    assert np.array_equal(a, b)
    flat = dict(run.params)
    flat.pop("sh_rest")
    run.params = flat  # the same model without its higher coefficients renders differently
    assert not np.array_equal(run.render(pose), a)
