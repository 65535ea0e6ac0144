"""Numba tile kernels: binning, forward compositing and its hand-written backward.

Layout: the image of camera `cam` is cut into 16 x 16 tiles; tile id = cam * n_tiles + ty * tiles_x + tx.
`tile_start[t]:tile_start[t + 1]` indexes `gid`, the tile's Gaussians front to back.
Each tile walks its Gaussians in depth order and, for each, the tile rows of its exact
alpha >= 1/255 box; a row is processed as 16 lanes without branches (selects only), which
LLVM vectorises, with a polynomial exp (`_exp_neg`, relative error < 1e-11). The forward
keeps, per pixel, the final transmittance and the list position of the last contributing
Gaussian; the backward walks the list back from there, recovering T by division by
(1 - alpha), and writes one gradient row per (tile, Gaussian) entry, summed per Gaussian
afterwards. Arithmetic inside is float64 whatever the input dtype.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .constants import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # FMA and reassociation; no nan/inf assumptions
_SIGMA_CLAMP = 8.0  # exp(-8) < ALPHA_MIN: beyond it alpha is skipped whatever the opacity


@njit(cache=True, inline="always", fastmath=_FASTMATH, error_model="numpy")
def _exp_neg(s):
    """exp(-s) for s in [0, 8] as (exp(-s / 8))^8, Taylor to degree 14 on [-1, 0]; vectorisable."""
    x = -0.125 * s
    p = 1.0 / 87178291200.0
    p = p * x + 1.0 / 6227020800.0
    p = p * x + 1.0 / 479001600.0
    p = p * x + 1.0 / 39916800.0
    p = p * x + 1.0 / 3628800.0
    p = p * x + 1.0 / 362880.0
    p = p * x + 1.0 / 40320.0
    p = p * x + 1.0 / 5040.0
    p = p * x + 1.0 / 720.0
    p = p * x + 1.0 / 120.0
    p = p * x + 1.0 / 24.0
    p = p * x + 1.0 / 6.0
    p = p * x + 0.5
    p = p * x + 1.0
    p = p * x + 1.0
    p = p * p
    p = p * p
    return p * p


@njit(cache=True)
def bin_tiles(
    order,  # [C, N] int64: per camera, Gaussian indices front to back (first n_valid[c] are valid)
    n_valid,  # [C] int64
    pix_box,  # [C, N, 4] int64 inclusive pixel box (x0, x1, y0, y1)
    tiles_x,
    tiles_y,
):  # -> tile_start [C * n_tiles + 1] int64, gid [n_isect] int32
    n_cam = order.shape[0]
    n_tiles = tiles_x * tiles_y
    counts = np.zeros(n_cam * n_tiles + 1, dtype=np.int64)
    for c in range(n_cam):
        base = c * n_tiles
        for j in range(n_valid[c]):
            g = order[c, j]
            tx0, tx1 = pix_box[c, g, 0] // TILE, pix_box[c, g, 1] // TILE
            ty0, ty1 = pix_box[c, g, 2] // TILE, pix_box[c, g, 3] // TILE
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    counts[base + ty * tiles_x + tx + 1] += 1
    tile_start = np.cumsum(counts)
    fill = tile_start[:-1].copy()
    gid = np.empty(tile_start[-1], dtype=np.int32)
    for c in range(n_cam):
        base = c * n_tiles
        for j in range(n_valid[c]):
            g = order[c, j]
            tx0, tx1 = pix_box[c, g, 0] // TILE, pix_box[c, g, 1] // TILE
            ty0, ty1 = pix_box[c, g, 2] // TILE, pix_box[c, g, 3] // TILE
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    t = base + ty * tiles_x + tx
                    gid[fill[t]] = g
                    fill[t] += 1
    return tile_start, gid


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model="numpy")
def forward_tiles(
    means2d,  # [C, N, 2]
    conics,  # [C, N, 3]
    opacities,  # [N]
    colors,  # [N, D]
    background,  # [D]
    pix_box,  # [C, N, 4] int64
    tile_start,  # [C * n_tiles + 1] int64
    gid,  # [n_isect] int32
    width,
    height,
    tiles_x,
    tiles_y,
    out_img,  # [C, H, W, D] written
    out_t,  # [C, H, W] written: final transmittance
    out_last,  # [C, H, W] int64 written: list position of the last contributing Gaussian, start - 1 if none
):
    n_tiles = tiles_x * tiles_y
    n_all = tile_start.shape[0] - 1
    d = colors.shape[1]
    for t in prange(n_all):
        cam = t // n_tiles
        tt = t - cam * n_tiles
        ty, tx = tt // tiles_x, tt - (tt // tiles_x) * tiles_x
        px0, py0 = tx * TILE, ty * TILE
        pw, ph = min(TILE, width - px0), min(TILE, height - py0)
        start, end = tile_start[t], tile_start[t + 1]
        trans = np.ones((TILE, TILE))
        acc = np.zeros((d, TILE, TILE))
        last = np.full((TILE, TILE), start - 1, dtype=np.int64)
        live = np.zeros((TILE, TILE))  # 1 while the pixel composites; 0 outside the image or once T is spent
        row_live = np.zeros(TILE, dtype=np.int64)  # live pixels per row: a spent row is skipped
        for ly in range(ph):
            row_live[ly] = pw
            for lx in range(pw):
                live[ly, lx] = 1.0
        n_active = pw * ph
        wrow = np.zeros(TILE)
        pxc = np.empty(TILE)
        for lx in range(TILE):
            pxc[lx] = px0 + lx + 0.5
        for k in range(start, end):
            if n_active == 0:
                break
            g = gid[k]
            mx, my = np.float64(means2d[cam, g, 0]), np.float64(means2d[cam, g, 1])
            ca, cb, cc = np.float64(conics[cam, g, 0]), np.float64(conics[cam, g, 1]), np.float64(conics[cam, g, 2])
            op = np.float64(opacities[g])
            ya = max(pix_box[cam, g, 2] - py0, 0)
            yb = min(pix_box[cam, g, 3] - py0, ph - 1)
            for ly in range(ya, yb + 1):
                if row_live[ly] == 0:
                    continue
                dy = my - (py0 + ly + 0.5)
                tr = trans[ly]
                lv = live[ly]
                la = last[ly]
                nstop = 0.0
                for lx in range(TILE):
                    dx = mx - pxc[lx]
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    alpha = min(ALPHA_MAX, op * _exp_neg(min(max(sigma, 0.0), _SIGMA_CLAMP)))
                    tc = tr[lx]
                    nt = tc * (1.0 - alpha)
                    ok = (sigma >= 0.0) & (alpha >= ALPHA_MIN) & (lv[lx] > 0.0)
                    stop = ok & (nt <= T_MIN)
                    con = ok & (nt > T_MIN)
                    wrow[lx] = alpha * tc if con else 0.0
                    tr[lx] = nt if con else tc
                    lv[lx] = 0.0 if stop else lv[lx]
                    la[lx] = k if con else la[lx]
                    nstop += 1.0 if stop else 0.0
                n_active -= int(nstop)
                row_live[ly] -= int(nstop)
                for ch in range(d):
                    cv = np.float64(colors[g, ch])
                    ar = acc[ch, ly]
                    for lx in range(TILE):
                        ar[lx] += wrow[lx] * cv
        for ly in range(ph):
            for lx in range(pw):
                y, x = py0 + ly, px0 + lx
                for ch in range(d):
                    out_img[cam, y, x, ch] = acc[ch, ly, lx] + trans[ly, lx] * background[ch]
                out_t[cam, y, x] = trans[ly, lx]
                out_last[cam, y, x] = last[ly, lx]


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model="numpy")
def backward_tiles(
    means2d,  # [C, N, 2]
    conics,  # [C, N, 3]
    opacities,  # [N]
    colors,  # [N, D]
    background,  # [D]
    pix_box,  # [C, N, 4] int64
    tile_start,  # [C * n_tiles + 1] int64
    gid,  # [n_isect] int32
    width,
    height,
    tiles_x,
    tiles_y,
    t_final,  # [C, H, W]
    last_idx,  # [C, H, W] int64
    v_img,  # [C, H, W, D] cotangent of the images
    v_alpha,  # [C, H, W] cotangent of the alphas
    out_geo,  # [n_isect, 6] written: d/d (mx, my, conic a, b, c, opacity) per list entry
    out_col,  # [n_isect, D] written: d/d colour per list entry
):
    n_tiles = tiles_x * tiles_y
    n_all = tile_start.shape[0] - 1
    d = colors.shape[1]
    for t in prange(n_all):
        start, end = tile_start[t], tile_start[t + 1]
        if end == start:
            continue
        cam = t // n_tiles
        tt = t - cam * n_tiles
        ty, tx = tt // tiles_x, tt - (tt // tiles_x) * tiles_x
        px0, py0 = tx * TILE, ty * TILE
        pw, ph = min(TILE, width - px0), min(TILE, height - py0)
        trans = np.ones((TILE, TILE))
        # rest: sum over later Gaussians of (c . v_C) alpha T, plus T_N (bg . v_C) - T_N v_alpha
        rest = np.zeros((TILE, TILE))
        vc = np.zeros((d, TILE, TILE))
        last = np.full((TILE, TILE), start - 1, dtype=np.int64)  # pixels outside the image never match
        kmax = start - 1
        row_kmax = np.full(TILE, start - 1, dtype=np.int64)  # rows whose pixels all stopped before k are skipped
        for ly in range(ph):
            for lx in range(pw):
                y, x = py0 + ly, px0 + lx
                tf = np.float64(t_final[cam, y, x])
                trans[ly, lx] = tf
                bgdot = 0.0
                for ch in range(d):
                    vc[ch, ly, lx] = v_img[cam, y, x, ch]
                    bgdot += background[ch] * v_img[cam, y, x, ch]
                rest[ly, lx] = tf * bgdot - tf * v_alpha[cam, y, x]
                last[ly, lx] = last_idx[cam, y, x]
                row_kmax[ly] = max(row_kmax[ly], last[ly, lx])
            kmax = max(kmax, row_kmax[ly])
        pxc = np.empty(TILE)
        for lx in range(TILE):
            pxc[lx] = px0 + lx + 0.5
        wrow = np.zeros(TILE)
        cdot = np.zeros(TILE)
        for k in range(kmax, start - 1, -1):
            g = gid[k]
            mx, my = np.float64(means2d[cam, g, 0]), np.float64(means2d[cam, g, 1])
            ca, cb, cc = np.float64(conics[cam, g, 0]), np.float64(conics[cam, g, 1]), np.float64(conics[cam, g, 2])
            op = np.float64(opacities[g])
            ya = max(pix_box[cam, g, 2] - py0, 0)
            yb = min(pix_box[cam, g, 3] - py0, ph - 1)
            g_mx = 0.0
            g_my = 0.0
            g_a = 0.0
            g_b = 0.0
            g_c = 0.0
            g_o = 0.0
            n_hit = 0.0
            for ly in range(ya, yb + 1):
                if k > row_kmax[ly]:
                    continue
                dy = my - (py0 + ly + 0.5)
                tr = trans[ly]
                rs = rest[ly]
                la = last[ly]
                for lx in range(TILE):
                    cdot[lx] = 0.0
                for ch in range(d):
                    cv = np.float64(colors[g, ch])
                    vr = vc[ch, ly]
                    for lx in range(TILE):
                        cdot[lx] += cv * vr[lx]
                for lx in range(TILE):
                    dx = mx - pxc[lx]
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    vis = _exp_neg(min(max(sigma, 0.0), _SIGMA_CLAMP))
                    raw = op * vis
                    alpha = min(ALPHA_MAX, raw)
                    ok = (sigma >= 0.0) & (alpha >= ALPHA_MIN) & (k <= la[lx])
                    ra = 1.0 / (1.0 - alpha)
                    tb = tr[lx] * ra  # T before this Gaussian
                    w = alpha * tb
                    v_al = cdot[lx] * tb - rs[lx] * ra
                    tr[lx] = tb if ok else tr[lx]
                    rs[lx] = rs[lx] + cdot[lx] * w if ok else rs[lx]
                    wrow[lx] = w if ok else 0.0
                    gate = ok & (raw < ALPHA_MAX)  # the clamp at ALPHA_MAX passes no gradient
                    v_sig = -raw * v_al if gate else 0.0
                    g_o += vis * v_al if gate else 0.0
                    g_a += 0.5 * dx * dx * v_sig
                    g_b += dx * dy * v_sig
                    g_c += 0.5 * dy * dy * v_sig
                    g_mx += (ca * dx + cb * dy) * v_sig
                    g_my += (cb * dx + cc * dy) * v_sig
                    n_hit += 1.0 if ok else 0.0
                for ch in range(d):
                    vr = vc[ch, ly]
                    sc = 0.0
                    for lx in range(TILE):
                        sc += wrow[lx] * vr[lx]
                    out_col[k, ch] += sc
            if n_hit > 0.0:
                out_geo[k, 0] = g_mx
                out_geo[k, 1] = g_my
                out_geo[k, 2] = g_a
                out_geo[k, 3] = g_b
                out_geo[k, 4] = g_c
                out_geo[k, 5] = g_o


@njit(cache=True)
def reduce_grads(
    tile_start,  # [C * n_tiles + 1] int64
    gid,  # [n_isect] int32
    n_tiles,
    geo,  # [n_isect, 6]
    col,  # [n_isect, D]
    v_means2d,  # [C, N, 2] accumulated
    v_conics,  # [C, N, 3] accumulated
    v_opac,  # [N] accumulated
    v_colors,  # [N, D] accumulated
):
    d = col.shape[1]
    for t in range(tile_start.shape[0] - 1):
        cam = t // n_tiles
        for k in range(tile_start[t], tile_start[t + 1]):
            g = gid[k]
            v_means2d[cam, g, 0] += geo[k, 0]
            v_means2d[cam, g, 1] += geo[k, 1]
            v_conics[cam, g, 0] += geo[k, 2]
            v_conics[cam, g, 1] += geo[k, 3]
            v_conics[cam, g, 2] += geo[k, 4]
            v_opac[g] += geo[k, 5]
            for ch in range(d):
                v_colors[g, ch] += col[k, ch]
