"""Numba tile kernels: binning, forward compositing and its hand-written backward.

Layout: the image of camera `cam` is cut into 16 x 16 tiles; tile id = cam * n_tiles + ty * tiles_x + tx.
`tile_start[t]:tile_start[t + 1]` indexes `gid`, the tile's Gaussians front to back.
Each tile walks its Gaussians in depth order and, for each, only the pixels of its exact
alpha >= 1/255 box that lie in the tile (Gaussian-outer, pixel-inner). The forward keeps,
per pixel, the final transmittance and the list position of the last contributing Gaussian;
the backward walks the list back from there, recovering T by division by (1 - alpha), and
writes one gradient row per (tile, Gaussian) entry, summed per Gaussian afterwards.
Arithmetic inside is float64 whatever the input dtype.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .constants import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE

_LOG_ALPHA_MIN = math.log(ALPHA_MIN)
_REJECT_SLACK = 1e-3  # sigma beyond ln(o / ALPHA_MIN) + slack: alpha < ALPHA_MIN for sure, skip the exp


@njit(cache=True, inline="always")
def _row_span(mx, dy, ca, cb, cc, thr, px0, xa, xb):
    """Columns lx in [xa, xb] of one row (offset dy = my - y) where sigma <= thr can hold.

    sigma(dx) = 0.5 ca dx^2 + cb dy dx + 0.5 cc dy^2 with dx = mx - (px0 + lx + 0.5); the
    quadratic's roots bound the span. thr carries slack, so no pixel with alpha >= ALPHA_MIN
    is left out; every pixel is still checked exactly.
    """
    disc = (cb * dy) ** 2 - ca * (cc * dy * dy - 2.0 * thr)
    if disc < 0.0 or ca <= 0.0:
        return 1, 0
    r = math.sqrt(disc)
    dx_lo = (-cb * dy - r) / ca
    dx_hi = (-cb * dy + r) / ca
    lo = math.ceil(mx - dx_hi - 0.5 - px0)
    hi = math.floor(mx - dx_lo - 0.5 - px0)
    return max(xa, int(lo)) if lo > xa else xa, min(xb, int(hi)) if hi < xb else xb


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


@njit(cache=True, parallel=True)
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
        trans = np.ones(TILE * TILE)
        acc = np.zeros((TILE * TILE, d))
        last = np.full(TILE * TILE, start - 1, dtype=np.int64)
        done = np.zeros(TILE * TILE, dtype=np.bool_)
        n_active = pw * ph
        for k in range(start, end):
            if n_active == 0:
                break
            g = gid[k]
            mx, my = means2d[cam, g, 0], means2d[cam, g, 1]
            ca, cb, cc = conics[cam, g, 0], conics[cam, g, 1], conics[cam, g, 2]
            op = opacities[g]
            thr = math.log(op) - _LOG_ALPHA_MIN + _REJECT_SLACK
            xa = max(pix_box[cam, g, 0] - px0, 0)
            xb = min(pix_box[cam, g, 1] - px0, pw - 1)
            ya = max(pix_box[cam, g, 2] - py0, 0)
            yb = min(pix_box[cam, g, 3] - py0, ph - 1)
            for ly in range(ya, yb + 1):
                dy = my - (py0 + ly + 0.5)
                xl, xr = _row_span(mx, dy, ca, cb, cc, thr, px0, xa, xb)
                for lx in range(xl, xr + 1):
                    i = ly * TILE + lx
                    if done[i]:
                        continue
                    dx = mx - (px0 + lx + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0 or sigma > thr:
                        continue
                    alpha = min(ALPHA_MAX, op * math.exp(-sigma))
                    if alpha < ALPHA_MIN:
                        continue
                    nt = trans[i] * (1.0 - alpha)
                    if nt <= T_MIN:
                        done[i] = True
                        n_active -= 1
                        continue
                    w = alpha * trans[i]
                    for ch in range(d):
                        acc[i, ch] += w * colors[g, ch]
                    trans[i] = nt
                    last[i] = k
        for ly in range(ph):
            for lx in range(pw):
                i = ly * TILE + lx
                y, x = py0 + ly, px0 + lx
                for ch in range(d):
                    out_img[cam, y, x, ch] = acc[i, ch] + trans[i] * background[ch]
                out_t[cam, y, x] = trans[i]
                out_last[cam, y, x] = last[i]


@njit(cache=True, parallel=True)
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
        trans = np.zeros(TILE * TILE)
        rest = np.zeros(TILE * TILE)  # sum over later Gaussians of (c . v_C) alpha T, plus the background/alpha terms
        vc = np.zeros((TILE * TILE, d))
        last = np.full(TILE * TILE, start - 1, dtype=np.int64)
        gcol = np.zeros(d)
        kmax = start - 1
        for ly in range(ph):
            for lx in range(pw):
                i = ly * TILE + lx
                y, x = py0 + ly, px0 + lx
                tf = t_final[cam, y, x]
                trans[i] = tf
                bgdot = 0.0
                for ch in range(d):
                    vc[i, ch] = v_img[cam, y, x, ch]
                    bgdot += background[ch] * v_img[cam, y, x, ch]
                # image = ... + T_N bg and alpha = 1 - T_N both depend on T_N = prod (1 - alpha_k)
                rest[i] = tf * bgdot - tf * v_alpha[cam, y, x]
                last[i] = last_idx[cam, y, x]
                kmax = max(kmax, last[i])
        for k in range(kmax, start - 1, -1):
            g = gid[k]
            mx, my = means2d[cam, g, 0], means2d[cam, g, 1]
            ca, cb, cc = conics[cam, g, 0], conics[cam, g, 1], conics[cam, g, 2]
            op = opacities[g]
            thr = math.log(op) - _LOG_ALPHA_MIN + _REJECT_SLACK
            xa = max(pix_box[cam, g, 0] - px0, 0)
            xb = min(pix_box[cam, g, 1] - px0, pw - 1)
            ya = max(pix_box[cam, g, 2] - py0, 0)
            yb = min(pix_box[cam, g, 3] - py0, ph - 1)
            g_mx = 0.0
            g_my = 0.0
            g_a = 0.0
            g_b = 0.0
            g_c = 0.0
            g_o = 0.0
            gcol[:] = 0.0
            hit = False
            for ly in range(ya, yb + 1):
                dy = my - (py0 + ly + 0.5)
                xl, xr = _row_span(mx, dy, ca, cb, cc, thr, px0, xa, xb)
                for lx in range(xl, xr + 1):
                    i = ly * TILE + lx
                    if k > last[i]:
                        continue
                    dx = mx - (px0 + lx + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0 or sigma > thr:
                        continue
                    vis = math.exp(-sigma)
                    raw = op * vis
                    alpha = min(ALPHA_MAX, raw)
                    if alpha < ALPHA_MIN:
                        continue
                    hit = True
                    ra = 1.0 / (1.0 - alpha)
                    tb = trans[i] * ra  # T before this Gaussian
                    trans[i] = tb
                    w = alpha * tb
                    cdot = 0.0
                    for ch in range(d):
                        gcol[ch] += w * vc[i, ch]
                        cdot += colors[g, ch] * vc[i, ch]
                    v_al = cdot * tb - rest[i] * ra
                    rest[i] += cdot * w
                    if raw < ALPHA_MAX:
                        g_o += vis * v_al
                        v_sig = -raw * v_al
                        g_a += 0.5 * dx * dx * v_sig
                        g_b += dx * dy * v_sig
                        g_c += 0.5 * dy * dy * v_sig
                        g_mx += (ca * dx + cb * dy) * v_sig
                        g_my += (cb * dx + cc * dy) * v_sig
            if hit:
                out_geo[k, 0] = g_mx
                out_geo[k, 1] = g_my
                out_geo[k, 2] = g_a
                out_geo[k, 3] = g_b
                out_geo[k, 4] = g_c
                out_geo[k, 5] = g_o
                for ch in range(d):
                    out_col[k, ch] = gcol[ch]


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
