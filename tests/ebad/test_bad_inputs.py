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


# --------------------------------------------------------------------------- events.pt counts


def _pt(tmp_path, t):
    path = tmp_path / "events.pt"
    torch.save(t, path)
    return path


def test_events_pt_that_cannot_be_right_is_refused_before_allocating(tmp_path):
    from scenes import CaptureError
    from scenes.e2nerf import read_event_bins

    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    with pytest.raises(CaptureError, match="empty file"):
        read_event_bins(empty)
    huge = torch.zeros(1, 2, 4, dtype=torch.int64)
    huge[0, 1, 2] = 2**62  # wrapped to 0 events in int32
    with pytest.raises(CaptureError, match=r"count 4611686018427387904 at view 0, bin 1, pixel 2"):
        read_event_bins(_pt(tmp_path, huge))
    with pytest.raises(CaptureError, match="count -9223372036854775808"):
        read_event_bins(_pt(tmp_path, torch.full((1, 1, 4), -(2**63), dtype=torch.int64)))
    repeated = torch.ones(1, 1, 1, dtype=torch.int32).expand(1000, 100, 100_000)  # a 2 kB file, 4e7 counts
    with pytest.raises(CaptureError, match="stride 0"):
        read_event_bins(_pt(tmp_path, repeated))
    ok = torch.tensor([[[1, -2, 0, 3]]], dtype=torch.int64)
    np.testing.assert_array_equal(read_event_bins(_pt(tmp_path, ok)), ok.numpy())


def test_events_pt_total_beyond_the_limit_is_refused(tmp_path, monkeypatch):
    import scenes.e2nerf as e2
    from scenes import CaptureError

    monkeypatch.setattr(e2, "MAX_EVENTS", 10)
    with pytest.raises(CaptureError, match="12 events in all: more than 10"):
        e2.read_event_bins(_pt(tmp_path, torch.full((1, 3, 4), -1, dtype=torch.int16)))


# --------------------------------------------------------------------------- finite divergence


def test_a_run_whose_loss_rose_ends_with_a_warning(monkeypatch, caplog):
    """--train.lr_means 1e3 on the tiny boxes scene: loss 0.32 at the first step, 1.39 over the last
    (test PSNR 14.6 -> 3.8), all finite; train() used to return 'iters' with nothing said."""
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.coarse_scale, cfg.train.plateau_patience = 40, 1, 0
    data = SimpleNamespace(scale=1.0, V=np.ones(2, np.int64), height=16, width=16)
    for losses, warned in ((np.linspace(0.32, 0.22, 40), False), (np.r_[0.32, np.full(39, 1.39)], True)):
        state = _state()
        state.step = 0

        def step(data, state, *a, losses=losses, **k):
            state.step += 1
            return SimpleNamespace(
                step=state.step, loss=float(losses[state.step - 1]), train_psnr=20.0, time=0.0, alpha=1.0
            )

        monkeypatch.setattr(loop, "train_step", step)
        caplog.clear()
        with caplog.at_level("WARNING", logger="ebad.loop"):
            assert loop.train(data, state, None, cfg) == "iters"
        assert ("training diverged: the loss rose from 0.32 at step 1 to 1.39" in caplog.text) == warned


def test_a_run_that_learnt_and_lost_the_scene_ends_with_a_warning(monkeypatch, caplog):
    """The training PSNR rose to about 21 dB and fell to 4 (an SfM start on a tiny colour capture, issue
    29's ablation): the loss ended below its first step's, so the loss check was silent; a coarse-to-fine
    drop of a few dB is not a collapse."""
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.coarse_scale, cfg.train.plateau_patience = 80, 1, 0
    data = SimpleNamespace(scale=1.0, V=np.ones(2, np.int64), height=16, width=16)
    rise = np.r_[np.linspace(4.0, 20.8, 20), np.full(20, 20.8)]
    cases = (
        (np.r_[rise, np.full(40, 4.2)], True),  # collapsed
        (np.r_[rise, np.full(40, 11.0)], False),  # 9.8 dB below: under the 10 dB rule
        (np.r_[np.linspace(20, 33, 20), np.full(20, 33), np.full(40, 30.5)], False),  # coarse to fine
    )
    for psnr, warned in cases:
        state = _state()
        state.step = 0

        def step(data, state, *a, psnr=psnr, **k):
            state.step += 1
            p = float(psnr[state.step - 1])
            return SimpleNamespace(step=state.step, loss=0.5 * 10 ** (-p / 20), train_psnr=p, time=0.0, alpha=1.0)

        monkeypatch.setattr(loop, "train_step", step)
        caplog.clear()
        with caplog.at_level("WARNING", logger="ebad.loop"):
            assert loop.train(data, state, None, cfg) == "iters"
        assert ("training collapsed: the training PSNR fell from 20.8 dB" in caplog.text) == warned, caplog.text
        if warned:
            assert "to 4.2 dB over the last 20 steps" in caplog.text
