"""The default colour latent of a CFA frame ("pixel": each pixel's own EDI ratio applied to all three
channels of the camera's RGB frame) against the demosaic of the per-pixel latents ("latents"), on the
ray-cast colour-DAVIS world (channels correlated, as in natural scenes) and on moving_texture
(independent random textures per channel: the case where "pixel" is wrong). c given, values pinned."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import scenes
from edi import deblur, moving_texture

C = (0.1704, 0.1359)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((np.clip(a, 0, 1) - b) ** 2)))


def _mean_psnr(monkeypatch, how: str, frames, exposures, events, truth, cfa) -> float:
    monkeypatch.setattr(sys.modules["edi.deblur"], "COLOUR_FROM_MOSAIC", how)
    return float(
        np.mean(
            [psnr(deblur(frames[i], tuple(exposures[i]), events, c=C, cfa=cfa), truth[i]) for i in range(len(frames))]
        )
    )


def test_pixel_is_the_default_and_wins_on_the_ray_cast_colour_davis_world(monkeypatch):
    assert sys.modules["edi.deblur"].COLOUR_FROM_MOSAIC == "pixel"
    sc = scenes.make_scene("boxes", size="tiny", seed=0, sensor="realistic", poses="noisy", cfa="RGGB")
    cap = sc.capture
    args = (cap.frames, cap.exposures, cap.events, sc.gt_frames, "RGGB")
    assert _mean_psnr(monkeypatch, "pixel", *args) == pytest.approx(22.63, abs=0.01)
    assert _mean_psnr(monkeypatch, "latents", *args) == pytest.approx(20.58, abs=0.01)
    assert np.mean([psnr(cap.frames[i], sc.gt_frames[i]) for i in range(cap.num_frames)]) == pytest.approx(
        19.73, abs=0.01
    )


def test_latents_win_where_the_channels_are_independent_textures(monkeypatch):
    s = moving_texture(height=32, width=40, num_frames=3, channels=3, cfa="RGGB", seed=0)
    mids = [float(e.mean()) for e in s.exposures]
    truth = [s.sharp(m) for m in mids]
    args = (s.frames, s.exposures, s.events, truth, "RGGB")
    pixel, latents = _mean_psnr(monkeypatch, "pixel", *args), _mean_psnr(monkeypatch, "latents", *args)
    assert pixel == pytest.approx(12.34, abs=0.01)  # no better than events as luminance here
    assert latents == pytest.approx(20.05, abs=0.01)
