"""ebad: EBAD-Gaussian reconstruction from blurry event-camera captures, on a CPU.

    run = ebad.reconstruct(capture, ebad.preset("ebad"))   # -> ebad.Run
    image = run.render(c2w, K, width, height)               # [H, W, D] numpy, linear [0, 1]

The heavy parts (torch, the trainer) are imported on first use, so ``ebad --help`` stays quick.
"""
from .errors import ConfigError, EbadError, UserError

__all__ = ["EbadError", "UserError", "ConfigError", "reconstruct", "Run", "Config", "preset", "PRESETS", "load_run",
           "prepare", "TrainState"]
__version__ = "0.1.0"

_LAZY = {
    "reconstruct": ("trainer", "reconstruct"),
    "prepare": ("data", "prepare"),
    "TrainState": ("state", "TrainState"),
    "Run": ("trainer", "Run"),
    "Config": ("config", "Config"),
    "preset": ("config", "preset"),
    "PRESETS": ("config", "PRESETS"),
    "load_run": ("runfolder", "load_run"),
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        mod, attr = _LAZY[name]
        return getattr(importlib.import_module(f".{mod}", __name__), attr)
    raise AttributeError(f"module 'ebad' has no attribute {name!r}")
