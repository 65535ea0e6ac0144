"""ebad: EBAD-Gaussian reconstruction from blurry event-camera captures, on a CPU.

    run = ebad.reconstruct(capture, ebad.preset("ebad"))   # -> ebad.Run
    image = run.render(c2w, K, width, height)               # [H, W, D] numpy, linear [0, 1]

The heavy parts (torch, the trainer) are imported on first use, so ``ebad --help`` stays quick.
Importing ``ebad`` changes no process-wide setting: the thread set-up (OpenMP's wait policy,
numba's threading layer) is ``ebad.threads.configure``, which ``ebad.reconstruct`` and the
command line call.
"""

from typing import TYPE_CHECKING

from .errors import ConfigError, EbadError, UserError

if TYPE_CHECKING:  # what ``__getattr__`` loads on first use, for type checkers and IDEs
    from .config import PRESETS, Config, preset
    from .data import prepare
    from .run import Run, reconstruct
    from .runfolder import load_run
    from .state import TrainState

__all__ = [
    "EbadError",
    "UserError",
    "ConfigError",
    "reconstruct",
    "Run",
    "Config",
    "preset",
    "PRESETS",
    "load_run",
    "prepare",
    "TrainState",
]
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
