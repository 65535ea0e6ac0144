"""``scenes.convert`` writes undistorted frames as PNG of the input's depth (issue 30, item 4):
8-bit frames stay 8-bit, 16-bit frames 16-bit, float frames (no PNG holds them) stay ``.npy``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import scenes
from scenes.convert import main
from scenes.undistort import input_bits, undistort_frames

W, H = 24, 16
K = np.array([[20.0, 0.0, 12.0], [0.0, 20.0, 8.0], [0.0, 0.0, 1.0]])
DIST = [-0.2, 0.05, 1e-3, -1e-3, 0.0]


def _ecd(root, bits: int, n: int = 3):
    """A tiny Event Camera Dataset folder with distortion and ``bits``-deep grey PNG frames."""
    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(bits)
    lines = []
    for i in range(n):
        img = rng.uniform(0.05, 0.95, (H, W, 1))
        scenes.write_image(root / "images" / f"frame_{i:08d}", img, bits=bits)
        lines.append(f"{0.01 * i:.6f} images/frame_{i:08d}.png")
    (root / "images.txt").write_text("\n".join(lines) + "\n")
    (root / "calib.txt").write_text(" ".join(str(v) for v in [K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5, *DIST]))
    (root / "events.txt").write_text("0.001 3 4 1\n0.002 5 6 0\n")
    return root


@pytest.mark.parametrize(("bits", "mode"), [(8, "L"), (16, "I;16")])
def test_converted_undistorted_frames_are_pngs_of_the_input_depth(tmp_path, bits, mode):
    src = _ecd(tmp_path / "ecd", bits)
    assert main([str(src), "--out", str(tmp_path / "c")]) == 0
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    assert doc["meta"]["undistorted"] is True
    files = [tmp_path / "c" / f["file"] for f in doc["frames"]]
    assert [f.suffix for f in files] == [".png"] * 3
    raw = scenes.load(src, undistort=False).frames
    for i, f in enumerate(files):
        with Image.open(f) as im:
            assert im.mode.startswith(mode) and im.size == (W, H)
        # the bilinear undistortion, rounded to the input's levels
        q = 2**bits - 1
        want = np.round(undistort_frames(raw[i : i + 1], K, np.array(DIST))[0] * q)
        np.testing.assert_array_equal(np.round(scenes.read_image(f) * q), want)
    # undistortion did move the pixels (else this test proves nothing)
    assert not np.array_equal(scenes.load(tmp_path / "c").frames, raw)


def test_input_bits_and_float_frames_stay_float():
    a = np.round(np.random.default_rng(0).uniform(0, 1, (2, 5, 6, 1)) * 255) / 255
    assert input_bits(a.astype(np.float32)) == 8
    assert input_bits((np.round(a * 65535 + 1) / 65535).astype(np.float32)) == 16
    f = np.random.default_rng(1).uniform(0, 1, (2, 5, 6, 1)).astype(np.float32)
    assert input_bits(f) is None
    out = undistort_frames(f, np.array([[5.0, 0, 3], [0, 5.0, 2.5], [0, 0, 1]]), np.array(DIST))
    assert input_bits(out) is None and out.dtype == np.float32


def test_a_raw_bayer_mosaic_is_undistorted_per_colour():
    from edi.cfa import mosaic

    # a flat colour scene seen through an RGGB mosaic: after undistortion every pixel must still
    # carry its own channel's value, never an average with its differently coloured neighbours
    rgb = np.broadcast_to(np.array([200, 128, 40], np.float32) / 255, (2, H, W, 3))
    raw = mosaic(np.ascontiguousarray(rgb), "RGGB")[..., None].astype(np.float32)
    out = undistort_frames(raw, K, np.array(DIST), cfa="RGGB")
    np.testing.assert_array_equal(out, raw)
    assert not np.array_equal(undistort_frames(raw, K, np.array(DIST)), raw)  # grey resampling mixes colours
    # no distortion: the mosaic comes back as it was (bilinear demosaic keeps each pixel's own value)
    noisy = (np.round(np.random.default_rng(0).uniform(0, 1, (1, H, W, 1)) * 255) / 255).astype(np.float32)
    np.testing.assert_array_equal(undistort_frames(noisy, K, np.zeros(5), cfa="RGGB"), noisy)
