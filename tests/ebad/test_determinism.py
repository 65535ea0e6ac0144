"""Determinism: one seed gives one run, and a run interrupted and resumed is the run that was not.

``reconstruct`` seeds everything from ``train.seed`` (the frame order, the trajectories' initial
noise, densification's splits, random L_ev windows); a checkpoint carries every generator and the
frame order of the current pass. The resume here crosses a pass boundary, where the frame order
draws a new permutation from the restored generator.
"""

from __future__ import annotations

import signal

import pytest
import torch

import scenes
from ebad.config import preset
from ebad.run import reconstruct

ITERS = 11  # 4 training frames: passes end at steps 4 and 8, and the run stops inside the third


@pytest.fixture(scope="module")
def tiny():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)


def _config(seed: int = 0):
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every, cfg.train.seed = ITERS, False, 0, seed
    cfg.train.checkpoint_every = 0
    cfg.strategy.refine_start, cfg.strategy.refine_every = 1, 3  # splits draw from the run's generator
    cfg.strategy.grad_threshold = 1e-6  # so that refinement clones and splits inside the few steps
    cfg.loss.event_windows = "random"  # L_ev's windows draw from it too
    cfg.trajectory.average_from = 0.5  # and the knots' running mean goes with the checkpoint
    return cfg


@pytest.fixture(scope="module")
def whole(tiny):
    """The uninterrupted run of seed 0."""
    return reconstruct(tiny.capture, _config())


def _trace(run) -> list[tuple]:
    """The history without its clocks."""
    return [(h.step, h.frame, h.loss, h.blur, h.ev, h.edi, h.train_psnr, h.gaussians, h.refine) for h in run.history]


def _assert_same_run(a, b):
    assert _trace(a) == _trace(b)
    assert a.params.keys() == b.params.keys()
    for k in a.params:
        assert torch.equal(a.params[k], b.params[k]), k
    assert torch.equal(a.trajectories.knots, b.trajectories.knots)
    assert a.metrics.averaged_steps == b.metrics.averaged_steps


class _InterruptAt:
    """Raises SIGINT in the process after step ``at``: the loop stops there as on Ctrl-C and checkpoints."""

    def __init__(self, at: int):
        self.at = at

    def on_step(self, state, stats):
        if state.step == self.at:
            signal.raise_signal(signal.SIGINT)

    def on_end(self, state, reason):
        pass


def test_two_runs_with_one_seed_are_identical_and_another_seed_differs(tiny, whole):
    a = whole
    torch.manual_seed(123)  # the global generator's state before the call does not matter
    b = reconstruct(tiny.capture, _config())
    assert a.step == ITERS and sum(h.refine.cloned + h.refine.split for h in a.history) > 0
    assert len({h.frame for h in a.history}) == 4
    _assert_same_run(a, b)
    c = reconstruct(tiny.capture, _config(seed=1))
    assert [h.frame for h in c.history] != [h.frame for h in a.history]
    assert not torch.equal(c.trajectories.knots, a.trajectories.knots)


# inside a pass (its rest of the order restored), and at a pass boundary (the order spent: the
# permutation drawn after the resume comes from the restored generator); the second is slow
@pytest.mark.parametrize("stop", [6, pytest.param(4, marks=pytest.mark.slow)])
def test_a_run_interrupted_and_resumed_across_a_pass_boundary_equals_the_uninterrupted_run(tiny, whole, tmp_path, stop):
    out = tmp_path / "run"
    first = reconstruct(tiny.capture, _config(), out_dir=out, callbacks=[_InterruptAt(stop)])
    assert first.metrics.stop_reason == "interrupted (SIGINT)" and first.step == stop
    torch.manual_seed(99)  # what the process did in between does not matter either
    resumed = reconstruct(tiny.capture, _config(), out_dir=out, resume=True)
    assert resumed.metrics.resumed_from == stop and resumed.step == ITERS
    _assert_same_run(whole, resumed)


# one seed, one run across processes: a child process hashes every parameter, the knots and the history of a
# run of CHILD_ITERS steps (past the pass boundary at step 4, where the frame order draws again, with
# refinements at steps 1 and 4, random L_ev windows and the knots' running mean); two children with different
# PYTHONHASHSEED (set and dict order) and NUMBA_NUM_THREADS (numba's reductions), run at the same time, must
# agree bit for bit. The module's own run above has loaded (or compiled and cached) the kernels first, so that
# both children load the same compiled code (see the note in ``TrainConfig.max_seconds``).
CHILD_ITERS = 5
_CHILD = """
import hashlib, sys, torch
sys.path.insert(0, {tests!r})
import scenes
from ebad.run import reconstruct
from test_determinism import _config, _trace
tiny = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
cfg = _config()
cfg.train.iters = {iters}
run = reconstruct(tiny.capture, cfg)
assert len({{h.frame for h in run.history}}) == 4 and sum(h.refine.cloned + h.refine.split for h in run.history) > 0
h = hashlib.sha256(repr(_trace(run)).encode())
for k in sorted(run.params):
    h.update(run.params[k].detach().contiguous().numpy().tobytes())
h.update(run.trajectories.knots.detach().contiguous().numpy().tobytes())
print("DIGEST", h.hexdigest())
"""


def _child_digests(*settings: tuple[str, str]) -> list[str]:
    """The digests of children run side by side, one per (PYTHONHASHSEED, NUMBA_NUM_THREADS)."""
    import os
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = _CHILD.format(tests=str(Path(__file__).resolve().parent), iters=CHILD_ITERS)
    procs = []
    for hash_seed, threads in settings:
        env = dict(os.environ, PYTHONHASHSEED=hash_seed, NUMBA_NUM_THREADS=threads)
        env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
        out, err = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")  # no pipe to fill while we wait
        procs.append((subprocess.Popen([sys.executable, "-c", code], env=env, stdout=out, stderr=err), out, err))
    digests = []
    for proc, out, err in procs:
        rc = proc.wait(timeout=600)
        out.seek(0), err.seek(0)
        assert rc == 0, err.read()[-2000:]
        digests.append([line for line in out.read().splitlines() if line.startswith("DIGEST")][-1])
    return digests


@pytest.mark.slow
def test_two_processes_with_one_seed_give_bit_identical_runs(whole):
    # ``whole`` first: the kernels are in numba's cache before the children start
    a, b = _child_digests(("0", "2"), ("12345", "1"))
    assert a == b
