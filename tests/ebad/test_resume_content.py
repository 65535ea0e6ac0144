"""``--resume`` refuses a checkpoint made from a capture of other content (inverted frames, moved
poses, scrambled events) with the same names, sizes, exposures and event count."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import scenes
from ebad.state import capture_fingerprint, fingerprint_diff
from edi import EventStream


@pytest.fixture(scope="module")
def cap():
    return scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4).capture


def _changed(cap, what: str):
    c = copy.copy(cap)
    if what == "inverted frames":
        c.frames = (1.0 - cap.frames).astype(np.float32)
    elif what == "one pixel":
        c.frames = cap.frames.copy()
        c.frames[2, 10, 10, 0] += 1e-3
    elif what == "moved poses":
        c.c2w = cap.c2w.copy()
        c.c2w[:, :3, 3] += 0.01
    elif what == "scrambled events":
        ev = cap.events
        c.events = EventStream(ev.t, ev.x[::-1].copy(), ev.y, ev.p, ev.width, ev.height, t0=ev.t0)
    elif what == "flipped polarities":
        ev = cap.events
        c.events = EventStream(ev.t, ev.x, ev.y, -ev.p, ev.width, ev.height, t0=ev.t0)
    elif what == "a cfa stated":
        c.cfa = "RGGB"
    return c


@pytest.mark.parametrize(
    "what,said",
    [
        ("inverted frames", "other frame pixels"),
        ("one pixel", "other frame pixels"),
        ("moved poses", "other poses"),
        ("scrambled events", "other event content"),
        ("flipped polarities", "other event content"),
        ("a cfa stated", "other poses"),
    ],
)
def test_other_content_with_the_same_shape_is_told(cap, what, said):
    saved = capture_fingerprint(cap)
    now = capture_fingerprint(_changed(cap, what))
    assert saved["frames"] == now["frames"] and saved["events"] == now["events"]
    assert fingerprint_diff(saved, now) == said


def test_the_same_capture_matches_and_old_checkpoints_still_resume(cap):
    fp = capture_fingerprint(cap)
    assert fingerprint_diff(fp, capture_fingerprint(copy.deepcopy(cap))) == ""
    old = {k: v for k, v in fp.items() if k not in ("pixels", "poses", "event_content")}  # before the hashes
    assert fingerprint_diff(old, capture_fingerprint(_changed(cap, "inverted frames"))) == ""
