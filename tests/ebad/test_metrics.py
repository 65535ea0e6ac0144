"""ebad.metrics: PSNR and SSIM pinned to known values and to kornia's and scikit-image's SSIM called directly.

The other tests compare PSNRs with each other; these pin the numbers themselves, so that a wrong data range
(255 for images in [0, 1]) or another SSIM window (7 instead of 11) fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebad.losses import ssim_map
from ebad.metrics import psnr, ssim

C1, C2 = 0.01**2, 0.03**2  # SSIM's constants for a data range of 1


def _pair(seed: int = 0, shape=(32, 40, 1)) -> tuple[np.ndarray, np.ndarray]:
    """A textured image in [0, 1] and a blurred, shifted, noisy copy of it: SSIM well inside (0, 1)."""
    rng = np.random.default_rng(seed)
    H, W, D = shape
    y, x = np.mgrid[0:H, 0:W]
    a = 0.5 + 0.35 * np.sin(x / 2.5 + 0.3 * y)[..., None] * np.cos(y / 3.0)[..., None] * np.ones(D)
    a = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1)
    b = 0.5 * (np.roll(a, 1, axis=1) + np.roll(a, 1, axis=0))
    b = np.clip(b + 0.08 * rng.standard_normal(b.shape), 0, 1)
    return a.astype(np.float32), b.astype(np.float32)


def test_psnr_of_zero_error_is_the_cap_and_of_a_constant_offset_is_its_exact_value():
    img = np.random.default_rng(0).uniform(0.3, 0.7, (16, 12, 1)).astype(np.float64)
    assert psnr(img, img) == 100.0
    # a constant offset d gives MSE d^2 and PSNR -20 log10(d) for a data range of 1 (255 would add 48.13 dB)
    for d, expected in ((0.1, 20.0), (0.25, 12.0412), (0.01, 40.0)):
        assert psnr(img + d, img) == pytest.approx(expected, abs=1e-3), d
        assert psnr(img - d, img) == pytest.approx(expected, abs=1e-3), d
    # batched and colour images: the mean over everything
    rgb = np.full((2, 4, 5, 3), 0.5)
    off = rgb.copy()
    off[..., 0] += 0.3  # one channel of three off by 0.3: MSE 0.03
    assert psnr(off, rgb) == pytest.approx(-10 * math.log10(0.03), abs=1e-3)


def test_psnr_clamps_the_prediction_to_the_unit_range():
    target = np.ones((4, 4, 1))
    assert psnr(np.full((4, 4, 1), 1.7), target) == 100.0  # the excess above 1 is not an error
    assert psnr(np.full((4, 4, 1), -0.5), np.full((4, 4, 1), 0.1)) == pytest.approx(20.0, abs=1e-3)


def test_ssim_of_identical_images_is_one_and_of_two_constants_the_closed_form():
    a, _ = _pair()
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-6)
    # two constant images: no variance, SSIM = (2 mu_a mu_b + C1) / (mu_a^2 + mu_b^2 + C1)
    x, y = np.full((20, 20, 1), 0.5), np.full((20, 20, 1), 0.6)
    # (metrics computes in float32: its rounding moves this one by 2e-4, as kornia's in float32)
    assert ssim(x, y) == pytest.approx((2 * 0.5 * 0.6 + C1) / (0.25 + 0.36 + C1), abs=3e-4)
    assert ssim(x, y) < 0.9840  # a data range of 255 would make C1 650 and SSIM 1.0000


@pytest.mark.parametrize("D", [1, 3])
def test_ssim_equals_kornia_called_directly_with_its_11_pixel_window(D):
    import kornia

    a, b = _pair(shape=(32, 40, D))

    def to_bchw(x):
        return torch.from_numpy(x).permute(2, 0, 1)[None].double()

    expected = float(kornia.metrics.ssim(to_bchw(a), to_bchw(b), 11).mean())
    assert 0.3 < expected < 0.95  # an informative pair
    assert ssim(a, b) == pytest.approx(expected, abs=1e-5)
    seven = float(kornia.metrics.ssim(to_bchw(a), to_bchw(b), 7).mean())
    assert abs(seven - expected) > 1e-3  # the window matters for this pair, so the default is pinned


def test_ssim_interior_equals_scikit_image_gaussian_ssim():
    """scikit-image's Gaussian SSIM (sigma 1.5, truncate 3.5: an 11-pixel window, population
    covariance) crops the window's half-width from the border before its mean; kornia (and ours)
    reflect-pad there, so the two agree on the interior."""
    from skimage.metrics import structural_similarity

    a, b = _pair(seed=1)
    expected = structural_similarity(
        a[..., 0].astype(np.float64),
        b[..., 0].astype(np.float64),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
    )
    assert 0.3 < expected < 0.95
    full = ssim_map(torch.from_numpy(a)[None].double(), torch.from_numpy(b)[None].double(), 11)[0]
    assert float(full[5:-5, 5:-5].mean()) == pytest.approx(expected, abs=1e-6)
    # ebad.metrics.ssim is the mean of that same map (borders included)
    assert ssim(a, b) == pytest.approx(float(full.mean()), abs=1e-5)
