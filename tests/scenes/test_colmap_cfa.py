"""SfM on a colour DAVIS capture: the EDI latents it matches are deblurred as the filter says (each
pixel's events on its own channel), and raw mosaics are demosaiced for SIFT.

``benchmarks.colmap_poses --colours cfa,raw --inputs "edi c,edi luma"`` measured it over 2 scenes x 5
seeds at 64x48 and 160x120 (docs/results.md); the seed-0 tiny capture below is the one the colour
ablation with SfM poses met: with its events taken as the luminance SfM registers 8 of its 10 frames,
with ATE 30.7% and rotations 128 degrees off."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import scenes
from edi import deblur
from scenes.colmap import ColmapConfig, _sfm_frames, estimate_poses, pose_errors


@pytest.fixture(scope="module")
def colour():
    return scenes.make_scene("boxes", "tiny", seed=0, poses="none", rgb=True, cfa="RGGB")


def test_sfm_registers_every_frame_of_the_colour_capture_the_luminance_path_lost(colour):
    est = estimate_poses(colour.capture, ColmapConfig(test_views="all"))
    assert est.registered.all() and len(est.test_c2w) == 3
    e = pose_errors(est.c2w, colour.gt_c2w)
    assert 100 * e["ate_rmse"] / e["trajectory_extent"] == pytest.approx(1.17, abs=0.3)  # measured 1.17%
    assert e["rot_mean_deg"] == pytest.approx(0.58, abs=0.3)  # measured 0.580
    assert est.colors.shape[1] == 3


def test_the_sfm_inputs_follow_the_filter():
    """Raw mosaics: each pixel's own channel of the SfM image is its EDI latent deblurred on the
    mosaic with the capture's c; the other two are interpolated (3 channels for SIFT)."""
    raw = scenes.make_scene("boxes", "tiny", seed=0, poses="none", rgb=True, cfa="RGGB", raw_frames=True).capture
    report: dict = {}
    imgs = _sfm_frames(raw, True, report)
    assert imgs.shape == (*raw.frames.shape[:3], 3)
    c = report["c_estimated"]
    k = 4
    lat = np.asarray(deblur(raw.frames[k], raw.exposures[k], raw.events, None, c, cfa="RGGB"))[..., 0]
    own = np.zeros(lat.shape, dtype=int)  # RGGB: R at (even, even), B at (odd, odd), G elsewhere
    own[0::2, 0::2], own[1::2, 1::2], own[0::2, 1::2], own[1::2, 0::2] = 0, 2, 1, 1
    picked = np.take_along_axis(imgs[k], own[..., None], axis=-1)[..., 0]
    assert np.allclose(picked, lat, atol=1e-12)
    assert not np.allclose(imgs[k][..., 0], imgs[k][..., 2])  # a colour image, not the mosaic repeated
    # with the filter left out, the same raw frames are one-channel images deblurred as grey
    luma = _sfm_frames(dataclasses.replace(raw, cfa=None), True, {})
    assert luma.shape == raw.frames.shape
