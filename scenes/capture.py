"""The in-memory capture: what every reader returns and the reconstruction eats."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edi import EventStream

__all__ = ["Capture", "TestView"]


@dataclass
class TestView:
    """A held-out view: a camera at time ``t`` (seconds) with pose ``c2w`` [4, 4] and,
    when known, its sharp image [H, W, D] float32 in linear [0, 1]."""

    name: str
    t: float
    c2w: np.ndarray  # [4, 4]
    image: np.ndarray | None = None  # [H, W, D]


@dataclass
class Capture:
    """A blurry multi-view event capture.

    Convention: frames are linear intensity in [0, 1], D = 1 grey or 3 colour; exposures in
    seconds on the same clock as ``events`` (whose ``t`` is microseconds from the capture
    start); ``K`` in pixels with the top-left pixel centre at (0.5, 0.5); ``c2w`` OpenCV
    camera-to-world at mid-exposure.
    """

    frames: np.ndarray  # [F, H, W, D] float32 in [0, 1]
    exposures: np.ndarray  # [F, 2] float64 seconds (t_start, t_end)
    events: EventStream
    K: np.ndarray  # [3, 3] float64
    distortion: np.ndarray | None = None  # [5] k1 k2 p1 p2 k3, or None
    c2w: np.ndarray | None = None  # [F, 4, 4] float64, or None (no poses)
    split: list[str] = field(default_factory=list)  # per frame: "train" | "test" | ...
    test_views: list[TestView] = field(default_factory=list)
    names: list[str] = field(default_factory=list)  # per frame, for output file names
    meta: dict[str, Any] = field(default_factory=dict)  # free-form: source layout, time unit, ...

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def height(self) -> int:
        return int(self.frames.shape[1])

    @property
    def width(self) -> int:
        return int(self.frames.shape[2])

    @property
    def channels(self) -> int:
        return int(self.frames.shape[3])
