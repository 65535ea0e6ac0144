"""capture.json without ``events.t_unit``: the unit is inferred against the frames' times, never assumed (issue 32)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from edi import EventStream
from scenes import Capture, CaptureError, load, save


def _saved(tmp_path, span_s: float = 0.3):
    """A 3-frame capture (exposures over 0.01 .. 0.24 s) with events over ``span_s``, saved, and
    its events rewritten as epoch nanoseconds in a capture.json without t_unit."""
    rng = np.random.default_rng(0)
    f, h, w, m = 3, 8, 10, 500
    t_us = np.sort(rng.integers(0, int(span_s * 1e6), m))
    ev = EventStream(t_us, rng.integers(0, w, m), rng.integers(0, h, m), rng.integers(0, 2, m), w, h)
    cap = Capture(
        frames=rng.uniform(0, 1, (f, h, w, 1)).astype(np.float32),
        exposures=np.stack([np.arange(f) * 0.1 + 0.01, np.arange(f) * 0.1 + 0.04], 1),
        events=ev,
        K=np.array([[10.0, 0, 5], [0, 10.0, 4], [0, 0, 1]]),
    )
    root = tmp_path / "cap"
    save(cap, root)
    epoch_ns = 1_700_000_000_000_000_000
    with np.load(root / "events.npz") as z:
        arrs = dict(z)
    arrs["t"] = epoch_ns + arrs["t"].astype(np.int64) * 1000
    np.savez(root / "events.npz", **arrs)
    doc = json.loads((root / "capture.json").read_text())
    del doc["events"]["t_unit"]
    doc["events"].pop("t0_us", None)
    (root / "capture.json").write_text(json.dumps(doc))
    return root, t_us


def test_missing_t_unit_is_inferred_from_the_frames_and_said(tmp_path, caplog):
    root, t_us = _saved(tmp_path)
    with caplog.at_level(logging.WARNING, logger="scenes.format"):
        cap = load(root)
    # epoch ns: read as ns (relative to the first event), not as microseconds (1000x too long)
    np.testing.assert_array_equal(cap.events.t, t_us - t_us[0])
    assert cap.meta["events_t_unit_inferred"] == "ns"
    assert "events.t_unit missing: inferred 'ns'" in caplog.text


def test_missing_t_unit_that_fits_no_unit_is_refused(tmp_path):
    root, _ = _saved(tmp_path, span_s=5.0)  # 5 s of events for 0.23 s of frames: 22x, fits ns ...
    load(root)
    root2, _ = _saved(tmp_path / "b", span_s=30.0)  # ... 130x fits no unit
    with pytest.raises(CaptureError, match=r"field 'events\.t_unit': missing, and no unit puts the events' span"):
        load(root2)


def test_given_t_unit_is_used_as_given(tmp_path):
    root, t_us = _saved(tmp_path)
    doc = json.loads((root / "capture.json").read_text())
    doc["events"]["t_unit"] = "ns"
    (root / "capture.json").write_text(json.dumps(doc))
    cap = load(root)
    np.testing.assert_array_equal(cap.events.t, t_us - t_us[0])
    assert "events_t_unit_inferred" not in cap.meta
