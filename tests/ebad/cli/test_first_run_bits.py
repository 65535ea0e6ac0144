"""``ebad reconstruct`` on a cold numba cache gives the bits of every later run (issue 32: same capture, same run).

A process that compiles numba's tile compositing kernels runs other machine code than the cache keeps
(tests/splat_cpu/test_cold_cache.py); a first run therefore lets two child processes compile (``ebad.precompile``)
while it prepares the capture, and loads their kernels from the cache, as later runs do. ``ebad demo`` does
the same through the same ``Precompile`` (tests/ebad/test_precompile.py checks its order of work).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


_RUN = """
import json, sys, numba.core.dispatcher as D
compiled = []
orig = D.Dispatcher.compile
def compile(self, sig):  # numba: a signature neither loaded from the cache nor compiled yet is compiled here
    n = sum(self._cache_misses.values())
    out = orig(self, sig)
    if sum(self._cache_misses.values()) > n:
        compiled.append(self.py_func.__module__ + "." + self.py_func.__qualname__)
    return out
D.Dispatcher.compile = compile
from ebad.cli import main
assert main(sys.argv[1:]) == 0
print(json.dumps(compiled))
"""


def _reconstruct(capture: Path, out: Path, cache: Path) -> tuple[str, list[str]]:  # -> stderr, what it compiled
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    args = ["reconstruct", str(capture), "--out", str(out), "--train.iters", "11", "--train.eval_every", "0"]
    r = subprocess.run([sys.executable, "-c", _RUN, *args], env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stderr, json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_first_run_on_a_cold_cache_gives_the_bits_of_the_later_runs(tmp_path):
    from ebad.cli import main

    assert main(["synth", "boxes", "--out", str(tmp_path / "scene"), "--size", "tiny", "--frames", "4"]) == 0
    capture, cache = tmp_path / "scene" / "capture", tmp_path / "numba"
    cold, compiled = _reconstruct(capture, tmp_path / "cold", cache)
    assert "waiting for the processes compiling numba's kernels" in cold, cold
    # the children compiled the rasteriser, the losses and the poses; this process loaded them (it compiled at most
    # what it ran while they worked: EDI's kernels, in prepare)
    assert not [k for k in compiled if k.startswith(("splat_cpu.", "ebad."))], compiled
    warm, compiled = _reconstruct(capture, tmp_path / "warm", cache)
    assert "compiling" not in warm and compiled == [], (warm, compiled)  # loaded: no child started
    for name in ("point_cloud.ply", "trajectories.json"):
        assert (tmp_path / "cold" / name).read_bytes() == (tmp_path / "warm" / name).read_bytes(), name
