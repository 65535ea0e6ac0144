"""Unit tests of the reconstruction's pure parts: config, Lie helpers, trajectories, losses,
V selection, strategy rules, PLY and PNG round trips."""
from __future__ import annotations

import argparse
import math
import re

import numpy as np
import pytest
import torch

from edi import EventStream
from ebad import config as C
from ebad.gaussians import SH_C0, activate, init_params, points_from_frames
from ebad.io import read_ply, read_png16, write_ply, write_png16
from ebad.lie import so3_exp, so3_log, viewmat_from_c2w
from ebad.losses import blur_loss, edi_loss, event_loss, l1_ssim, luminance
from ebad.strategy import DefaultStrategy, duplicate, remove, reset_opacity, split
from ebad.trajectory import TRAJECTORIES, ExposureTrajectories, bspline_weights, virtual_instants
from ebad.views import choose_num_views, event_sums


# --------------------------------------------------------------------------- config

def test_presets_registry_and_json_roundtrip(tmp_path):
    assert set(C.PRESETS) == {"3dgs", "bad", "edi-3dgs", "ebad", "oracle"}
    e = C.preset("ebad")
    assert (e.loss.w_blur, e.loss.w_event, e.loss.w_edi) == (1.0, 0.1, 1.0)
    assert C.preset("bad").loss.w_event == 0 and C.preset("bad").trajectory.kind == "linear"
    assert C.preset("3dgs").trajectory.kind == "fixed"
    assert C.preset("edi-3dgs").loss.target == "edi"
    e.model.init_depth = (1.0, 3.0)
    C.save_config(e, tmp_path / "c.json")
    back = C.load_config(tmp_path / "c.json")
    assert back == e


def test_config_errors_name_the_key():
    with pytest.raises(ValueError, match="nope"):
        C.preset("nope")
    with pytest.raises(ValueError, match="bogus"):
        C.config_from_dict({"train": {"bogus": 1}})


def test_argparse_from_dataclass():
    p = argparse.ArgumentParser()
    C.add_dataclass_arguments(p)
    args = p.parse_args(["--train.iters", "7", "--loss.w_event", "0.5", "--train.progress", "false",
                         "--loss.target", "edi"])
    cfg = C.apply_dataclass_arguments(C.preset("ebad"), args)
    assert cfg.train.iters == 7 and cfg.loss.w_event == 0.5 and cfg.train.progress is False
    assert cfg.loss.target == "edi" and cfg.loss.w_edi == 1.0  # untouched fields keep the preset
    with pytest.raises(SystemExit):
        p.parse_args(["--loss.target", "sharp"])


# --------------------------------------------------------------------------- Lie / trajectories

def test_so3_exp_log_roundtrip_and_identity_gradient():
    g = torch.Generator().manual_seed(0)
    w = torch.randn(64, 3, generator=g, dtype=torch.float64)
    w = w / w.norm(dim=-1, keepdim=True) * torch.rand(64, 1, generator=g, dtype=torch.float64) * 3.0  # angles < pi
    assert torch.allclose(so3_log(so3_exp(w)), w, atol=1e-10)
    R = so3_exp(w)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(64, 3, 3), atol=1e-12)
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    so3_log(so3_exp(z)).sum().backward()
    assert torch.allclose(z.grad, torch.ones(3, dtype=torch.float64))
    x = (torch.randn(4, 3, generator=g, dtype=torch.float64) * 0.3).requires_grad_(True)
    torch.autograd.gradcheck(lambda x: so3_log(so3_exp(x)), (x,))


def _random_c2w(F, seed=0):
    g = torch.Generator().manual_seed(seed)
    R = so3_exp(torch.randn(F, 3, generator=g))
    c2w = torch.eye(4).repeat(F, 1, 1)
    c2w[:, :3, :3] = R
    c2w[:, :3, 3] = torch.randn(F, 3, generator=g)
    return c2w


def test_linear_trajectory_endpoints_and_midpoint():
    c2w = _random_c2w(3).double()
    knots = torch.randn(3, 2, 6, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 0.1
    poses = TRAJECTORIES["linear"].poses(c2w, knots, torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64), 2.0)
    R0 = c2w[:, :3, :3] @ so3_exp(knots[:, 0, :3])
    R1 = c2w[:, :3, :3] @ so3_exp(knots[:, 1, :3])
    assert torch.allclose(poses[:, 0, :3, :3], R0, atol=1e-10)
    assert torch.allclose(poses[:, 2, :3, :3], R1, atol=1e-10)
    assert torch.allclose(poses[:, 0, :3, 3], c2w[:, :3, 3] + 2.0 * knots[:, 0, 3:], atol=1e-10)
    assert torch.allclose(poses[:, 2, :3, 3], c2w[:, :3, 3] + 2.0 * knots[:, 1, 3:], atol=1e-10)
    # the middle is the geodesic midpoint: equal rotation angle to both ends
    a = so3_log(R0.transpose(-1, -2) @ poses[:, 1, :3, :3]).norm(dim=-1)
    b = so3_log(poses[:, 1, :3, :3].transpose(-1, -2) @ R1).norm(dim=-1)
    assert torch.allclose(a, b, atol=1e-9)


def test_cubic_and_fixed_trajectories():
    B = bspline_weights(torch.linspace(0, 1, 7, dtype=torch.float64))
    assert torch.allclose(B.sum(-1), torch.ones(7, dtype=torch.float64))
    c2w = _random_c2w(2).double()
    zero = torch.zeros(2, 4, 6, dtype=torch.float64)
    u = torch.linspace(0, 1, 5, dtype=torch.float64)
    assert torch.allclose(TRAJECTORIES["cubic"].poses(c2w, zero, u), c2w[:, None].expand(-1, 5, -1, -1))
    knots = zero.clone()
    knots[..., 3] = 1.0  # every knot moved by +1 in x: the whole segment moves by +1
    p = TRAJECTORIES["cubic"].poses(c2w, knots, u)
    assert torch.allclose(p[..., 0, 3] - c2w[:, None, 0, 3], torch.ones(2, 5, dtype=torch.float64))
    f = TRAJECTORIES["fixed"].poses(c2w, torch.zeros(2, 0, 6, dtype=torch.float64), u)
    assert f.shape == (2, 5, 4, 4) and torch.equal(f[:, 3], c2w)


def test_exposure_trajectories_module():
    c2w = _random_c2w(4)
    moving = torch.tensor([True, False, True, True])
    traj = ExposureTrajectories(c2w, "linear", moving, scale=1.0, init_noise=1e-2,
                                generator=torch.Generator().manual_seed(0))
    u = virtual_instants(5)
    assert torch.allclose(u, torch.tensor([0.1, 0.3, 0.5, 0.7, 0.9]))
    p = traj(torch.arange(4), u)
    assert p.shape == (4, 5, 4, 4)
    assert torch.allclose(p[1], c2w[1].expand(5, 4, 4), atol=1e-6)  # non-moving frame: mid pose
    assert not torch.allclose(p[0, 0], p[0, -1])  # symmetric noise: start != end
    assert torch.allclose(traj.mid_poses(), c2w, atol=1e-5)  # symmetric init keeps the mid pose
    p.sum().backward()
    assert traj.knots.grad[1].abs().max() == 0 and traj.knots.grad[0].abs().max() > 0
    with pytest.raises(ValueError, match="kind"):
        ExposureTrajectories(c2w, "zigzag")
    with pytest.raises(ValueError, match="c2w_mid"):
        ExposureTrajectories(c2w[:, :3], "linear")


def test_viewmat_inverts_c2w():
    c2w = _random_c2w(3)
    assert torch.allclose(viewmat_from_c2w(c2w) @ c2w, torch.eye(4).expand(3, 4, 4), atol=1e-5)


# --------------------------------------------------------------------------- losses

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
    E = torch.full((1, 4, 4), 2.0)
    assert float(event_loss(torch.stack([I0, I1]), E, c, eps)) == pytest.approx(0.0, abs=1e-5)
    assert float(event_loss(torch.stack([I0, I1]), E - 1, c, eps)) == pytest.approx(c, abs=1e-5)
    with pytest.raises(ValueError, match="event_sums"):
        event_loss(torch.stack([I0, I1]), torch.zeros(2, 4, 4), c)


def test_luminance_grey_passthrough_and_rgb():
    g = torch.rand(3, 4, 1, generator=torch.Generator().manual_seed(3))
    assert torch.equal(luminance(g), g)
    rgb = torch.ones(2, 2, 3)
    assert torch.allclose(luminance(rgb), torch.ones(2, 2, 1))
    with pytest.raises(ValueError, match="D = 1 or 3"):
        luminance(torch.ones(2, 2, 2))


# --------------------------------------------------------------------------- V selection

def _stream(n_per_frame, W=8, H=6, exposures=((0.0, 0.04), (0.1, 0.14))):
    ts, xs, ys, ps = [], [], [], []
    rng = np.random.default_rng(0)
    for (t0, t1), n in zip(exposures, n_per_frame):
        ts.append(np.sort(rng.uniform(t0, t1, n)) * 1e6)
        xs.append(rng.integers(0, W, n)); ys.append(rng.integers(0, H, n)); ps.append(rng.choice([-1, 1], n))
    return EventStream(np.concatenate(ts).astype(np.int64), np.concatenate(xs), np.concatenate(ys),
                       np.concatenate(ps), W, H)


def test_views_sharp_frames_get_one_view():
    ex = np.array([[0.0, 0.04], [0.1, 0.14], [0.2, 0.2]])
    ev = _stream([200, 0])
    V = choose_num_views(ex, ev, 5, adaptive=True, sharp_events_per_pixel=0.05)
    assert V.tolist() == [5, 1, 1]  # busy / no events in exposure / zero-length exposure
    assert choose_num_views(ex, None, 5).tolist() == [5, 5, 1]  # no events: only t0 == t1 is sharp
    assert choose_num_views(ex, EventStream.empty(8, 6), 5).tolist() == [1, 1, 1]  # sensor saw nothing
    with pytest.raises(ValueError, match="num_views"):
        choose_num_views(ex, ev, 0)


def test_event_sums_match_bruteforce():
    ev = _stream([300, 50])
    s = event_sums(ev, (0.0, 0.04), 5)
    assert s.shape == (4, 6, 8)
    inst = (np.arange(5) + 0.5) / 5 * 0.04 * 1e6
    k = 2
    m = (ev.t >= round(inst[k])) & (ev.t < round(inst[k + 1]))
    ref = np.zeros((6, 8))
    np.add.at(ref, (ev.y[m], ev.x[m]), ev.p[m])
    assert np.array_equal(s[k].numpy(), ref)
    assert event_sums(ev, (0.0, 0.04), 1).shape == (0, 6, 8)


# --------------------------------------------------------------------------- model / strategy

def _params(n=10, D=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    return init_params(torch.randn(n, 3, generator=g), torch.rand(n, D, generator=g), opacity=0.5)


def _optims(params):
    return {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}


def _touch(params, opts):
    loss = sum((p ** 2).sum() for p in params.values())
    loss.backward()
    for o in opts.values():
        o.step()


def test_surgery_keeps_adam_state_aligned():
    params = _params(6)
    opts = _optims(params)
    _touch(params, opts)
    duplicate(params, opts, torch.tensor([True, False, False, False, False, True]))
    assert params["means"].shape == (8, 3)
    st = opts["means"].state[params["means"]]
    assert st["exp_avg"].shape == (8, 3) and st["exp_avg"][6:].abs().sum() == 0
    assert opts["means"].param_groups[0]["params"][0] is params["means"]
    remove(params, opts, torch.tensor([True] + [False] * 7))
    assert params["colors"].shape == (7, 1) and opts["colors"].state[params["colors"]]["exp_avg"].shape == (7, 1)
    split(params, opts, torch.tensor([True] + [False] * 6), generator=torch.Generator().manual_seed(0))
    assert params["means"].shape == (8, 3)
    assert torch.allclose(params["scales"][-1], params["scales"][-2])
    reset_opacity(params, opts, 0.01)
    assert torch.sigmoid(params["opacities"]).max() <= 0.01 + 1e-6
    _touch(params, opts)  # still trainable after surgery
    assert all(torch.isfinite(p).all() for p in params.values())


def _info(N, grad, C=3, W=64, H=48):
    m2d = torch.zeros(C, N, 2, requires_grad=True)
    m2d.grad = torch.zeros(C, N, 2)
    m2d.grad[:, :, 0] = grad
    radii = torch.ones(C, N, 2, dtype=torch.int32)
    return {"means2d": m2d, "radii": radii, "width": W, "height": H}


def test_strategy_clone_split_prune_reset_fire():
    cfg = C.StrategyConfig(grad_threshold=1e-3, refine_start=0, refine_every=2, reset_every=4,
                           split_scale=0.1, prune_opacity=0.05)
    params = _params(4)
    with torch.no_grad():
        params["scales"][:2] = math.log(0.01)  # small -> clone
        params["scales"][2:] = math.log(1.0)  # big -> split
        params["opacities"][3] = -10  # transparent -> pruned
    opts = _optims(params)
    strat = DefaultStrategy(cfg, scene_scale=1.0, generator=torch.Generator().manual_seed(0))
    state = strat.initialize_state(4)
    grad = torch.tensor([1.0, 0.0, 1.0, 0.0])  # Gaussians 0 and 2 have high gradients
    rep1 = strat.step_post_backward(params, opts, state, 1, _info(4, grad))
    assert rep1 == {"cloned": 0, "split": 0, "pruned": 0, "reset": False}
    assert state["count"].tolist() == [3, 3, 3, 3]  # all 3 cameras of the step accumulated
    rep2 = strat.step_post_backward(params, opts, state, 2, _info(4, grad))
    assert rep2["cloned"] == 1 and rep2["split"] == 1 and rep2["pruned"] == 1
    assert params["means"].shape[0] == 4 + 1 + 1 - 1
    rep4 = strat.step_post_backward(params, opts, state, 4, _info(5, torch.zeros(5)))
    assert rep4["reset"] is True
    assert torch.sigmoid(params["opacities"]).max() <= cfg.reset_opacity + 1e-6


def test_strategy_accumulates_every_virtual_view():
    """One view with a high gradient among five still counts (no 'last view only' bug)."""
    cfg = C.StrategyConfig(grad_threshold=1e-3)
    strat = DefaultStrategy(cfg)
    state = strat.initialize_state(2)
    info = _info(2, torch.zeros(2), C=5)
    info["means2d"].grad[2, 0, 0] = 5.0  # only the middle virtual view moves Gaussian 0
    strat.accumulate(state, info)
    assert state["grad2d"][0] == pytest.approx(5.0 * 64 / 2) and state["grad2d"][1] == 0
    assert state["count"].tolist() == [5, 5]


def test_strategy_respects_max_gaussians():
    cfg = C.StrategyConfig(grad_threshold=1e-3, refine_start=0, refine_every=1, reset_every=0)
    params = _params(4)
    with torch.no_grad():
        params["scales"][:] = math.log(0.001)
    opts = _optims(params)
    strat = DefaultStrategy(cfg, 1.0, max_gaussians=6)
    state = strat.initialize_state(4)
    rep = strat.step_post_backward(params, opts, state, 1, _info(4, torch.ones(4)))
    assert rep["cloned"] == 2 and params["means"].shape[0] == 6


def test_points_from_frames_lie_on_their_rays():
    frames = np.random.default_rng(0).random((2, 12, 16, 1)).astype(np.float32)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, :3, 3] = [1, 0, 0]
    K = np.array([[20.0, 0, 8], [0, 20.0, 6], [0, 0, 1]])
    pts, cols, sc = points_from_frames(frames, c2w, K, 200, (1.0, 4.0), seed=1)
    assert pts.shape == (200, 3) and cols.shape == (200, 1) and sc.shape == (200,)
    z = pts[:, 2]
    assert (z >= 1.0 - 1e-5).all() and (z <= 4.0 + 1e-5).all()
    with pytest.raises(ValueError, match="depth_range"):
        points_from_frames(frames, c2w, K, 5, (2.0, 1.0))


def test_activation_conventions():
    p = _params(5, D=3)
    a = activate(p)
    assert torch.allclose(a["opacities"], torch.full((5,), 0.5))
    assert torch.allclose(a["colors"], (0.5 + SH_C0 * p["colors"]).clamp_min(0))
    with pytest.raises(ValueError, match="points"):
        init_params(torch.zeros(3, 2), torch.zeros(3, 1))


# --------------------------------------------------------------------------- files

@pytest.mark.parametrize("D", [1, 3])
def test_ply_roundtrip(tmp_path, D):
    p = _params(7, D=D)
    path = write_ply(tmp_path / "point_cloud.ply", p)
    header = path.read_bytes().split(b"end_header")[0].decode()
    for name in ["x", "nx", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "rot_3"]:
        assert f"property float {name}\n" in header
    back = read_ply(path)
    for k in p:
        assert torch.equal(back[k], p[k].detach()), k
    if D == 1:  # viewers see grey: the DC value in all three f_dc
        raw = np.frombuffer(path.read_bytes().split(b"end_header\n", 1)[1], "<f4").reshape(7, 17)
        assert np.array_equal(raw[:, 6], raw[:, 7]) and np.array_equal(raw[:, 6], raw[:, 8])


@pytest.mark.parametrize("D", [1, 3])
def test_png16_roundtrip(tmp_path, D):
    img = np.random.default_rng(0).random((5, 7, D))
    back = read_png16(write_png16(tmp_path / "a.png", img))
    assert back.shape == (5, 7, D)
    assert np.abs(back - img).max() <= 0.5 / 65535 + 1e-7
    from PIL import Image
    if D == 1:
        assert np.array(Image.open(tmp_path / "a.png")).dtype == np.uint16 or Image.open(tmp_path / "a.png").mode.startswith("I")
    with pytest.raises(ValueError, match="non-finite"):
        write_png16(tmp_path / "b.png", np.full((2, 2, 1), np.nan))


@pytest.mark.parametrize("shape,window", [((2, 20, 24, 1), 7), ((1, 12, 9, 3), 11), ((1, 5, 6, 1), 11)])
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


@pytest.mark.parametrize("kind", ["linear", "cubic"])
def test_anchored_trajectory_keeps_mid_pose(kind):
    c2w = _random_c2w(3)
    traj = ExposureTrajectories(c2w, kind, scale=0.5, init_noise=0.0, anchored=True)
    with torch.no_grad():
        traj.knots.normal_(0, 0.05)
    p = traj(torch.arange(3), torch.tensor([0.0, 0.5, 1.0]))
    assert torch.allclose(p[:, 1], c2w, atol=1e-5)
    assert not torch.allclose(p[:, 0], p[:, 2], atol=1e-3)
    free = ExposureTrajectories(c2w, kind, scale=0.5)
    with torch.no_grad():
        free.knots.copy_(traj.knots)
    assert not torch.allclose(free(torch.arange(3), torch.tensor([0.5]))[:, 0], c2w, atol=1e-3)


def test_every_config_option_has_its_field_comment_as_help():
    import argparse
    import dataclasses

    from ebad.config import Config, add_dataclass_arguments, field_comments

    @dataclasses.dataclass
    class Demo:
        a: int = 1  # inline help
        #   continued here
        # help above b
        b: float = 2.0
        c: bool = False  # help of c

    assert field_comments(Demo) == {"a": "inline help continued here", "b": "help above b", "c": "help of c"}
    parser = argparse.ArgumentParser()
    add_dataclass_arguments(parser, Config)
    helps = {a.dest: a.help for a in parser._actions if a.dest != "help"}
    assert helps, "no options generated"
    fallback = re.compile(r"^(\(true/false\))?\s*([A-Z]\w*\.\w+)?$")  # empty, or the Class.field stand-in
    undocumented = [k for k, h in helps.items() if fallback.match(h or "")]
    assert not undocumented, undocumented
    assert "tripod" in helps["trajectory.pose_source"]
