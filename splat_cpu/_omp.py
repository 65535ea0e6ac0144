"""OpenMP's wait policy and numba's threading layer, decided in one place, without loading torch.

torch loads an OpenMP runtime that reads OMP_WAIT_POLICY once, when it loads: unless it was
PASSIVE then, idle OpenMP threads spin between parallel regions and take the cores from other
work. numba's "omp" threading layer runs on that same runtime, so it is safe only when the
policy in force is PASSIVE; numba's own "workqueue" layer never spins.

Nothing here runs on import. ``set_wait_policy`` sets the variable (only while torch is not
loaded, so that it takes effect); ``openmp_threads_sleep`` says which policy is actually in
force; ``choose_threading_layer`` picks numba's layer from it, before numba's first parallel
launch. ``ebad.threads.configure`` calls the three; the rasteriser calls the last before its
first kernel, so that a caller who configured nothing never runs on spinning threads.
"""

from __future__ import annotations

import os
import sys
from typing import Literal

__all__ = [
    "NumbaLayer",
    "openmp_loaded",
    "set_wait_policy",
    "openmp_threads_sleep",
    "choose_threading_layer",
    "WORKQUEUE",
]

NumbaLayer = Literal["omp", "workqueue", "user", "launched"]  # what choose_threading_layer did
POLICY = "OMP_WAIT_POLICY"
WORKQUEUE: Literal["workqueue"] = "workqueue"  # numba's own pool: idle workers block on a condition, never spin
_noted: list[str | None] = []  # the policy a set-up saw while torch was not loaded (what torch then reads)
_chosen: list[NumbaLayer] = []  # the layer choose_threading_layer settled on, once


def openmp_loaded() -> bool:
    """torch (and with it its OpenMP runtime) is loaded: OMP_WAIT_POLICY can no longer change."""
    return "torch" in sys.modules


def _passive(value: str | None) -> bool:
    return (value or "").strip().upper() == "PASSIVE"


def _starting_environment() -> dict[str, str] | None:
    """The environment the process started with (Linux: /proc/self/environ, which in-process
    changes do not reach), or None where it cannot be read."""
    try:
        raw = open("/proc/self/environ", "rb").read()
    except OSError:
        return None
    pairs = (item.split(b"=", 1) for item in raw.split(b"\0") if b"=" in item)
    return {k.decode(errors="replace"): v.decode(errors="replace") for k, v in pairs}


def set_wait_policy(value: str = "PASSIVE") -> bool:
    """Set OMP_WAIT_POLICY to ``value`` unless it is set already (a user's value wins) or torch is
    loaded (too late to take effect); note what torch will read. Returns whether it set it."""
    if openmp_loaded():
        return False
    changed = POLICY not in os.environ
    if changed:
        os.environ[POLICY] = value
    _noted[:] = [os.environ.get(POLICY)]
    return changed


def openmp_threads_sleep() -> bool:
    """Idle OpenMP threads sleep (OMP_WAIT_POLICY=PASSIVE) in the runtime torch loads, or loaded.

    Before torch loads: the environment's value now. After: the value noted by ``set_wait_policy``
    before torch loaded, else the process's starting environment (where readable, else the
    environment now). A value set inside the process after torch loaded is not in force, and is
    not taken for it."""
    if not openmp_loaded():
        return _passive(os.environ.get(POLICY))
    if _noted:
        return _passive(_noted[0])
    start = _starting_environment()
    return _passive((start if start is not None else os.environ).get(POLICY))


def choose_threading_layer() -> NumbaLayer:
    """numba's threading layer, chosen once before its first parallel launch: "omp" first when
    OpenMP's threads sleep (``openmp_threads_sleep``; "workqueue" if numba has no omp layer),
    "workqueue" otherwise. A layer the user chose (NUMBA_THREADING_LAYER, or
    numba.config.THREADING_LAYER set in code) is kept, and so is the layer of threads numba has
    already launched. Returns the layer chosen, or "user" / "launched" when it left it alone."""
    if _chosen:
        return _chosen[0]
    import numba
    from numba.np.ufunc import parallel

    user_layer = numba.config.THREADING_LAYER  # type: ignore[attr-defined]  # numba.config sets it at import time
    if "NUMBA_THREADING_LAYER" in os.environ or user_layer != "default":
        return "user"
    if getattr(parallel, "_is_initialized", False):
        return "launched"
    if openmp_threads_sleep():
        numba.config.THREADING_LAYER_PRIORITY = ["omp", WORKQUEUE, "tbb"]  # type: ignore[attr-defined]  # as above
        _chosen.append("omp")
    else:
        numba.config.THREADING_LAYER = WORKQUEUE  # type: ignore[attr-defined]  # as above
        _chosen.append(WORKQUEUE)
    return _chosen[0]
