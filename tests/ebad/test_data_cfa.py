"""``ebad.data.prepare`` on a colour DAVIS capture: the c estimate and the EDI latents get the capture's cfa."""

from __future__ import annotations

import numpy as np
import pytest

import edi
import scenes
from ebad.config import preset
from ebad.data import prepare


@pytest.fixture(scope="module")
def capture():
    s = edi.moving_texture(height=16, width=20, num_frames=3, channels=3, cfa="RGGB", lead=0.02, step_us=100, seed=0)
    K = np.array([[20.0, 0, 10], [0, 20.0, 8], [0, 0, 1]])
    c2w = np.repeat(np.eye(4)[None], 3, axis=0)
    c2w[:, 0, 3] = [0.0, 0.1, 0.2]
    return scenes.Capture(s.frames.astype(np.float32), s.exposures, s.events, K, c2w=c2w, cfa="RGGB")


@pytest.mark.parametrize("prior", ["edi", "medi"])
def test_prepare_passes_the_captures_cfa_to_the_c_estimate_and_the_latents(capture, prior, monkeypatch):
    seen: dict[str, list] = {"estimate_c": [], "deblur": [], "medi": []}
    for name in seen:
        real = getattr(edi, name)

        def spy(*a, _real=real, _name=name, **kw):
            seen[_name].append(kw.get("cfa"))
            return _real(*a, **kw)

        monkeypatch.setattr(edi, name, spy)
    cfg = preset("ebad")
    cfg.loss.edi_prior = prior
    cfg.loss.cfa_frames = "rgb"  # the latents of the RGB frames (the ebad preset compares their mosaic)
    data = prepare(capture, cfg)
    assert seen["estimate_c"] == ["RGGB"]
    used = seen["medi"] if prior == "medi" else seen["deblur"]
    assert used and all(c == "RGGB" for c in used)
    assert data.latents is not None and data.latents.shape == data.frames.shape
    if prior == "edi":  # the mid-exposure latent is edi.deblur's per-pixel one
        f, c = 1, data.c
        want = edi.deblur(data.frames[f].numpy(), data.exposures[f], capture.events, c=c, cfa="RGGB")
        np.testing.assert_allclose(data.latents[f].numpy(), want, atol=1e-6)
