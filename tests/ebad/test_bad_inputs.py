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
