"""Every option ``Config.check`` validates, at its boundaries: the first value that cannot work
is refused naming the option, the last one that can is accepted; and ``train.pose_warmup`` does
what it says in the loop."""

from __future__ import annotations

import dataclasses
import math
import typing

import pytest
import torch

from ebad import config as C
from ebad.errors import ConfigError

# option -> (values refused, values accepted); the accepted ones sit at the boundary where there is one
RULES: dict[str, tuple[tuple, tuple]] = {
    "model.init_points": ((0, -1), (1,)),
    "model.init_opacity": ((0.0, 1.0), (1e-6, 1 - 1e-6)),
    "model.init_scale_px": ((0.0, -1.0), (1e-6,)),
    "model.init_depth": (((0.0, 1.0), (2.0, 1.0), (1.0, 1.0)), ((1e-3, 1.0), None)),
    "model.min_sfm_points": ((0,), (1,)),
    "model.stereo_depths": ((1,), (2,)),
    "model.stereo_neighbours": ((0,), (1,)),
    "model.stereo_patch": ((0, 4, -1), (1, 3)),
    "model.max_gaussians": ((-1,), (0, 1)),
    "model.background": ((-0.01, 1.01), (0.0, 1.0)),
    "model.sh_degree": ((-1, 4), (0, 3)),
    "model.sh_degree_interval": ((0, -1), (1,)),
    "model.lr_response": ((-1e-6,), (0.0,)),
    "trajectory.num_views": ((0,), (1,)),
    "trajectory.sharp_events_per_pixel": ((-1e-6,), (0.0,)),
    "trajectory.view_spacing": ((-1e-6,), (0.0, 2.0)),
    "trajectory.max_views": ((1,), (2,)),
    "trajectory.init_noise": ((-1e-6,), (0.0,)),
    "trajectory.lr": ((-1e-6,), (0.0,)),
    "trajectory.lr_final": ((0.0, 1.01), (1e-6, 1.0)),
    "trajectory.average_from": ((-0.01, 1.01), (0.0, 1.0)),
    "loss.event_windows": (("sliding",), ("consecutive", "random")),
    "loss.event_norm": (("l3",), ("l1", "l2")),
    "loss.edi_prior": (("mapEDI",), ("edi",)),
    "loss.cfa_events": (("mean",), ("filter", "luminance")),
    "loss.cfa_frames": (("raw",), ("rgb", "mosaic")),
    "loss.edi_instants": (("all",), ("mid", "views")),
    "loss.w_blur": ((-1e-6,), (0.0,)),
    "loss.w_event": ((-1e-6,), (0.0,)),
    "loss.w_edi": ((-1e-6,), (0.0,)),
    "loss.ssim_weight": ((-0.01, 1.01), (0.0, 1.0)),
    "loss.ssim_window": ((0, 6, -1), (1, 11)),
    "loss.contrast": (((0.0, 0.2), (0.2, -0.1), (0.2,)), ((1e-3, 1e-3), None)),
    "loss.lr_contrast": ((-1e-6,), (0.0,)),
    "strategy.grad_threshold": ((0.0, -1e-6), (1e-9,)),
    "strategy.split_shrink": ((1.0, 0.5), (1.0 + 1e-6,)),
    "strategy.prune_opacity": ((-1e-6, 1.0), (0.0, 0.999)),
    "strategy.refine_every": ((0,), (1,)),
    "strategy.reset_every": ((-1,), (0,)),
    "strategy.reset_opacity": ((0.0, 1.0), (1e-6, 0.999)),
    "strategy.reset_until": ((-0.01, 1.01), (0.0, 1.0)),
    "train.iters": ((-1,), (0, 1)),
    "train.max_seconds": ((0.0, -1.0), (1e-3, None)),
    "train.plateau_patience": ((-1,), (0,)),
    "train.plateau_every": ((0,), (1,)),
    "train.plateau_tol": ((-1e-6,), (0.0,)),
    "train.empty_render_steps": ((-1,), (0,)),
    "train.lr_means": ((-1e-6,), (0.0,)),
    "train.lr_scales": ((-1e-6,), (0.0,)),
    "train.lr_quats": ((-1e-6,), (0.0,)),
    "train.lr_opacities": ((-1e-6,), (0.0,)),
    "train.lr_colors": ((-1e-6,), (0.0,)),
    "train.lr_means_final": ((0.0, 1.01), (1e-6, 1.0)),
    "train.pose_warmup": ((-1,), (0,)),
    "train.coarse_scale": ((0,), (1,)),
    "train.coarse_until": ((-0.01, 1.01), (0.0, 1.0)),
    "train.eval_every": ((-1,), (0,)),
    "train.checkpoint_every": ((-1,), (0,)),
}


def _set(cfg: C.Config, option: str, value) -> None:
    section, name = option.split(".")
    setattr(getattr(cfg, section), name, value)


CASES = [(o, v, ok) for o, (bad, good) in RULES.items() for ok, vals in ((False, bad), (True, good)) for v in vals]


@pytest.mark.parametrize("option,value,ok", CASES, ids=[f"{o}={v}" for o, v, _ in CASES])
def test_each_checked_option_refuses_past_its_boundary_and_accepts_at_it(option, value, ok):
    cfg = C.preset("ebad")
    if option == "loss.edi_instants":
        cfg.loss.edi_prior = "edi"
    _set(cfg, option, value)
    if ok:
        assert cfg.check() is cfg
    else:
        with pytest.raises(ConfigError) as info:
            cfg.check()
        assert str(info.value).startswith(f"--{option}: "), str(info.value)


def _fields():
    for section in ("model", "trajectory", "loss", "strategy", "train"):
        cls = type(getattr(C.Config(), section))
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            yield f"{section}.{f.name}", hints[f.name]


def _probes(t) -> list:
    """Values of type ``t`` that a range check would refuse somewhere (no NaN: that is the finite check's)."""
    args = [a for a in typing.get_args(t) if a is not type(None)]
    if typing.get_origin(t) is typing.Literal:
        return ["bogus"]
    if typing.get_origin(t) in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return _probes(args[0])
    if typing.get_origin(t) is tuple:
        return [(2.0, 1.0), (-1.0, 1.0), (0.0, 0.0)]
    if t is bool or t is str:
        return []
    return [-1, 0, 1, 2, 4, 6, 0.5, 1.5, 1e9, -1e9] if t is int else [-1.0, 0.0, 0.5, 1.0, 1.01, 2.0, 1e9, -1e9]


def test_every_option_check_validates_is_in_the_table():
    """Probe every field with values of its type: any that ``check`` refuses must be tested above."""
    validated = set()
    for option, t in _fields():
        for v in _probes(t):
            cfg = C.preset("ebad")
            _set(cfg, option, v)
            try:
                cfg.check()
            except ConfigError as exc:
                if str(exc).startswith(f"--{option}: "):
                    validated.add(option)
    assert validated - set(RULES) == set(), "options check validates that no test covers"
    assert set(RULES) - validated == set(), "options the table tests that check does not validate"


def test_every_float_option_must_be_finite():
    for option, t in _fields():
        args = typing.get_args(t)
        if t is float or (float in args and typing.get_origin(t) is not tuple):
            for bad in (math.nan, math.inf):
                cfg = C.preset("ebad")
                _set(cfg, option, bad)
                with pytest.raises(ConfigError, match=f"--{option}: must be a finite number"):
                    cfg.check()


def test_the_cross_checks_name_the_option():
    cfg = C.preset("ebad")
    cfg.loss.edi_prior, cfg.loss.edi_instants = "medi", "views"
    with pytest.raises(ConfigError, match="^--loss.edi_instants: views needs loss.edi_prior edi"):
        cfg.check()
    cfg.loss.edi_instants = "mid"
    cfg.check()
    cfg = C.preset("ebad")
    cfg.trajectory.view_spacing, cfg.train.coarse_until = 2.0, 0.0
    with pytest.raises(ConfigError, match="^--trajectory.view_spacing: needs train.coarse_until > 0"):
        cfg.check()


# --------------------------------------------------------------------------- train.pose_warmup in the loop


@pytest.mark.parametrize("warmup", [0, 1, 3])
def test_pose_warmup_holds_the_trajectories_for_exactly_that_many_steps(warmup):
    import scenes
    from ebad.data import prepare
    from ebad.loop import train_step
    from ebad.state import TrainState, max_gaussians
    from ebad.strategy import make_strategy

    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=3, n_test=1)
    cfg = C.preset("ebad")
    cfg.train.pose_warmup, cfg.train.progress, cfg.train.iters = warmup, False, 600
    data = prepare(sc.capture, cfg)
    state = TrainState.create(data, cfg)
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    state.strategy_state = strategy.initialize_state(state.num_gaussians)
    moved = []
    for _ in range(warmup + 1):
        before = state.trajectories.knots.detach().clone()
        train_step(data, state, strategy, state.next_frame(), cfg)
        moved.append(not torch.equal(before, state.trajectories.knots))
    assert moved == [False] * warmup + [True]  # steps 0 .. warmup-1 hold the knots, step `warmup` moves them
