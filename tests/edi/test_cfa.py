"""The Bayer helpers: channel layout by hand, mosaic/demosaic round trip, bilinear values, flips and crops."""

import numpy as np
import pytest
import torch

from edi import InputError
from edi.cfa import channel_map, check_pattern, demosaic, mosaic, transform_pattern


def test_channel_map_names_pixels_x_then_y():
    # RGGB: (x=0,y=0) R, (1,0) G, (0,1) G, (1,1) B
    np.testing.assert_array_equal(channel_map("RGGB", 2, 3), [[0, 1, 0], [1, 2, 1]])
    np.testing.assert_array_equal(channel_map("GRBG", 3, 2), [[1, 0], [2, 1], [1, 0]])
    np.testing.assert_array_equal(channel_map("bggr", 2, 2), [[2, 1], [1, 0]])


def test_bad_pattern_names_the_field():
    with pytest.raises(InputError, match="capture.json cfa.*RGBG"):
        check_pattern("RGBG", "capture.json cfa")


def test_mosaic_numpy_and_torch_agree_and_pick_own_channel():
    rng = np.random.default_rng(0)
    rgb = rng.random((2, 4, 6, 3))
    raw = mosaic(rgb, "GBRG")
    assert raw.shape == (2, 4, 6)
    assert raw[0, 0, 0] == rgb[0, 0, 0, 1] and raw[0, 0, 1] == rgb[0, 0, 1, 2]
    assert raw[1, 1, 0] == rgb[1, 1, 0, 0] and raw[1, 1, 1] == rgb[1, 1, 1, 1]
    t = torch.tensor(rgb, requires_grad=True)
    rt = mosaic(t, "GBRG")
    np.testing.assert_array_equal(rt.detach().numpy(), raw)
    rt.sum().backward()
    assert t.grad is not None and float(t.grad.sum()) == raw.size  # one channel per pixel


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_demosaic_keeps_samples_and_is_exact_on_flat_colour(pattern):
    rng = np.random.default_rng(1)
    raw = rng.random((5, 7)).astype(np.float32)
    rgb = demosaic(raw, pattern)
    assert rgb.dtype == np.float32 and rgb.shape == (5, 7, 3)
    np.testing.assert_array_equal(mosaic(rgb, pattern), raw)
    flat = mosaic(np.broadcast_to(np.array([0.2, 0.5, 0.9]), (6, 8, 3)).copy(), pattern)
    np.testing.assert_allclose(demosaic(flat, pattern), np.broadcast_to([0.2, 0.5, 0.9], (6, 8, 3)), atol=1e-12)


def test_demosaic_bilinear_values_by_hand():
    raw = np.arange(16, dtype=np.float64).reshape(4, 4)  # RGGB
    rgb = demosaic(raw, "RGGB")
    # pixel (x=1, y=1) is B (value 5): R from its 4 diagonals (0, 2, 8, 10), G from its 4 neighbours (1, 4, 6, 9)
    assert rgb[1, 1, 0] == pytest.approx((0 + 2 + 8 + 10) / 4)
    assert rgb[1, 1, 1] == pytest.approx((1 + 4 + 6 + 9) / 4)
    # pixel (x=1, y=0) is G (value 1): R from left/right (0, 2), B from below only (5; the row above is outside)
    assert rgb[0, 1, 0] == pytest.approx(1.0) and rgb[0, 1, 2] == pytest.approx(5.0)


def test_transform_pattern_flip_and_crop():
    assert transform_pattern("RGGB", 346, 260) == "RGGB"
    assert transform_pattern("RGGB", 346, 260, flip_x=True) == "GRBG"  # even width: columns swap
    assert transform_pattern("RGGB", 346, 260, flip_y=True) == "GBRG"
    assert transform_pattern("RGGB", 346, 260, flip_x=True, flip_y=True) == "BGGR"
    assert transform_pattern("RGGB", 345, 260, flip_x=True) == "RGGB"  # odd width: pixel W-1 is even
    assert transform_pattern("RGGB", 346, 260, x0=1) == "GRBG"
    assert transform_pattern("RGGB", 346, 260, y0=3) == "GBRG"
    # the same through the images themselves
    rng = np.random.default_rng(2)
    rgb = rng.random((6, 8, 3))
    raw = mosaic(rgb, "RGGB")
    for fx, fy, x0, y0 in [(True, False, 0, 0), (False, True, 1, 0), (True, True, 1, 1)]:
        img = rgb[:: -1 if fy else 1, :: -1 if fx else 1][y0:, x0:]
        r = raw[:: -1 if fy else 1, :: -1 if fx else 1][y0:, x0:]
        np.testing.assert_array_equal(mosaic(img, transform_pattern("RGGB", 8, 6, fx, fy, x0, y0)), r)
