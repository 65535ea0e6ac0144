"""ebad.state: TrainState.save / load are each other's inverse, and refuse what is not theirs."""

from __future__ import annotations

import copy

import pytest
import torch

import scenes
from ebad.config import preset
from ebad.data import prepare
from ebad.errors import UserError
from ebad.loop import train_step
from ebad.state import TrainState, capture_fingerprint, max_gaussians, with_step_budget
from ebad.strategy import make_strategy


@pytest.fixture(scope="module")
def tiny():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)


def _setup(capture, name="ebad"):
    cfg = preset(name)
    cfg.train.progress = False
    cfg.strategy.refine_start = 1
    cfg.strategy.refine_every = 2  # densification fires inside the test's few steps
    data = prepare(capture, cfg)
    cfg = with_step_budget(cfg, data.num_frames)  # as reconstruct does: train.iters 0 -> 600 steps here
    state = TrainState.create(data, cfg)
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    state.strategy_state = strategy.initialize_state(state.num_gaussians)
    return cfg, data, state, strategy


def _steps(cfg, data, state, strategy, n):
    for _ in range(n):
        train_step(data, state, strategy, state.next_frame(), cfg)


def test_save_load_then_one_step_equals_one_step(tiny, tmp_path):
    cfg, data, state, strategy = _setup(tiny.capture)
    _steps(cfg, data, state, strategy, 5)  # mid-pass: the frame order is half used
    state.accumulate_knots()
    state.accumulate_knots()  # trajectory.average_from's running sum goes with the checkpoint
    path = tmp_path / "ck" / "last.pt"
    state.save(path)
    loaded = TrainState.load(path, data, cfg)
    assert loaded.step == state.step == 5 and loaded.order == state.order
    assert loaded.knots_count == 2 and torch.equal(loaded.knots_sum, state.knots_sum)
    assert torch.allclose(loaded.knots_mean(), state.trajectories.knots)
    strategy2 = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), loaded.generator)
    torch.manual_seed(123)  # a step draws only from the state's generators: the global RNG plays no part
    _steps(cfg, data, state, strategy, 2)
    torch.manual_seed(456)
    _steps(cfg, data, loaded, strategy2, 2)
    for k in state.params:
        assert torch.equal(state.params[k], loaded.params[k]), k
    assert torch.equal(state.trajectories.knots, loaded.trajectories.knots)
    assert torch.equal(state.strategy_state.grad2d, loaded.strategy_state.grad2d)
    assert [h.loss for h in state.history] == [h.loss for h in loaded.history]
    assert not list(path.parent.glob("*.tmp"))  # the temporary file was renamed into place


def test_load_refuses_a_checkpoint_of_another_capture(tiny, tmp_path):
    cfg, data, state, strategy = _setup(tiny.capture)
    path = tmp_path / "last.pt"
    state.save(path, capture_fingerprint(tiny.capture))
    other = copy.copy(tiny.capture)
    other.frames = other.frames[:1]
    other.exposures = other.exposures[:1]
    other.names = other.names[:1]
    with pytest.raises(UserError, match="made from another capture.*4 frames then, 1 now"):
        TrainState.load(path, data, cfg, capture_fingerprint(other))


def test_load_refuses_a_damaged_checkpoint(tiny, tmp_path):
    cfg, data, state, strategy = _setup(tiny.capture)
    path = tmp_path / "last.pt"
    state.save(path)
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(UserError, match="last.pt: not a readable checkpoint"):
        TrainState.load(path, data, cfg)


def test_learning_rates_decay_over_the_run_to_their_final_fractions(tiny):
    """The means' and the knots' learning rates follow lr * final ** (fraction of the run): at
    the start the configured lr, half-way the square root of the final fraction."""
    cfg, data, state, strategy = _setup(tiny.capture)
    cfg.train.iters = 4
    cfg.train.lr_means_final = 0.01
    cfg.trajectory.lr_final = 0.25
    lr = lambda name: state.optimizers[name].param_groups[0]["lr"]  # noqa: E731
    _steps(cfg, data, state, strategy, 1)  # step 0 of 4
    assert lr("poses") == pytest.approx(cfg.trajectory.lr)
    assert lr("means") == pytest.approx(cfg.train.lr_means * data.scale)
    _steps(cfg, data, state, strategy, 2)  # step 2 of 4
    assert lr("poses") == pytest.approx(cfg.trajectory.lr * 0.5)
    assert lr("means") == pytest.approx(cfg.train.lr_means * data.scale * 0.1)


def test_the_run_s_trajectories_are_the_mean_of_the_knots_since_average_from(tiny):
    from ebad.run import reconstruct

    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 10, False, 0
    seen = []

    class Knots:
        def on_step(self, state, stats):
            seen.append((state.step, state.trajectories.knots.detach().clone()))

        def on_end(self, state, reason):
            pass

    cfg.trajectory.average_from = 0.5
    run = reconstruct(tiny.capture, cfg, callbacks=[Knots()])
    tail = [k for step, k in seen if step >= 5]  # steps 5 to 10 of 10
    assert run.metrics.averaged_steps == len(tail) == 6
    assert torch.allclose(run.trajectories.knots, torch.stack(tail).mean(0), atol=1e-7)
    assert not torch.allclose(run.trajectories.knots, seen[-1][1])  # the knots moved over the tail
    seen.clear()
    cfg.trajectory.average_from = 1.0
    run = reconstruct(tiny.capture, cfg, callbacks=[Knots()])
    assert run.metrics.averaged_steps == 0 and torch.equal(run.trajectories.knots, seen[-1][1])


def test_adam_is_fused_where_torch_has_it_and_falls_back_to_the_same_update(monkeypatch):
    from ebad import state as S

    g = torch.Generator().manual_seed(0)
    start = torch.randn(50, 3, generator=g)
    grads = [torch.randn(50, 3, generator=g) for _ in range(5)]

    def run(opt_factory):
        p = torch.nn.Parameter(start.clone())
        opt = opt_factory([p])
        for gr in grads:
            p.grad = gr.clone()
            opt.step()
        return opt, p.detach()

    fused, p_fused = run(lambda ps: S._adam(ps, lr=1e-2, eps=1e-15))
    assert fused.defaults["fused"]
    real_adam = torch.optim.Adam

    def adam_without_fused(params, fused=None, **kw):  # what torch < 2.4 does on the CPU
        if fused:
            raise RuntimeError("`fused=True` requires all the params to be floating point Tensors of supported devices")
        return real_adam(params, **kw)

    monkeypatch.setattr(torch.optim, "Adam", adam_without_fused)
    plain, p_plain = run(lambda ps: S._adam(ps, lr=1e-2, eps=1e-15))
    assert not plain.defaults.get("fused")
    assert torch.allclose(p_fused, p_plain, rtol=0, atol=1e-7)  # float32 rounding: 1.5e-8 here, the updates 0.05
    assert not torch.equal(p_plain, start)


def test_a_checkpoint_of_an_older_version_with_the_global_rng_state_still_loads(tiny, tmp_path):
    cfg, data, state, strategy = _setup(tiny.capture)
    _steps(cfg, data, state, strategy, 2)
    path = tmp_path / "last.pt"
    state.save(path)
    doc = torch.load(path, weights_only=True)
    assert "torch_rng" not in doc  # nothing draws from torch's global RNG: it is not saved
    doc["torch_rng"] = torch.get_rng_state()  # as checkpoints before it was dropped had it
    torch.save(doc, path)
    rng = torch.get_rng_state()
    loaded = TrainState.load(path, data, cfg)
    assert loaded.step == 2 and torch.equal(torch.get_rng_state(), rng)  # loading leaves the global RNG alone
