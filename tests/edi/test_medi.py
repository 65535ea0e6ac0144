"""mEDI (edi.medi): all frames jointly, against frame-by-frame EDI and a dense per-pixel least squares."""

import numpy as np
import pytest
import torch

from edi import LOG_EPS, SATURATION, InputError, deblur, events_in_window, medi, moving_texture
from edi.medi import solve_tridiagonal


@pytest.fixture(scope="module")
def seq3():
    return moving_texture(num_frames=3, seed=1, c=0.2)


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_solve_tridiagonal_matches_dense_solve(seed):
    rng = np.random.default_rng(seed)
    F, P, lam = 6, 50, 0.7
    w = np.where(rng.random((F, P)) < 0.3, 1e-6, 1.0)  # saturated entries
    deg = np.full(F, 2.0)
    deg[[0, -1]] = 1.0
    diag = w + lam * deg[:, None]
    rhs = rng.standard_normal((F, P))
    x = solve_tridiagonal(np.full(F - 1, -lam), diag, np.full(F - 1, -lam), rhs)
    for p in range(P):
        A = np.diag(diag[:, p]) - lam * (np.eye(F, k=1) + np.eye(F, k=-1))
        np.testing.assert_allclose(x[:, p], np.linalg.solve(A, rhs[:, p]), rtol=1e-10, atol=1e-12)


def dense_medi(frames, exposures, events, c, lam):
    """Reference: mEDI's objective per pixel, built and solved densely (np.linalg.solve)."""
    F, H, W, D = frames.shape
    centres = exposures.mean(axis=1)
    y = np.stack([np.log(deblur(frames[i], exposures[i], events, c=c) + LOG_EPS) for i in range(F)])
    w = np.where((frames >= SATURATION).any(axis=-1), 1e-6, 1.0)
    d = np.empty((F - 1, H, W))
    for i in range(F - 1):
        j0, j1 = events_in_window(events, centres[i], centres[i + 1])
        win = events[j0:j1]
        d[i] = c[0] * win.count_image(1) - c[1] * win.count_image(-1)
    Dm = np.eye(F - 1, F, k=1) - np.eye(F - 1, F)  # (D x)_i = x_{i+1} - x_i
    out = np.empty_like(y)
    for r in range(H):
        for q in range(W):
            A = np.diag(w[:, r, q]) + lam * Dm.T @ Dm
            for ch in range(D):
                out[:, r, q, ch] = np.linalg.solve(A, w[:, r, q] * y[:, r, q, ch] + lam * Dm.T @ d[:, r, q])
    return np.clip(np.exp(out) - LOG_EPS, 0.0, 1.0)


def test_medi_with_saturated_pixels_matches_dense_least_squares():
    """Issue 11: the weights of a saturated pixel are its own. Before, every pixel solved with
    pixel (0, 0)'s matrix, so saturating (0, 0) in one frame moved every other pixel."""
    s = moving_texture(num_frames=4, seed=2, c=0.2, channels=3, height=20, width=24)
    fr = s.frames.copy()
    fr[1, 0, 0] = 1.0  # pixel (0, 0) saturated in frame 1
    fr[2, 5:8, 3:6] = 1.0  # a saturated patch in frame 2
    c = (0.2, 0.2)
    got = medi(fr, s.exposures, s.events, c=c, lam=0.8)
    ref = dense_medi(fr, s.exposures, s.events, c, 0.8)
    np.testing.assert_allclose(got, ref, atol=1e-9)
    # the saturated pixel (0, 0) changes nothing elsewhere
    base = medi(s.frames, s.exposures, s.events, c=c, lam=0.8)
    mask = np.ones(fr.shape[1:3], bool)
    mask[0, 0] = False
    mask[5:8, 3:6] = False
    np.testing.assert_allclose(got[:, mask], base[:, mask], atol=1e-12)
    # ... and the saturated frames are carried by the events from their neighbours
    assert np.abs(got[1, 0, 0] - 1.0).max() > 1e-3


def test_medi_flickers_less_than_frame_by_frame():
    s = moving_texture(num_frames=5, seed=0, c=0.2)
    rng = np.random.default_rng(0)
    gains = rng.uniform(0.85, 1.15, (5, 1, 1, 1))  # exposure flicker of the APS frames
    noisy = np.clip(s.frames * gains, 0, 1)
    gt = np.stack([s.sharp(t) for t in s.exposures.mean(axis=1)])
    fbf = np.stack([deblur(noisy[i], s.exposures[i], s.events, c=0.2) for i in range(5)])
    joint = medi(noisy, s.exposures, s.events, c=0.2)
    assert joint.shape == noisy.shape

    def flicker(L):  # error of the frame-to-frame log change
        return np.abs(np.diff(np.log(L + LOG_EPS), axis=0) - np.diff(np.log(gt + LOG_EPS), axis=0)).mean()

    assert flicker(joint) < 0.85 * flicker(fbf), (flicker(joint), flicker(fbf))
    assert rmse(joint, gt) < rmse(fbf, gt)
    # lam = 0 is frame by frame
    np.testing.assert_allclose(medi(noisy, s.exposures, s.events, c=0.2, lam=0.0), fbf, atol=1e-9)


def test_medi_torch_grey_and_estimated_c(seq3):
    out = medi(torch.from_numpy(seq3.frames[..., 0]), seq3.exposures, seq3.events)
    assert isinstance(out, torch.Tensor) and out.shape == seq3.frames.shape[:3] and torch.isfinite(out).all()
    with pytest.raises(InputError, match="time order"):
        medi(seq3.frames, seq3.exposures[::-1].copy(), seq3.events, c=0.2)
    with pytest.raises(InputError, match=r"exposures must be \[F, 2\]"):
        medi(seq3.frames, seq3.exposures[:2], seq3.events, c=0.2)
