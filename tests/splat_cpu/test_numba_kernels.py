"""The numba tile kernels' parts: the polynomial exp, the half-tile pixel layout, the binning's
row ranges, and float32 compositing against the reference on a larger image."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from numba import njit

from splat_cpu import _numba_kernels as K
from splat_cpu._numba_impl import _np, rasterize_numba
from splat_cpu._numba_project import project_forward
from splat_cpu._torch_impl import rasterize_reference
from splat_cpu.constants import ALPHA_MIN, TILE

from .conftest import make_scene
from .test_rasterize import NAMES, _close, _grads


@njit(cache=True, fastmath=K._FASTMATH)  # as in the kernels
def _exp_neg_all(s):  # [M] -> [M] in the dtype of s
    out = np.empty_like(s)
    for i in range(s.shape[0]):
        out[i] = K.exp_neg(s[i])
    return out


@pytest.mark.parametrize("dtype,n_eps", [(np.float32, 2), (np.float64, 16)])
def test_exp_neg_relative_error_over_its_whole_range(dtype, n_eps):
    """Within a few epsilons of the type (measured: 8.7e-8 in float32, under 1 eps; 2.0e-15 in
    float64, where the rounding of n ln 2 for n <= 8 dominates)."""
    bound = n_eps * float(np.finfo(dtype).eps)
    s = np.linspace(0.0, K._SIGMA_CLAMP, 200_001).astype(dtype)
    got = _exp_neg_all(s).astype(np.float64)
    want = np.exp(-s.astype(np.float64))  # of the same (rounded) argument
    rel = np.abs(got - want) / want
    assert _exp_neg_all(s).dtype == dtype
    assert float(rel.max()) < bound, float(rel.max())
    assert float(rel.max()) > 0.0  # a polynomial, not a call to exp: the check is not vacuous


def test_exp_neg_is_compiled_only():
    with pytest.raises(NotImplementedError):
        K.exp_neg(1.0)


def test_half_tile_layout_is_a_bijection_with_matching_offsets():
    pix_x, pix_y = K._pixel_offsets(np.dtype(np.float32))
    seen = set()
    for ly in range(TILE):
        for lx in range(TILE):
            i = K._pixel(lx, ly)
            seen.add(i)
            assert (pix_x[i], pix_y[i]) == (lx, ly)
            assert i // K._HALF_PX == lx // K.HALF  # left columns in the first half of the buffers
    assert seen == set(range(TILE * TILE))


def _bin(inputs, width, height):
    """Project and bin as the fast path does; returns the float64 geometry and the tile lists."""
    means, quats, scales, opac, colors, viewmats, ks = inputs
    n, n_cam = means.shape[0], viewmats.shape[0]
    arrs = [_np(x) for x in (means, quats, scales, opac, viewmats, ks)]
    m2, co, dep = np.empty((n_cam, n, 2)), np.empty((n_cam, n, 3)), np.empty((n_cam, n))
    radii, box = np.empty((n_cam, n, 2), np.int32), np.empty((n_cam, n, 4), np.int64)
    valid = np.empty((n_cam, n), np.bool_)
    project_forward(*arrs, width, height, m2, co, dep, radii, box, valid)
    dt = arrs[0].dtype  # the compositing sees the projection rounded to the input dtype
    m2, co = m2.astype(dt), co.astype(dt)
    order = np.argsort(np.where(valid, dep, np.inf), axis=1, kind="stable")
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    tile_start, gid, rows = K.bin_tiles(order, valid.sum(axis=1), box, m2, co, arrs[3], width, height, tiles_x, tiles_y)
    return m2.astype(np.float64), co.astype(np.float64), arrs[3].astype(np.float64), valid, tile_start, gid, rows


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("width,height", [(37, 29), (64, 48), (17, 31)])
def test_binning_keeps_every_pixel_where_alpha_reaches_alpha_min(seed, dtype, width, height):
    """Every (Gaussian, pixel) with o exp(-sigma) >= ALPHA_MIN, computed in float64, lies in an
    entry of its tile's list, inside the entry's row range for the pixel's half tile."""
    inputs = make_scene(150, d=1, n_cams=2, width=width, height=height, seed=seed, dtype=dtype)
    m2, co, op, valid, tile_start, gid, rows = _bin(inputs, width, height)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    n_checked = 0
    for c in range(m2.shape[0]):
        covered = {}  # (g, tile) -> rows (left half, right half)
        for t in range(tiles_x * tiles_y):
            for k in range(tile_start[c * tiles_x * tiles_y + t], tile_start[c * tiles_x * tiles_y + t + 1]):
                covered[(int(gid[k]), t)] = rows[k]
        for g in np.nonzero(valid[c])[0]:
            dx, dy = m2[c, g, 0] - xx, m2[c, g, 1] - yy
            sigma = 0.5 * (co[c, g, 0] * dx * dx + co[c, g, 2] * dy * dy) + co[c, g, 1] * dx * dy
            for y, x in zip(*np.nonzero((op[g] * np.exp(-sigma) >= ALPHA_MIN) & (sigma >= 0))):
                t = (y // TILE) * tiles_x + x // TILE
                assert (g, t) in covered, f"camera {c}: Gaussian {g} misses tile {t} at pixel ({x}, {y})"
                h = (x % TILE) // K.HALF
                r0, r1 = covered[(g, t)][2 * h], covered[(g, t)][2 * h + 1]
                assert r0 <= y % TILE <= r1, f"camera {c}: Gaussian {g}, pixel ({x}, {y}) outside rows {r0}..{r1}"
                n_checked += 1
    assert n_checked > 1000


def test_binning_culls_rows_and_half_tiles():
    """The row ranges are tighter than the tiles: fewer lanes than whole tiles, so the culling is exercised."""
    inputs = make_scene(150, d=1, n_cams=2, width=64, height=48, seed=0, dtype=torch.float32, dense=False)
    *_, rows = _bin(inputs, 64, 48)
    rows = rows.astype(np.int64)
    lanes = ((rows[:, 1] - rows[:, 0] + 1).clip(0) + (rows[:, 3] - rows[:, 2] + 1).clip(0)) * K.HALF
    assert lanes.min() > 0  # no entry without a row
    assert lanes.sum() < 0.8 * rows.shape[0] * TILE * TILE
    assert bool(((rows[:, 0] > rows[:, 1]) | (rows[:, 2] > rows[:, 3])).any())  # some entries use one half only


@pytest.mark.parametrize("seed", range(3))
def test_float32_compositing_matches_the_reference_on_a_larger_image(seed):
    """Compositing in float32 at pixel coordinates in the hundreds agrees with the torch reference
    (which composites the same float32-rounded projection) at the tolerances of
    test_matches_brute_force_forward_and_gradients. (Against the float64 brute force, seed 2 differs
    by 3e-4 in both paths and in main's float64-arithmetic kernels alike: the float32 rounding of
    the projected means and conics, not the compositing arithmetic.)"""
    width, height = 200, 150
    inputs = make_scene(150, d=1, n_cams=2, width=width, height=height, seed=seed, dtype=torch.float32)
    inputs[6][:, 0, 0] *= 5.0  # focal lengths for this image size: Gaussians a few to tens of pixels wide
    inputs[6][:, 1, 1] *= 5.0
    bg = torch.tensor([0.3])
    gen = torch.Generator().manual_seed(seed)
    cot_img = torch.randn(2, height, width, 1, generator=gen, dtype=torch.float64)
    cot_alpha = torch.randn(2, height, width, 1, generator=gen, dtype=torch.float64)
    img, alpha, grads = _grads(rasterize_numba, inputs, bg, width, height, cot_img, cot_alpha)
    img_r, alpha_r, grads_r = _grads(rasterize_reference, inputs, bg, width, height, cot_img, cot_alpha)
    assert float(alpha_r.detach().max()) > 0.99 and float(alpha_r.detach().min()) < 0.5
    _close(img, img_r, 1e-5, "images")
    _close(alpha, alpha_r, 1e-5, "alphas")
    for name, g, gr in zip(NAMES, grads, grads_r):
        if name != "Ks":
            _close(g, gr, 1e-4, f"d/d{name}")


def test_sigma_clamp_is_beyond_alpha_min():
    assert math.exp(-K._SIGMA_CLAMP) < ALPHA_MIN


@pytest.mark.parametrize("dtype,tol", [(np.float32, 1e-4), (np.float64, 1e-10)])
def test_kernels_skip_pixels_where_an_indefinite_conic_gives_negative_sigma(dtype, tol):
    """An indefinite conic (b^2 > a c) has sigma < 0 on part of the tile, where o exp(-sigma) would pass
    ALPHA_MIN: forward_tiles and backward_tiles must skip those pixels as the reference does (sigma >= 0)."""
    from splat_cpu._torch_impl import composite_dense

    size = TILE  # one tile
    m2 = np.array([[7.3, 8.1], [8.6, 6.9], [5.2, 9.4]])  # front to back
    co = np.array([[0.05, 0.01, 0.04], [0.02, 0.06, 0.03], [0.03, -0.005, 0.02]])  # the second is indefinite
    op = np.array([0.6, 0.5, 0.9])
    col = np.array([[0.9], [0.4], [0.2]])
    bg = np.array([0.3])
    order, n_valid = np.arange(3)[None], np.array([3])
    pix_box = np.tile(np.array([0, size - 1, 0, size - 1]), (1, 3, 1))
    args = [a.astype(dtype) for a in (m2[None], co[None], op, col[None], bg)]
    tile_start, gid, rows = K.bin_tiles(order, n_valid, pix_box, args[0], args[1], args[2], size, size, 1, 1)
    img = np.empty((1, size, size, 1), dtype)
    t_final = np.empty((1, size, size), dtype)
    last = np.empty((1, size, size), np.int32)
    tiles = (rows, tile_start, gid, size, size, 1, 1)
    K.forward_tiles(*args, *tiles, img, t_final, last)
    rng = np.random.default_rng(0)
    v_img, v_alpha = rng.standard_normal((1, size, size, 1)), rng.standard_normal((1, size, size))
    geo = np.empty((gid.shape[0], 6), dtype)
    out_col = np.empty((gid.shape[0], 1), dtype)
    K.backward_tiles(*args, *tiles, t_final, last, v_img.astype(dtype), v_alpha.astype(dtype), geo, out_col)
    ys, xs = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    pix = torch.tensor(np.stack([xs.ravel(), ys.ravel()], -1) + 0.5)
    ins = [torch.tensor(a.astype(dtype).astype(np.float64), requires_grad=True) for a in (m2, co, op, col)]
    ref, t_ref = composite_dense(pix, *ins)
    ref = ref + t_ref[:, None] * torch.tensor(bg)
    dx, dy = m2[1, 0] - pix[:, 0], m2[1, 1] - pix[:, 1]
    sigma = 0.5 * (co[1, 0] * dx * dx + co[1, 2] * dy * dy) + co[1, 1] * dx * dy
    assert bool((sigma < 0).any()) and bool((sigma > 0).any())  # the conic really is indefinite on this tile
    loss = (ref * torch.tensor(v_img.reshape(-1, 1))).sum() + ((1 - t_ref) * torch.tensor(v_alpha.reshape(-1))).sum()
    grads = torch.autograd.grad(loss, ins)
    assert np.abs(img.reshape(-1, 1) - ref.detach().numpy()).max() < tol
    assert np.abs(t_final.reshape(-1) - t_ref.detach().numpy()).max() < tol
    got = np.zeros((3, 6))
    got[gid] = geo  # one tile: one entry per Gaussian
    want = torch.cat([grads[0], grads[1], grads[2][:, None]], 1).numpy()
    assert np.abs(got - want).max() < tol * max(1.0, np.abs(want).max()), np.abs(got - want).max()
    assert np.abs(out_col[np.argsort(gid)] - grads[3].numpy()).max() < tol * max(1.0, np.abs(grads[3].numpy()).max())
