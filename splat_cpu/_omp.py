"""Whether OpenMP's idle threads sleep, read in one place, without torch.

``import ebad`` reads it before torch loads (``ebad.OMP_PASSIVE``), and the rasteriser reads it
when it chooses numba's threading layer (``splat_cpu._numba_impl``). This module and the
``splat_cpu`` package's own import load nothing heavy, so ``ebad`` can use it first.
"""
from __future__ import annotations

import os


def openmp_threads_sleep() -> bool:
    """OMP_WAIT_POLICY=PASSIVE is in the environment: idle OpenMP threads sleep instead of spinning
    (in force when it was set before torch loaded its OpenMP runtime, as ``ebad`` does)."""
    return os.environ.get("OMP_WAIT_POLICY", "").strip().upper() == "PASSIVE"
