"""ebad: EBAD-Gaussian reconstruction from blurry event-camera captures, on a CPU.

    run = ebad.reconstruct(capture, ebad.preset("ebad"))   # -> ebad.Run
    image = run.render(c2w, K, width, height)               # [H, W, D] numpy, linear [0, 1]

The heavy parts (torch, the trainer) are imported on first use, so ``ebad --help`` stays quick.

Importing ``ebad`` before torch sets ``OMP_WAIT_POLICY=PASSIVE`` (unless the environment says
otherwise): torch's OpenMP threads otherwise spin between parallel regions and take the cores
from the rasteriser's numba threads and from other work. On a loaded 2-core machine (load 5 to
9) a 346x260 ebad step took 1116 and 2219 ms with the spinning default, 78 and 305 ms with
PASSIVE, 227 and 390 ms single-threaded (about 75 ms of CPU time per step in the last two, 600
to 830 ms with spinning). With PASSIVE in force the numba kernels run on OpenMP too
(``splat_cpu._numba_impl``), and ``ebad.trainer.train`` runs torch single-threaded either way
(``OMP_PASSIVE`` tells whether torch's threads sleep).
"""
import os as _os
import sys as _sys

if "torch" not in _sys.modules:
    _os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from splat_cpu._omp import openmp_threads_sleep as _openmp_threads_sleep  # noqa: E402  (loads no torch)

#: torch's OpenMP threads sleep when idle (OMP_WAIT_POLICY=PASSIVE was in force when torch loaded)
OMP_PASSIVE = _openmp_threads_sleep()

from typing import TYPE_CHECKING  # noqa: E402

from .errors import ConfigError, EbadError, UserError  # noqa: E402

if TYPE_CHECKING:  # what ``__getattr__`` loads on first use, for type checkers and IDEs
    from .config import PRESETS, Config, preset
    from .data import prepare
    from .run import Run, reconstruct
    from .runfolder import load_run
    from .state import TrainState

__all__ = ["EbadError", "UserError", "ConfigError", "reconstruct", "Run", "Config", "preset", "PRESETS", "load_run",
           "prepare", "TrainState"]
__version__ = "0.1.0"

_LAZY = {
    "reconstruct": ("run", "reconstruct"),
    "prepare": ("data", "prepare"),
    "TrainState": ("state", "TrainState"),
    "Run": ("run", "Run"),
    "Config": ("config", "Config"),
    "preset": ("config", "preset"),
    "PRESETS": ("config", "PRESETS"),
    "load_run": ("runfolder", "load_run"),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        mod, attr = _LAZY[name]
        return getattr(importlib.import_module(f".{mod}", __name__), attr)
    raise AttributeError(f"module 'ebad' has no attribute {name!r}")
