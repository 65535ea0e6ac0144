"""End to end on a real recording: the AEDAT4 file in ../shared/data (skipped without it)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from ebad.cli import main

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
AEDAT = SHARED / "data" / "davis346_street" / "davis346_street.aedat4"

pytestmark = pytest.mark.skipif(
    not AEDAT.is_file(), reason=f"real recording not found at {AEDAT} (../shared is absent)"
)


@pytest.mark.slow
def test_aedat4_capture_reconstructs_end_to_end_on_a_static_camera(tmp_path, caplog):
    """The street recording has a static camera: its frames change only where the cars pass (2.1%
    of the pixels at most), so the run poses it as a tripod without trying SfM, says so, and
    completes its run folder."""
    out = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="ebad.data"):
        rc = main(["reconstruct", str(AEDAT), "--out", str(out), "--train.iters", "5", "--no-progress"])
    assert rc == 0
    assert "the camera did not move: at most 2.1% of the pixels" in caplog.text
    metrics = json.loads((out / "metrics.json").read_text())
    prep = metrics["prepare"]
    assert prep["pose_source"] == "static" and metrics["steps"] == 5
    assert prep["channels"] == 1  # a grey DAVIS346 stays one channel
    # 0.5 ms exposures with a handful of events per frame: every frame is sharp, V = 1
    assert set(prep["views"]) == {1}
    assert (out / "point_cloud.ply").stat().st_size > 0
    assert len(list((out / "deblurred").glob("*.png"))) == prep["train_frames"] == 59
