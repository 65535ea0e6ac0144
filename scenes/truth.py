"""What a synthetic scene (or an EBAD-NeRF folder) records as its truth, for evaluation only.

``scenes.format.read_ground_truth`` parses it; ``scenes.e2nerf.ground_truth_blur`` maps an
EBAD-NeRF folder's sharp frames onto it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .images import read_image

__all__ = ["GroundTruth", "GT_FILE"]

GT_FILE = "gt.json"


@dataclass
class GroundTruth:
    """What a synthetic scene's ``gt/`` folder records (``scenes.write_scene``), for evaluation
    only: no code path of the method reads it.

    ``frame_files`` maps a frame name to its sharp mid-exposure image; ``trajectories`` maps a
    frame name to its true in-exposure trajectory (times [S] seconds, c2w [S, 4, 4]).
    """

    root: Path
    frame_files: dict[str, Path] = field(default_factory=dict)
    trajectories: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def frames(self, names: list[str]) -> np.ndarray | None:  # -> [F, H, W, D] float32
        """The sharp frames of ``names`` (in that order), or None when one is not recorded."""
        if not all(n in self.frame_files for n in names):
            return None
        return np.stack([read_image(self.frame_files[n], f"{GT_FILE}: frames[{n!r}].file") for n in names])

    def trajectory_c2w(self, names: list[str]) -> np.ndarray | None:  # -> [F, S, 4, 4]
        """The true trajectories of ``names`` (in that order), or None when one is missing or
        they have different sample counts."""
        if not all(n in self.trajectories for n in names):
            return None
        c2ws = [self.trajectories[n][1] for n in names]
        if len({c.shape for c in c2ws}) != 1:
            return None
        return np.stack(c2ws)

    @property
    def cfa(self) -> str | None:
        """The Bayer pattern of the colour DAVIS that recorded the capture ("RGGB", ...), or None
        (a grey sensor, or colour events taken as luminance), as the scene's meta states it."""
        v = self.meta.get("cfa")
        return str(v) if v is not None else None
