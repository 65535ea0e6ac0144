"""ebad.precompile: numba's kernels compiled into the cache by two child processes, the caller loading them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

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


_PARENT = """
import json, numba.core.dispatcher as D
from ebad.precompile import Precompile, kernels_cached
cached_before = kernels_cached()
with Precompile(["grey"]) as pre:
    pre.wait()
compiled = []
orig = D.Dispatcher.compile
def compile(self, sig):  # numba: a signature neither loaded nor compiled yet is compiled here
    n = sum(self._cache_misses.values())
    out = orig(self, sig)
    if sum(self._cache_misses.values()) > n:
        compiled.append(self.py_func.__qualname__)
    return out
D.Dispatcher.compile = compile
from ebad.run import warm_up
warm_up(["grey"])
print(json.dumps({"before": cached_before, "started": pre.started, "failed": pre.failed, "after": kernels_cached(),
                  "compiled": compiled}))
"""


@pytest.mark.slow
def test_after_the_children_the_callers_warm_up_compiles_no_kernel(tmp_path):
    # a cold cache: the two children compile every kernel warm_up reaches (each half once), the caller loads them
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    r = subprocess.run([sys.executable, "-c", _PARENT], env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["before"] is False and out["started"] is True and out["failed"] == [] and out["after"] is True
    # the scene simulator's kernel is the caller's own (its tiny scene); no kernel of a training step is compiled
    assert set(out["compiled"]) <= {"_crossings_numba"}, out["compiled"]
