"""The order the compositing kernels take the tiles in (`balanced_runs`): runs of image order of equal cost, one per
thread, the costs it is given, and outputs that do not depend on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from splat_cpu import _numba_kernels as K
from splat_cpu.constants import TILE

from .conftest import make_scene
from .test_numba_kernels import _bin


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("n_runs", [1, 2, 3, 4])
def test_balanced_runs_cut_image_order_into_runs_of_equal_cost(seed, n_runs):
    gen = np.random.default_rng(seed)
    n = 374  # the target image's tiles
    cost = gen.integers(2000, 4300, n)
    cost[: n // 2] += 400  # costlier at the top: there a cut at the middle is not balanced
    cost[gen.choice(n, 40, replace=False)] = 0  # empty tiles
    slots = K.balanced_runs(cost, n_runs)
    longest = slots.shape[0] // n_runs
    assert slots.shape[0] == n_runs * longest
    np.testing.assert_array_equal(slots[slots >= 0], np.arange(n))  # every tile once, in image order
    for r in range(n_runs):  # thread r's equal share of the slots (numba's static split) holds run r
        run = slots[r * longest : (r + 1) * longest]
        tiles = run[run >= 0]
        assert np.all(run[tiles.size :] == -1)  # the run first, then padding
        assert abs(cost[tiles].sum() - cost.sum() / n_runs) <= cost.max()
    if n_runs == 2:
        assert cost[: n // 2].sum() - cost.sum() / 2 > 4 * cost.max()  # the middle cut was not balanced


def _composite(inputs, width, height, order_f=None, order_b=None):
    """forward_tiles then backward_tiles (float32) in the orders given (balanced runs by default); every output."""
    m2, co, op, _, tile_start, gid, rows = _bin(inputs, width, height)
    f32 = np.float32
    colors, n_cam = inputs[4].numpy()[None].astype(f32), m2.shape[0]
    args = (m2.astype(f32), co.astype(f32), op.astype(f32), colors, np.full(colors.shape[-1], 0.25, f32))
    tiles = (rows, tile_start, gid, width, height, -(-width // TILE), -(-height // TILE))
    n_all = tile_start.shape[0] - 1
    img = np.empty((n_cam, height, width, colors.shape[-1]), f32)
    t_final, last = np.empty((n_cam, height, width), f32), np.empty((n_cam, height, width), np.int32)
    cost = np.full(n_all, -7, np.int64)
    order_f = K.balanced_runs(K.forward_cost(tile_start, rows), 2) if order_f is None else order_f
    K.forward_tiles(*args, *tiles, order_f, img, t_final, last, cost)
    gen = np.random.default_rng(1)
    v_img = gen.standard_normal(img.shape).astype(f32)
    v_alpha = gen.standard_normal(t_final.shape).astype(f32)
    geo, col = np.full((gid.shape[0], 6), np.nan, f32), np.full((gid.shape[0], colors.shape[-1]), np.nan, f32)
    order_b = K.balanced_runs(cost, 2) if order_b is None else order_b
    K.backward_tiles(*args, *tiles, order_b, t_final, last, v_img, v_alpha, geo, col)
    return (img, t_final, last, geo, col), cost, (tile_start, rows)


@pytest.mark.parametrize("d", [1, 3])
def test_kernels_give_the_same_bits_in_any_order_of_the_tiles(d):
    width, height = 64, 48
    inputs = make_scene(300, d=d, n_cams=2, width=width, height=height, seed=3, dtype=torch.float32)
    balanced, cost, _ = _composite(inputs, width, height)
    n_all = cost.shape[0]
    image_order = np.arange(n_all)
    shuffled = np.random.default_rng(0).permutation(n_all)
    padded = np.insert(shuffled, [0, 5, 5, n_all], -1)  # slots to skip
    assert np.any(K.balanced_runs(cost, 2) < 0)  # the default has padding
    for order_f, order_b in ((image_order, image_order), (shuffled, padded[::-1].copy())):
        got, got_cost, _ = _composite(inputs, width, height, order_f, order_b)
        for a, b in zip(got, balanced):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(got_cost, cost)
    assert not any(np.isnan(a).any() for a in balanced[3:])  # every gradient row written


def test_costs_count_the_rows_the_kernels_walk():
    """forward_cost: every row of every entry; forward_tiles' out_cost: the rows backward_tiles walks, entries up to
    the tile's last contributing one, less the rows at either end of an entry whose pixels all stopped before it;
    both plus _SPAN_COST per non-empty span. Counted here in Python from the tile lists and the last positions."""
    width, height = 64, 48
    inputs = make_scene(300, d=1, n_cams=2, width=width, height=height, seed=4, dtype=torch.float32)
    (_, _, last, _, _), cost, (tile_start, rows) = _composite(inputs, width, height)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    want_f, want_b = [], []
    for t in range(tile_start.shape[0] - 1):
        cam, tt = divmod(t, tiles_x * tiles_y)
        ty, tx = divmod(tt, tiles_x)
        block = last[cam, ty * TILE : (ty + 1) * TILE, tx * TILE : (tx + 1) * TILE]
        row_kmax = np.full((2, TILE), -1)
        for h in range(2):
            part = block[:, h * K.HALF : (h + 1) * K.HALF]
            row_kmax[h, : part.shape[0]] = part.max(axis=1, initial=-1)
        fwd = bwd = 0
        for kk, k in enumerate(range(tile_start[t], tile_start[t + 1])):
            for h in range(2):
                ya, yb = int(rows[k, 2 * h]), int(rows[k, 2 * h + 1])
                if ya <= yb:
                    fwd += yb - ya + 1 + K._SPAN_COST
                live = [y for y in range(ya, yb + 1) if row_kmax[h, y] >= kk]
                if live:  # interior rows whose pixels stopped stay in the span
                    bwd += live[-1] - live[0] + 1 + K._SPAN_COST
        want_f.append(fwd)
        want_b.append(bwd)
    np.testing.assert_array_equal(K.forward_cost(tile_start, rows), want_f)
    np.testing.assert_array_equal(cost, want_b)
    assert 0 < sum(want_b) < sum(want_f)  # the backward's trimming is exercised
