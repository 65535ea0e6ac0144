"""``train.iters`` 0 (the default): a step budget in proportion to the training frames, or the clock alone under
``train.max_seconds`` (issue 31: a 30-frame capture had the 600 steps of a 10-frame one, 20 a frame, and
``--train.max_seconds 900`` stopped at 600 steps)."""

from __future__ import annotations

import logging

import pytest

import scenes
from ebad import reconstruct
from ebad.config import preset
from ebad.schedule import Schedule
from ebad.state import NO_STEP_LIMIT, step_budget, with_step_budget


def _cfg(iters=0, max_seconds=None):
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = iters, max_seconds
    cfg.train.progress, cfg.train.eval_every = False, 0
    return cfg


@pytest.mark.parametrize(("frames", "steps"), [(1, 600), (4, 600), (10, 600), (11, 660), (30, 1800), (87, 5220)])
def test_automatic_budget_is_60_steps_a_frame_and_at_least_600(frames, steps):
    assert step_budget(_cfg(), frames) == steps


def test_a_given_budget_is_kept_and_a_time_budget_alone_has_no_step_limit():
    assert step_budget(_cfg(iters=7), 30) == 7
    assert step_budget(_cfg(iters=7, max_seconds=60.0), 30) == 7  # both given: whichever comes first, as before
    assert step_budget(_cfg(max_seconds=60.0), 30) == NO_STEP_LIMIT


def test_with_step_budget_copies_and_leaves_the_given_config_alone():
    cfg = _cfg()
    out = with_step_budget(cfg, 30)
    assert out.train.iters == 1800 and cfg.train.iters == 0
    assert out.loss == cfg.loss and out.model == cfg.model


def test_an_unresolved_budget_is_an_internal_error_not_a_division():
    with pytest.raises(ValueError, match="with_step_budget"):
        Schedule.from_config(_cfg(), 1.0)


class _Stop(Exception):
    pass


class _StopAtFirstStep:
    def on_step(self, state, stats):
        raise _Stop

    def on_end(self, state, reason):
        pass


def test_reconstruct_gives_a_12_frame_capture_720_steps_and_says_so(caplog):
    cap = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=12, n_test=0, sensor="ideal").capture
    cfg = _cfg()
    with caplog.at_level(logging.INFO, logger="ebad.progress"), pytest.raises(_Stop):
        reconstruct(cap, cfg, callbacks=[_StopAtFirstStep()])
    assert "budget (train.iters 0, automatic): 720 steps" in caplog.messages
    assert cfg.train.iters == 0  # the caller's config is not changed


def test_reconstruct_under_a_time_budget_alone_runs_until_the_clock(caplog):
    cap = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=0, sensor="ideal").capture
    with caplog.at_level(logging.INFO, logger="ebad.progress"):
        run = reconstruct(cap, _cfg(max_seconds=2.0))
    assert "budget (train.iters 0, automatic): no step limit" in caplog.messages
    assert run.metrics.stop_reason == "time" and run.config.train.iters == NO_STEP_LIMIT
    assert run.metrics.steps >= 1 and run.metrics.train_seconds >= 2.0
