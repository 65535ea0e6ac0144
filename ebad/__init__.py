"""ebad: EBAD-Gaussian reconstruction from blurry event-camera captures, on a CPU."""
from .errors import UserError

__all__ = ["UserError"]
__version__ = "0.1.0"
