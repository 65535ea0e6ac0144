"""Progress (issue 31): the training bar counts the time budget; phases before the first step say what they do."""

from __future__ import annotations

import logging
from types import SimpleNamespace

from ebad.callbacks import ProgressBar, Ticker, say
from ebad.config import preset
from ebad.state import NO_STEP_LIMIT


def _stats(**kw):
    base = dict(loss=0.1, blur=0.1, ev=None, edi=None, gaussians=100, test_psnr=None, train_psnr=20.0)
    return SimpleNamespace(**{**base, **kw})


def test_the_bar_counts_seconds_against_max_seconds():
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = 100_000, 30.0
    bar = ProgressBar(cfg, 0)
    assert bar.bar.total == 30.0  # was train.iters: "0% 259/100000 ... <3:00:53" under a 300 s budget
    bar.on_step(SimpleNamespace(step=7, elapsed=3.25), _stats())  # type: ignore[arg-type]
    assert bar.bar.n == 3.25 and "step=7/100000" in bar.bar.postfix
    bar.on_step(SimpleNamespace(step=8, elapsed=31.0), _stats())  # type: ignore[arg-type]
    assert bar.bar.n == 30.0  # the step that crossed the budget fills the bar, no more
    bar.on_end(None, "time")  # type: ignore[arg-type]


def test_under_a_time_budget_alone_the_bar_shows_the_step_without_a_limit():
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = NO_STEP_LIMIT, 30.0  # train.iters 0 with max_seconds, resolved
    bar = ProgressBar(cfg, 0)
    bar.on_step(SimpleNamespace(step=7, elapsed=3.25), _stats())  # type: ignore[arg-type]
    assert "step=7," in bar.bar.postfix + "," and "/" not in bar.bar.postfix.split("step=")[1]
    bar.on_end(None, "time")  # type: ignore[arg-type]


def test_without_a_budget_the_bar_counts_steps():
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = 500, None
    bar = ProgressBar(cfg, 10)
    assert bar.bar.total == 500 and bar.bar.n == 10
    bar.on_step(SimpleNamespace(step=11, elapsed=1.0), _stats())  # type: ignore[arg-type]
    assert bar.bar.n == 11
    bar.on_end(None, "iters")  # type: ignore[arg-type]


def test_phases_are_logged_or_printed(capsys, caplog):
    log = logging.getLogger("ebad.progress")
    saved = log.handlers[:], log.propagate, log.level
    try:  # no handler shows INFO: printed with show, silent without
        log.handlers, log.propagate = [], False
        say(True, "estimating the contrast threshold")
        say(False, "quiet")
        tick = Ticker(True, "EDI latents", 3, every=1e9)
        for k in (1, 1, 2, 3, 3):  # a count said again is said once
            tick(k)
        err = capsys.readouterr().err
        assert "ebad: estimating the contrast threshold" in err and "quiet" not in err
        assert err.count("EDI latents: 1/3") == 1 and err.count("EDI latents: 3/3") == 1 and "2/3" not in err
    finally:
        log.handlers, log.propagate = saved[0], saved[1]
        log.setLevel(saved[2])
    with caplog.at_level(logging.INFO, logger="ebad.progress"):
        say(False, "initialising the Gaussians")
    assert "initialising the Gaussians" in caplog.text and not capsys.readouterr().err
