"""edi: event streams and the Event-based Double Integral (Pan et al., CVPR 2019)."""
from .events import EventError, EventStream, seconds_to_us

__all__ = ["EventStream", "EventError", "seconds_to_us"]
