"""Compiling numba's kernels into numba's cache in two child processes, while the caller works on.

On a cold cache a reconstruction's kernels take about 90 CPU-seconds to compile, one after the
other: numba compiles under one lock per process and holds the GIL for most of it, so a thread
does not help. ``Precompile`` starts two children that each run ``ebad.run.warm_up`` on half of
the kernels, one with the losses and poses on their torch reference and EDI on its numpy one (it
compiles the rasteriser), one with the rasteriser on its torch reference (it compiles SSIM, L_ev,
the trajectories' poses and EDI); each saves what it compiled in the cache. Meanwhile the caller
works on (``ebad demo`` builds its scene, ``ebad reconstruct`` prepares the capture:
``reconstruct(..., ready=pre.wait)``); it then loads the kernels from the cache: the machine code
every later run loads, not the in-process copies a cold compile runs, which round differently in
the last bits (tests/splat_cpu/test_cold_cache.py).

Nothing here is needed for correctness: a child that fails or is missing leaves its kernels to the
caller's ``warm_up``, which compiles them as before. On a warm cache no child starts.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["Precompile", "end_with_parent", "kernels_cached"]

_PARTS = ("raster", "losses")  # what each child compiles (``_child``)
_PARENT = "EBAD_PRECOMPILE_PARENT"  # the pid of the process that started the children


def kernels_cached() -> bool:
    """numba's cache holds (for the current sources) the largest kernels of both halves: the
    rasteriser's backward and SSIM's backward. False when it cannot tell."""
    try:
        from splat_cpu import _numba_kernels

        from .kernels import _numba_ssim

        kernels: tuple[Any, ...] = (_numba_kernels.backward_tiles, _numba_ssim.ssim_backward)  # numba's private API
        return all(bool(k._cache._cache_file._load_index()) for k in kernels)  # numba's index, {} when stale
    except Exception:  # noqa: BLE001  (numba's private cache API moved: just compile)
        return False


class Precompile:
    """Two child processes compiling the kernels ``warm_up(kinds)`` would, into numba's cache.

    ``wait()`` joins them and returns the seconds since the start; ``stop()`` ends them (a context
    manager stops them on leaving, so an exception in the caller leaves no child behind)."""

    def __init__(self, kinds: Sequence[str] = ("grey",)):
        self.t0 = time.perf_counter()
        self.procs: list[subprocess.Popen] = []
        self.failed: list[str] = []
        if kernels_cached():
            return
        root = str(Path(__file__).resolve().parents[1])
        env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")  # compiling is serial in each child
        env[_PARENT] = str(os.getpid())
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
        self._logs = [tempfile.TemporaryFile() for _ in _PARTS]
        for part, log in zip(_PARTS, self._logs, strict=True):
            cmd = [sys.executable, "-m", "ebad.precompile", part, *kinds]
            self.procs.append(subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT))

    @property
    def started(self) -> bool:
        return bool(self.procs)

    @property
    def failure(self) -> str:
        """What failed, for a caller's line: "the losses process failed" ('' when no child failed)."""
        if not self.failed:
            return ""
        return f"the {' and '.join(self.failed)} process{'es' if len(self.failed) > 1 else ''} failed"

    def wait(self) -> float:
        for part, proc in zip(_PARTS[: len(self.procs)], self.procs, strict=True):
            if proc.wait() != 0:
                self.failed.append(part)
        return time.perf_counter() - self.t0

    def stop(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()

    def __enter__(self) -> Precompile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def end_with_parent(parent: int, poll: float = 1.0) -> None:
    """End this process (exit status 1) once ``parent`` (a pid) is no longer its parent: a demo killed
    outright (SIGKILL, a timeout) leaves no compiling child behind, even one killed before this ran.
    A daemon thread polls the parent's pid."""
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="end_with_parent").start()


def _child(part: str, kinds: Sequence[str]) -> None:
    """Run ``warm_up(kinds)`` with the other half's kernels on their torch reference, or as plain Python (a
    kernel's own source, ``py_func``, where it has no other reference), so that no kernel is compiled twice."""
    import contextlib

    end_with_parent(int(os.environ[_PARENT]))

    import scenes.simulate
    import splat_cpu

    from . import gaussians, strategy
    from .kernels import torch_reference
    from .run import warm_up

    # the tiny capture's events as plain Python (0.4 s): a reconstruction of a recorded capture never simulates,
    # and the demo's own scene is simulated (the kernel compiled) by the caller
    scenes.simulate._crossings_numba = scenes.simulate._crossings_numba.py_func  # type: ignore[assignment]
    if part == "losses":
        splat_cpu._fast_path = lambda: None  # the rasteriser's torch reference: the other child compiles it
    else:  # no c estimate (its value does not change what the rasteriser compiles; 3.7 CPU-s on EDI's reference),
        import edi  # EDI's numpy reference (a tiny capture's latents), the quaternions' normalisation and
        import edi.model  # densification's screen gradients as plain Python: the losses child compiles them

        edi.estimate_c = lambda *args, **kwargs: edi.Contrast(0.2, 0.2)
        edi.model._IMPLS["fast"] = edi.model._IMPLS["reference"]
        gaussians._normalise_rows = gaussians._normalise_rows.py_func  # type: ignore[assignment]
        strategy._add_screen_grads = strategy._add_screen_grads.py_func  # type: ignore[assignment]
    with torch_reference() if part == "raster" else contextlib.nullcontext():
        warm_up(kinds)  # type: ignore[arg-type]  # checked by warm_up


if __name__ == "__main__":
    _child(sys.argv[1], sys.argv[2:])
