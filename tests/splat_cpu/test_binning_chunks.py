"""The parallel binning (chunks of Gaussians), the per-Gaussian gradient sums and the depth order of the fast path."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import torch

from splat_cpu import _numba_kernels as K
from splat_cpu._numba_impl import _depth_order, _np, _Project, rasterize_numba
from splat_cpu.constants import TILE

from .conftest import make_scene
from .test_numba_kernels import _bin


def test_depth_order_is_the_stable_argsort_with_ties_and_invalid_gaussians():
    gen = np.random.default_rng(0)
    depths = gen.choice(np.float32([0.5, 1.0, 1.0 + 2**-20, 7.0, 1e30]), size=(3, 200))  # many ties
    valid = gen.random((3, 200)) < 0.8
    depths[~valid] = 0.0  # what the projection writes for a culled Gaussian
    for dtype in (np.float32, np.float64):
        got = _depth_order(depths.astype(dtype), valid)
        want = np.argsort(np.where(valid, depths.astype(dtype), np.inf), axis=1, kind="stable")
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want)


def _lists(inputs, width, height, threads):
    before = numba.get_num_threads()
    numba.set_num_threads(threads)  # 4 chunks per thread: 4 or 8 chunks of the Gaussians
    try:
        return _bin(inputs, width, height)[4:]
    finally:
        numba.set_num_threads(before)


@pytest.mark.parametrize("seed", range(3))
def test_tile_lists_do_not_depend_on_the_chunks_and_run_front_to_back(seed):
    width, height = 64, 48
    inputs = make_scene(300, d=1, n_cams=3, width=width, height=height, seed=seed, dtype=torch.float32)
    one = _lists(inputs, width, height, 1)
    two = _lists(inputs, width, height, min(2, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)
    tile_start, gid, _ = one
    n_tiles = -(-width // TILE) * -(-height // TILE)
    # each tile's list is strictly front to back in the camera's depth order (the order bin_tiles was given)
    means, _, _, _, _, viewmats, _ = inputs
    z = (means.double() @ viewmats[:, 2, :3].double().T + viewmats[:, 2, 3].double()).T.float().numpy()  # [C, N]
    for t in range(tile_start.shape[0] - 1):
        c = t // n_tiles
        g = gid[tile_start[t] : tile_start[t + 1]]
        assert np.all(np.diff(z[c, g]) >= 0), f"tile {t} not front to back"
    assert gid.shape[0] > 1000


def test_gradient_sums_per_gaussian_equal_the_sums_in_list_order():
    """reduce_grads adds each Gaussian's rows through the candidate index: the same as a plain scatter-add in
    list order (float64 sums of float32 rows, so equal to the last bit)."""
    width, height = 64, 48
    inputs = make_scene(300, d=3, n_cams=2, width=width, height=height, seed=1, dtype=torch.float32)
    means, quats, scales, opac, colors, viewmats, ks = inputs
    out: dict = {}
    m2t, cot = _Project.apply(means, quats, scales, opac, viewmats, ks, width, height, out, {})
    order = _depth_order(out["depths"].numpy(), out["valid"])
    n_valid = out["valid"].sum(axis=1)
    tx, ty = -(-width // TILE), -(-height // TILE)
    tile_start, gid, rows, cam_start, box_start, ent = K.bin_tiles_indexed(
        order, n_valid, out["pix_box"], _np(m2t), _np(cot), _np(opac), width, height, tx, ty
    )
    rng = np.random.default_rng(0)
    geo = rng.standard_normal((gid.shape[0], 6)).astype(np.float32)
    col = rng.standard_normal((gid.shape[0], 3)).astype(np.float32)
    n_cam, n = viewmats.shape[0], means.shape[0]
    got = [np.zeros((n_cam, n, 2)), np.zeros((n_cam, n, 3)), np.zeros((n_cam, n)), np.zeros((n_cam, n, 3))]
    K.reduce_grads(order, cam_start, box_start, ent, geo, col, *got)
    want = [np.zeros_like(a) for a in got]
    for k in range(gid.shape[0]):  # list order
        c = int(np.searchsorted(tile_start, k, side="right") - 1) // (tx * ty)
        g = gid[k]
        want[0][c, g] += geo[k, :2]
        want[1][c, g] += geo[k, 2:5]
        want[2][c, g] += geo[k, 5]
        want[3][c, g] += col[k]
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    assert np.count_nonzero(ent >= 0) == gid.shape[0]


def test_gradients_do_not_depend_on_the_number_of_threads():
    width, height = 64, 48
    inputs = make_scene(300, d=3, n_cams=2, width=width, height=height, seed=2, dtype=torch.float32)
    grads = []
    before = numba.get_num_threads()
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):  # type: ignore[attr-defined]
        numba.set_num_threads(threads)
        try:
            leaves = [t.clone().requires_grad_() for t in inputs[:6]]
            img, alpha, _ = rasterize_numba(*leaves, inputs[6], width, height)
            (img.sum() + 0.5 * alpha.square().sum()).backward()
            grads.append([img.detach()] + [t.grad for t in leaves])
        finally:
            numba.set_num_threads(before)
    for a, b in zip(*grads):
        assert torch.equal(a, b)
