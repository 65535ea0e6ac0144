"""The run's schedule (``ebad.schedule``): what happens at which fraction of the budget, and that
the loop does it there (an opacity reset fires, the coarse phase ends, averaging starts)."""

from __future__ import annotations

import pytest
import torch

import scenes
from ebad.config import preset
from ebad.data import prepare
from ebad.loop import train
from ebad.schedule import Schedule
from ebad.state import TrainState, max_gaussians
from ebad.strategy import make_strategy


@pytest.fixture(scope="module")
def capture():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1).capture


def _cfg(iters: int):
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = iters, False, 0
    return cfg


def _train(capture, cfg) -> TrainState:
    data = prepare(capture, cfg)
    state = TrainState.create(data, cfg)
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    state.strategy_state = strategy.initialize_state(state.num_gaussians)
    assert train(data, state, strategy, cfg) == "iters"
    return state


def test_the_fraction_is_steps_or_time_whichever_is_further():
    cfg = _cfg(100)
    s = Schedule.from_config(cfg, scale=1.0)
    assert s.fraction(25, 1e6) == 0.25  # no time budget: steps only
    cfg.train.max_seconds = 10.0
    s = Schedule.from_config(cfg, scale=1.0)
    assert s.fraction(25, 5.0) == 0.5 and s.fraction(75, 5.0) == 0.75 and s.fraction(25, 50.0) == 1.0


def test_each_item_happens_at_its_fraction():
    cfg = _cfg(10)
    cfg.train.coarse_until, cfg.strategy.reset_until, cfg.trajectory.average_from = 0.3, 0.5, 0.7
    cfg.trajectory.view_spacing = 2.0
    cfg.train.lr_means, cfg.train.lr_means_final, cfg.trajectory.lr, cfg.trajectory.lr_final = 1e-2, 0.1, 1e-3, 0.5
    s = Schedule.from_config(cfg, scale=2.0)
    phases = [s.at(k, 0.0) for k in range(11)]
    assert [p.coarse for p in phases] == [True] * 3 + [False] * 8
    assert [p.views_due for p in phases] == [False] * 3 + [True] * 8
    assert [p.resets for p in phases] == [True] * 5 + [False] * 6
    assert [p.averaging for p in phases] == [False] * 7 + [True] * 4
    assert phases[0].lr_means == pytest.approx(2e-2) and phases[10].lr_means == pytest.approx(2e-3)
    assert phases[0].lr_poses == pytest.approx(1e-3) and phases[10].lr_poses == pytest.approx(5e-4)
    off = Schedule.from_config(cfg, scale=2.0, coarse=False, choose_views=False, averaging=False)
    assert not any(p.coarse or p.views_due or p.averaging for p in (off.at(k, 0.0) for k in range(11)))
    cfg.trajectory.average_from = 1.0  # 1: the last step's knots, never averaged
    assert Schedule.from_config(cfg, scale=2.0).average_from is None


def test_in_training_a_reset_fires_only_before_reset_until_and_the_coarse_phase_ends_at_coarse_until(capture):
    cfg = _cfg(10)
    cfg.strategy.refine_start, cfg.strategy.refine_every = 1000, 1000  # no refinement: only resets
    cfg.strategy.reset_every, cfg.strategy.reset_until = 2, 0.5
    cfg.train.coarse_until = 0.3
    state = _train(capture, cfg)
    # a reset may fire after 2, 4, 6 and 8 steps (StepStats.step counts the step itself: 3, 5, 7,
    # 9); those at fractions 0.2 and 0.4 are before reset_until, those at 0.6 and 0.8 after it
    assert [h.step for h in state.history if h.refine.reset] == [3, 5]
    W = capture.frames.shape[2]
    assert [h.width for h in state.history] == [W // 2] * 3 + [W] * 7  # fractions 0, 0.1, 0.2 coarse


def test_in_training_averaging_starts_where_a_step_ends_at_average_from(capture):
    cfg = _cfg(10)
    cfg.trajectory.average_from = 0.5
    state = _train(capture, cfg)
    assert state.knots_count == 6  # the steps ending at fractions 0.5, 0.6, ..., 1.0
    assert state.knots_sum is not None and torch.isfinite(state.knots_sum).all()
