"""What a first run compiles: numba's kernels per half of ``ebad.precompile``, from a cold cache.

    python -m benchmarks.compile_time [--kinds grey] [--name compile_time]

Each half (``raster``: the rasteriser; ``losses``: SSIM, L_ev, the trajectories' poses and EDI)
runs as ``ebad.precompile``'s child does, in a fresh process with an empty ``NUMBA_CACHE_DIR`` of
its own and one numba thread, one half after the other (not side by side, as a first run has
them: the CPU-seconds are what each costs). For every kernel numba compiles at the top level
(not the helpers it inlines), the CPU-seconds of its ``Dispatcher.compile``; per half, its wall
and CPU seconds in all (imports, the tiny capture, three training steps). Timings move with the
machine's load: CPU-seconds less than wall seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from ._common import write_json

ROOT = Path(__file__).resolve().parents[1]
HALVES = ("raster", "losses")
FLOOR = 0.05  # CPU-s: a kernel below it is neither listed nor counted as compiled twice

_CHILD = """
import json, os, sys, time
from numba.core import dispatcher
orig = dispatcher.Dispatcher.compile
depth, top = [0], {}
def timed(self, sig):  # a kernel's compile, with what it inlines; nested compiles are its helpers'
    depth[0] += 1
    t0 = time.process_time()
    try:
        return orig(self, sig)
    finally:
        depth[0] -= 1
        if depth[0] == 0:
            name = self.py_func.__module__ + "." + self.py_func.__qualname__
            top[name] = top.get(name, 0.0) + time.process_time() - t0
dispatcher.Dispatcher.compile = timed
t0, c0 = time.perf_counter(), time.process_time()
from ebad.precompile import _child
_child(sys.argv[1], sys.argv[2:])
print(json.dumps({"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "kernels": top}))
"""


def measure(half: str, kinds: list[str]) -> dict:
    """One half of the precompile, cold, in a fresh process."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
        env["EBAD_PRECOMPILE_PARENT"] = str(os.getpid())
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
        r = subprocess.run(
            [sys.executable, "-c", _CHILD, half, *kinds], env=env, capture_output=True, text=True, timeout=1800
        )
    if r.returncode != 0:
        raise SystemExit(f"the {half} half failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def compiled_twice(halves: dict[str, dict], floor: float = FLOOR) -> list[str]:
    """The kernels every half compiled (at least ``floor`` CPU-s each): work a first run does twice."""
    sets = [{k for k, s in m["kernels"].items() if s >= floor} for m in halves.values()]
    return sorted(set.intersection(*sets)) if sets else []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.compile_time", description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="grey", help="capture kinds to compile for (ebad.run.warm_up), comma-separated")
    ap.add_argument("--name", default="compile_time", help="results file benchmarks/results/NAME.json")
    a = ap.parse_args(argv)
    kinds = [k for k in a.kinds.split(",") if k]
    halves = {}
    for half in HALVES:
        print(f"compiling the {half} half from a cold cache ...", flush=True)
        m = halves[half] = measure(half, kinds)
        compiled = sum(m["kernels"].values())
        print(f"  {m['wall_s']:.1f} s wall, {m['cpu_s']:.1f} CPU-s in all, {compiled:.1f} CPU-s compiling:")
        for k, s in sorted(m["kernels"].items(), key=lambda kv: -kv[1]):
            if s >= FLOOR:
                print(f"    {s:6.2f}  {k}")
    twice = compiled_twice(halves)
    print(f"compiled by both halves: {', '.join(twice) or 'none'}")
    path = write_json(a.name, {"kinds": kinds, "halves": halves, "compiled_twice": twice, "argv": sys.argv[1:]})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
