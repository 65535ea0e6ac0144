"""Inputs and runs that used to go silently wrong (issue 32): divergence, frames without events."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from ebad import loop
from ebad.callbacks import Checkpointer
from ebad.config import preset
from ebad.errors import EbadError


def _state(bad: str | None = None):
    params = {k: torch.nn.Parameter(torch.zeros(3)) for k in ("means", "scales")}
    if bad is not None:
        with torch.no_grad():
            params[bad][1] = float("nan")
    opts = {k: torch.optim.Adam([p]) for k, p in params.items()}
    return SimpleNamespace(optimizers=opts, step=7, elapsed=0.0, next_frame=lambda: 0, history=[])


def test_check_finite_names_the_option_to_lower():
    loop.check_finite(_state(), 7)  # finite: nothing said
    with pytest.raises(
        loop.DivergedError, match=r"step 7: the means parameters became non-finite; lower --train\.lr_means"
    ):
        loop.check_finite(_state("means"), 7)
    assert issubclass(loop.DivergedError, EbadError)


def test_diverged_run_keeps_the_last_good_checkpoint(monkeypatch, tmp_path):
    """A step that diverges raises DivergedError out of train(), and the Checkpointer does not save
    the diverged state over the checkpoint written before it."""
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.coarse_scale = 50, 1
    data = SimpleNamespace(scale=1.0, V=np.ones(2, np.int64), height=16, width=16)
    saved: list[str] = []

    class Probe(Checkpointer):
        def on_end(self, state, reason):
            saved.append(reason)

    def step(*a, **k):
        raise loop.DivergedError("training diverged at step 0: the loss became non-finite")

    monkeypatch.setattr(loop, "train_step", step)
    ends: list[str] = []
    other = SimpleNamespace(on_step=lambda s, st: None, on_end=lambda s, r: ends.append(r))
    with pytest.raises(loop.DivergedError):
        loop.train(data, _state(), None, cfg, [Probe(tmp_path / "last.pt", 0, None), other])
    assert saved == [] and ends == ["iters"]


def test_rasteriser_non_finite_is_a_divergence(monkeypatch):
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.coarse_scale = 50, 1
    data = SimpleNamespace(scale=1.0, V=np.ones(2, np.int64), height=16, width=16)

    def step(*a, **k):
        raise ValueError("means: contains non-finite values (nan or inf)")

    monkeypatch.setattr(loop, "train_step", step)
    with pytest.raises(loop.DivergedError, match="non-finite.*lower"):
        loop.train(data, _state(), None, cfg)


# --------------------------------------------------------------------------- frames without events


def _capture(ev_t_us: list[int], exposures: list[tuple[float, float]]):
    from edi import EventStream
    from scenes import Capture

    F, H, W = len(exposures), 16, 16
    c2w = np.repeat(np.eye(4)[None], F, 0)
    c2w[:, 0, 3] = np.arange(F) * 0.1
    n = len(ev_t_us)
    events = EventStream(
        np.array(ev_t_us, np.int64), np.arange(n) % W, np.zeros(n, np.int64), np.ones(n, np.int8), W, H
    )
    return Capture(
        frames=np.full((F, H, W, 1), 0.5, np.float32),
        exposures=np.array(exposures, np.float64),
        events=events,
        K=np.array([[16.0, 0, 8], [0, 16.0, 8], [0, 0, 1]]),
        c2w=c2w,
        names=[f"f{i}" for i in range(F)],
    )


def _cfg():
    cfg = preset("ebad")
    cfg.loss.w_event, cfg.loss.w_edi, cfg.loss.target = 0.0, 0.0, "frames"
    return cfg


def test_a_frame_without_events_is_a_named_warning(caplog):
    from ebad.data import prepare

    # frames 0 and 2 have events in their 10 ms exposures, frame 1 none, frame 3 is sharp (no window)
    cap = _capture([1000, 2000, 41000], [(0.0, 0.01), (0.02, 0.03), (0.04, 0.05), (0.06, 0.06)])
    with caplog.at_level("WARNING", logger="ebad.data"):
        data = prepare(cap, _cfg())
    assert data.report.frames_without_events == ["f1"]
    assert "1 of 4 training frames hold no event" in caplog.text and "f1" in caplog.text


def test_no_frame_with_events_is_an_error_naming_the_times():
    from ebad.data import prepare
    from ebad.errors import UserError

    # events in nanoseconds read as microseconds: 1e3 x later than the frames' 0..50 ms
    cap = _capture([1_000_000, 21_000_000, 41_000_000], [(0.0, 0.01), (0.02, 0.03), (0.04, 0.05)])
    with pytest.raises(
        UserError, match=r"none of the 3 training exposures holds an event.*\[0, 0\.01\].*from 1 to 41 s"
    ):
        prepare(cap, _cfg())
