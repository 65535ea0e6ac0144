"""The ray-cast scenes built on the shared wall and floor (``scenes.synth._wall_and_floor``) render bit for
bit what they rendered before it was factored out of ``build_spheres`` and ``build_glossy``: the sharp and the
blurry frames of each, grey and colour, hashed (values computed on the code before the change)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import scenes

PINNED = {
    ("spheres", False): "e9f3e7873a3ca190",
    ("spheres", True): "b1f85a6d6d4cd53a",
    ("glossy", False): "0f0f38d2ddc2e1dd",
    ("glossy", True): "79b2ae0fa5f296d6",
}


@pytest.mark.parametrize("name,rgb", list(PINNED))
def test_scene_frames_are_bit_identical_to_the_pinned_ones(name, rgb):
    s = scenes.make_scene(name, "tiny", seed=0, n_frames=2, n_test=1, rgb=rgb)
    raw = np.ascontiguousarray(s.gt_frames).tobytes() + np.ascontiguousarray(s.capture.frames).tobytes()
    assert hashlib.sha256(raw).hexdigest()[:16] == PINNED[(name, rgb)]
