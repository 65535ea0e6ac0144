"""ebad.precompile: numba's kernels compiled into the cache by two child processes, the caller loading them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from ebad import precompile

ROOT = Path(__file__).resolve().parents[2]


def test_no_child_starts_on_a_warm_cache(monkeypatch):
    monkeypatch.setattr(precompile, "kernels_cached", lambda: True)
    with precompile.Precompile(["grey"]) as pre:
        assert not pre.started and pre.procs == []
        assert pre.wait() >= 0 and pre.failed == []


def test_children_are_ended_when_the_caller_raises(monkeypatch):
    class Sleeper(subprocess.Popen):  # a child that would outlive the caller
        def __init__(self, cmd, **kw):
            super().__init__([sys.executable, "-c", "import time; time.sleep(60)"], **kw)

    monkeypatch.setattr(precompile, "kernels_cached", lambda: False)
    monkeypatch.setattr(precompile.subprocess, "Popen", Sleeper)
    with pytest.raises(KeyError), precompile.Precompile(["grey"]) as pre:
        assert pre.started and len(pre.procs) == 2
        raise KeyError("the caller failed")
    assert all(p.poll() is not None for p in pre.procs)


def test_a_failed_child_is_named(monkeypatch):
    class Failing(subprocess.Popen):
        def __init__(self, cmd, **kw):
            super().__init__([sys.executable, "-c", f"raise SystemExit({int(cmd[-2] == 'losses')})"], **kw)

    monkeypatch.setattr(precompile, "kernels_cached", lambda: False)
    monkeypatch.setattr(precompile.subprocess, "Popen", Failing)
    with precompile.Precompile(["grey"]) as pre:
        pre.wait()
    assert pre.failed == ["losses"]


_ORPHAN = """
import os, subprocess, sys
code = "import sys, time; from ebad.precompile import end_with_parent as e; e(int(sys.argv[1]), 0.05); time.sleep(60)"
child = subprocess.Popen([sys.executable, "-c", code, str(os.getpid())])
print(child.pid, flush=True)
child.wait()
"""


def test_a_child_ends_when_its_parent_is_killed():
    # a demo killed outright (SIGKILL: no __exit__ runs) must not leave a child compiling for a minute
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p))
    parent = subprocess.Popen([sys.executable, "-c", _ORPHAN], env=env, stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    pid = int(parent.stdout.readline())
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 50  # a loaded machine starts python slowly
    while time.monotonic() < deadline and Path(f"/proc/{pid}").exists() and "Z" not in _state(pid):
        time.sleep(0.05)
    gone = not Path(f"/proc/{pid}").exists() or "Z" in _state(pid)
    if not gone:
        os.kill(pid, 9)
    assert gone


def _state(pid: int) -> str:  # the process's state letter (Z: exited, not yet reaped), "" when gone
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return ""


class _Stop(Exception):
    pass


def test_the_demo_compiles_while_it_builds_its_scene_and_scores_after_loading_the_kernels(
    tmp_path, monkeypatch, capsys
):
    # the children start before the scene is built, and the demo scores the blurry frames (SSIM's kernel) once
    # warm_up has loaded the kernels: scored before, its process would compile SSIM's kernel beside a child
    import ebad.evaluate
    import ebad.run
    import scenes
    from ebad.cli import demo

    events: list = []

    class Recorder:
        started = True
        failed = ["losses"]  # its kernels are left to the demo's warm_up, and the demo says so
        failure = precompile.Precompile.failure  # the real wording

        def __init__(self, kinds):
            events.append(("start", list(kinds)))

        def wait(self) -> float:
            events.append("wait")
            return 0.0

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            events.append("stop")

    def score_frames(*args):
        events.append("score")
        raise _Stop

    cap = SimpleNamespace(
        num_frames=3, width=8, height=6, events=[], test_views=[], effective_pose_trust="exact", frames=None
    )
    monkeypatch.setattr(precompile, "Precompile", Recorder)
    monkeypatch.setattr(
        scenes, "make_scene", lambda *a, **kw: events.append("scene") or SimpleNamespace(capture=cap, gt_frames=None)
    )
    monkeypatch.setattr(scenes, "save", lambda *a, **kw: None)
    monkeypatch.setattr(ebad.run, "warm_up", lambda kinds: events.append("warm_up") or 0.0)
    monkeypatch.setattr(ebad.evaluate, "score_frames", score_frames)
    with pytest.raises(_Stop):
        demo.run(demo.Args(out=str(tmp_path / "o"), size="tiny"))
    assert events == [("start", ["grey"]), "scene", "wait", "stop", "warm_up", "score"]
    assert "s from the start (the losses process failed: compiled below)" in capsys.readouterr().out


# A cold first run end to end (the children compile, the caller loads, its bits are the later runs'):
# tests/ebad/cli/test_first_run_bits.py, through `ebad reconstruct`, which uses this Precompile as the demo does.


def test_the_failure_line_names_the_children_that_failed():
    pre = object.__new__(precompile.Precompile)  # no child started: only the wording is under test
    pre.failed = []
    assert pre.failure == ""
    pre.failed = ["losses"]
    assert pre.failure == "the losses process failed"
    pre.failed = ["raster", "losses"]
    assert pre.failure == "the raster and losses processes failed"


_CHILD = """
import json, sys, numba.core.dispatcher as D
called = []
orig = D.Dispatcher.compile
def compile(self, sig):  # every kernel run for a new signature comes here, loaded from the cache or compiled
    called.append(self.py_func.__module__ + "." + self.py_func.__qualname__)
    return orig(self, sig)
D.Dispatcher.compile = compile
from ebad.precompile import _child
_child(sys.argv[1], ["grey"])
print(json.dumps(called))
"""


def _compiled_by_child(part: str) -> list[str]:  # the kernels a child ran, each compiled or loaded from the cache
    env = dict(os.environ, EBAD_PRECOMPILE_PARENT=str(os.getpid()), NUMBA_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    r = subprocess.run([sys.executable, "-c", _CHILD, part], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_no_kernel_is_compiled_by_both_children():
    # both children build and prepare a tiny capture and train it 3 steps. The rasteriser's child estimates no c and
    # runs EDI's numpy reference, the quaternions' normalisation and densification's screen gradients as plain
    # Python: the losses child compiles them. Neither compiles the event simulator (plain Python on the
    # tiny capture): a recorded capture never needs it, and the demo compiles it for its own scene.
    raster, losses = _compiled_by_child("raster"), _compiled_by_child("losses")
    assert "splat_cpu._numba_kernels.backward_tiles" in raster, raster
    assert [k for k in raster if not k.startswith("splat_cpu.")] == [], raster
    assert "ebad.kernels._numba_ssim.ssim_backward" in losses and "edi._kernels._edi_pass_numba" in losses, losses
    assert [k for k in losses if k.startswith(("splat_cpu.", "scenes."))] == [], losses
