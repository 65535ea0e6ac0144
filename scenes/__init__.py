"""scenes: capture format, readers for real recordings, synthetic scenes, camera initialisation."""
from .capture import Capture, TestView

__all__ = ["Capture", "TestView"]
