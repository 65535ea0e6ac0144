"""Numba tile kernels: binning, forward compositing and its hand-written backward.

Layout: the image of camera `cam` is cut into 16 x 16 tiles; tile id = cam * n_tiles + ty * tiles_x + tx.
`tile_start[t]:tile_start[t + 1]` indexes `gid`, the tile's Gaussians front to back, and
`rows`, the rows of each half tile (its left and right 8 columns) that each may touch.
Binning (gsplat-style tile culling) keeps a tile only when the Gaussian's alpha >= 1/255
ellipse (o exp(-sigma) >= ALPHA_MIN, the opacity-aware extent) reaches its pixels, and per
half tile only the rows it reaches there. Each tile keeps flat per-pixel buffers, the left
half's 16 rows of 8 pixels then the right half's (`_pixel`), and walks its Gaussians in depth
order; a Gaussian's rows in a half are one contiguous slice of those buffers, processed by two
loops without branches (selects only) that LLVM vectorises: the polynomial exp (`exp_neg`) into a
per-pixel buffer, then the compositing that reads it.
The forward keeps, per pixel, the final transmittance and the list position of the last
contributing Gaussian; the backward walks the list back from there, recovering T by division
by (1 - alpha), and writes one gradient row per (tile, Gaussian) entry, summed per Gaussian
afterwards. Arithmetic inside the compositing is in the inputs' float type: float32 inputs
run 16 float32 lanes per AVX-512 vector (their outputs were float32 before; the error against
the float64 brute force is unchanged, tests/splat_cpu), float64 inputs run in float64.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, overload
from numpy.polynomial import Chebyshev, Polynomial

from .constants import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # FMA and reassociation; no nan/inf assumptions
_SIGMA_CLAMP = 5.6  # exp(-5.6) = 0.0037 < ALPHA_MIN: beyond it alpha is skipped whatever the opacity
assert math.exp(-_SIGMA_CLAMP) < ALPHA_MIN
_CULL_MARGIN = 1e-4  # binning widens each ellipse to sigma <= smax + this (>> float32 rounding of sigma and exp)
_ROW_MARGIN = 1e-3  # and each row range by this many pixels (>> the rounding of the ellipse geometry)
_ILL_CONDITIONED = 1e-9  # det(conic) below this times a c: the geometry is not trusted, the box's rows are kept
_TILE_SHIFT = 4  # TILE = 1 << 4: pixel x lies in tile column x >> 4
HALF = TILE // 2  # each tile's buffers hold its left HALF columns, then its right ones
_HALF_PX = HALF * TILE  # pixels of a half tile
_HALF_SHIFT = 3  # HALF = 1 << 3
assert HALF == 1 << _HALF_SHIFT


_LN2 = math.log(2.0)  # one constant: fastmath would fold a Cody-Waite split of it (n <= 8 keeps the error small)
# exp(-r) on |r| <= ln2 / 2 by its Chebyshev interpolant in the power basis, lowest degree first; the
# degree per float width reaches the width's rounding (tested in tests/splat_cpu/test_numba_kernels.py)
_EXP_DEGREE = {32: 6, 64: 12}
_EXP_COEFS = {
    bits: tuple(
        Chebyshev.interpolate(lambda r: np.exp(-r), deg, domain=[-_LN2 / 2, _LN2 / 2])
        .convert(kind=Polynomial)
        .coef.tolist()
    )
    for bits, deg in _EXP_DEGREE.items()
}
_FLOAT_BITS = {32: (23, 127), 64: (52, 1023)}  # mantissa bits and exponent bias of IEEE floats


@intrinsic
def _float_from_bits(typingctx, bits, like):
    """The float of `like`'s type whose IEEE bit pattern is the integer `bits` (LLVM bitcast, vectorisable)."""
    if not isinstance(bits, types.Integer) or not isinstance(like, types.Float):
        return None
    int_ty = ir.IntType(like.bitwidth)
    float_ty = ir.FloatType() if like.bitwidth == 32 else ir.DoubleType()

    def codegen(context, builder, signature, args):
        value = args[0]
        if bits.bitwidth > like.bitwidth:
            value = builder.trunc(value, int_ty)
        elif bits.bitwidth < like.bitwidth:
            value = builder.sext(value, int_ty)
        return builder.bitcast(value, float_ty)

    return like(bits, like), codegen


@intrinsic
def _select(typingctx, cond, a, b):
    """`a if cond else b` as one LLVM select, no branch: a store of it into the array it was read from
    stays one plain vector store (a branch lets LLVM drop the store on the unchanged side and vectorise
    the rest as masked stores, which cost many micro-ops on AMD cores)."""
    if not isinstance(cond, types.Boolean) or a != b:
        return None

    def codegen(context, builder, signature, args):
        c = args[0]
        if c.type != ir.IntType(1):
            c = builder.icmp_unsigned("!=", c, ir.Constant(c.type, 0))
        return builder.select(c, args[1], args[2])

    return a(cond, a, b), codegen


def exp_neg(s):
    """exp(-s) for s in [0, _SIGMA_CLAMP], in the float type of s (float32 or float64); numba only."""
    raise NotImplementedError("exp_neg is compiled inside numba kernels only")


@overload(exp_neg, inline="always")
def _exp_neg_impl(s):
    """exp(-s) = 2^-n exp(-r), n = round(s / ln 2), |r| <= ln2 / 2: a polynomial and an exponent, no branch.

    Relative error 8.7e-8 in float32 and 2.0e-15 in float64 (measured by tests/splat_cpu/test_numba_kernels.py).
    """
    if not isinstance(s, types.Float):
        return None
    f = np.float32 if s.bitwidth == 32 else np.float64
    coefs = tuple(f(c) for c in _EXP_COEFS[s.bitwidth][::-1])  # highest degree first, for Horner
    mant, bias = _FLOAT_BITS[s.bitwidth]
    log2e, ln2, half = f(1.0 / _LN2), f(_LN2), f(0.5)

    def impl(s):
        n = np.floor(s * log2e + half)
        r = s - n * ln2
        p = coefs[0]
        for c in coefs[1:]:
            p = p * r + c
        # n in int32: AVX2 converts packed floats to int32 (vcvttps2dq, vcvttpd2dq) but not to int64
        return p * _float_from_bits((bias - np.int32(n)) << mant, s)

    return impl


@njit(cache=True, inline="always")
def _ellipse(mx, my, ca, cb, cc, smax):  # -> the terms of `_band_extent`, once per Gaussian
    """The ellipse sigma <= smax, sigma = 0.5 (a dx^2 + c dy^2) + b dx dy with (dx, dy) = (mx - x, my - y):
    its centre, b, 1 / c, b^2 - a c, 2 c smax, and its top and bottom points (where dx = -b dy / a)."""
    ey = math.sqrt(2.0 * smax * ca / (ca * cc - cb * cb))
    ex = cb * ey / ca
    return mx, my, cb, 1.0 / cc, cb * cb - ca * cc, 2.0 * cc * smax, mx + ex, my - ey, mx - ex, my + ey


@njit(cache=True, inline="always")
def _band_extent(ell, xa, xb):  # -> (ylo, yhi), (inf, -inf) when empty
    """The y-extent of the ellipse `ell` (from `_ellipse`) inside the vertical band xa <= x <= xb:
    its top and bottom points when they lie in the band, and the chords on the band's two edges."""
    mx, my, cb, inv_cc, q, c2s, x_top, y_top, x_bot, y_bot = ell
    ylo, yhi = np.inf, -np.inf
    if xa <= x_top <= xb:
        ylo, yhi = min(ylo, y_top), max(yhi, y_top)
    if xa <= x_bot <= xb:
        ylo, yhi = min(ylo, y_bot), max(yhi, y_bot)
    for edge in range(2):
        dx = mx - (xa if edge == 0 else xb)
        disc = dx * dx * q + c2s
        if disc >= 0.0:
            r = math.sqrt(disc)
            ylo = min(ylo, my - (r - cb * dx) * inv_cc)
            yhi = max(yhi, my + (r + cb * dx) * inv_cc)
    return ylo, yhi


@njit(cache=True, inline="always")
def _band_span(ell, trusted, bx0, bx1, by0, by1, col0, col1, height):  # -> (lo, hi) image rows, lo > hi: a miss
    """The image rows, in the pixel columns col0..col1, where the Gaussian's alpha >= ALPHA_MIN ellipse `ell`
    may have pixels (a superset: widened by _CULL_MARGIN in sigma and _ROW_MARGIN in pixels), within its
    inclusive pixel box (bx0, bx1, by0, by1). Independent of the tile row: computed once per column band."""
    if max(col0, bx0) > min(col1, bx1):
        return height, -1  # the box misses these columns
    if not trusted or (col0 <= bx0 and bx1 <= col1):
        return by0, by1  # an untrusted conic, or the whole box within the columns: the box's rows
    ylo, yhi = _band_extent(ell, col0 + 0.5, col1 + 0.5)
    if not ylo <= yhi:
        return height, -1
    # row j (pixel centre j + 0.5) is kept when ylo <= j + 0.5 <= yhi, widened by _ROW_MARGIN
    lo = max(by0, int(math.ceil(max(ylo - _ROW_MARGIN - 0.5, -1.0))))
    hi = min(by1, int(math.floor(min(yhi + _ROW_MARGIN - 0.5, float(height)))))
    return lo, hi


@njit(cache=True, inline="always")
def _tile_range(pix_box, c, g):  # -> (tx0, tx1, ty0, ty1): the tiles of the pixel box (inside the image: >= 0)
    return (
        pix_box[c, g, 0] >> _TILE_SHIFT,
        pix_box[c, g, 1] >> _TILE_SHIFT,
        pix_box[c, g, 2] >> _TILE_SHIFT,
        pix_box[c, g, 3] >> _TILE_SHIFT,
    )


@njit(cache=True, inline="always")
def _camera_of(cam_start, f, c):  # -> the camera of flat index f (cameras' valid Gaussians back to back), from c on
    while f >= cam_start[c + 1]:
        c += 1
    return c


@njit(cache=True, parallel=True)
def _tile_hits(order, cam_start, means2d, conics, smax, pix_box, width, height, box_start, tiles_x, out_rows, counts):
    """out_rows[box_start[c, j] + r] = rows of each half of the r-th tile (row-major) of the j-th Gaussian's box
    (camera c) it may touch, counted from the tile's top row: (row0, row1) of the left HALF columns, then of the
    right ones; (0, -1) where it touches none. counts[q, tile] += the tile's kept candidates in chunk q of the
    Gaussians (all cameras' valid Gaussians back to back, cut into counts.shape[0] chunks)."""
    n_chunks = counts.shape[0]
    total = cam_start[-1]
    n_tiles = counts.shape[1] // (cam_start.shape[0] - 1)  # tiles per camera
    for q in prange(n_chunks):
        c = 0
        for f in range(q * total // n_chunks, (q + 1) * total // n_chunks):
            c = _camera_of(cam_start, f, c)
            j = f - cam_start[c]
            g = order[c, j]
            r0 = box_start[c, j]
            ca, cb, cc = np.float64(conics[c, g, 0]), np.float64(conics[c, g, 1]), np.float64(conics[c, g, 2])
            # an underflowed or needle-thin conic is not trusted: its box's rows are kept
            trusted = ca > 0.0 and cc > 0.0 and ca * cc - cb * cb > _ILL_CONDITIONED * ca * cc
            ell = (
                _ellipse(np.float64(means2d[c, g, 0]), np.float64(means2d[c, g, 1]), ca, cb, cc, smax[g] + _CULL_MARGIN)
                if trusted
                else (0.0,) * 10
            )
            bx0, bx1, by0, by1 = pix_box[c, g, 0], pix_box[c, g, 1], pix_box[c, g, 2], pix_box[c, g, 3]
            tx0, tx1, ty0, ty1 = _tile_range(pix_box, c, g)
            ntx = tx1 - tx0 + 1
            for tx in range(tx0, tx1 + 1):
                for h in range(2):
                    col0 = tx * TILE + h * HALF
                    lo, hi = _band_span(ell, trusted, bx0, bx1, by0, by1, col0, min(col0 + HALF, width) - 1, height)
                    for ty in range(ty0, ty1 + 1):
                        r = r0 + (ty - ty0) * ntx + (tx - tx0)
                        row0 = max(lo, ty * TILE)
                        row1 = min(hi, ty * TILE + TILE - 1)
                        miss = row0 > row1
                        out_rows[r, 2 * h] = 0 if miss else row0 - ty * TILE
                        out_rows[r, 2 * h + 1] = -1 if miss else row1 - ty * TILE
            r = r0
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    if _hits(out_rows, r):
                        counts[q, c * n_tiles + ty * tiles_x + tx] += 1
                    r += 1


@njit(cache=True, inline="always")
def _hits(rows, r):  # does candidate/entry r touch any row of either half?
    return rows[r, 0] <= rows[r, 1] or rows[r, 2] <= rows[r, 3]


def bin_tiles(*args):  # -> tile_start [C * n_tiles + 1] int64, gid [n_isect] int32, rows [n_isect, 4] int8
    """`bin_tiles_indexed` (same arguments) without the index the backward's per-Gaussian sums use."""
    return bin_tiles_indexed(*args)[:3]


def bin_tiles_indexed(
    order,  # [C, N] int64: per camera, Gaussian indices front to back (first n_valid[c] are valid)
    n_valid,  # [C] int64
    pix_box,  # [C, N, 4] int64 inclusive pixel box (x0, x1, y0, y1), inside the image
    means2d,  # [C, N, 2]
    conics,  # [C, N, 3]
    opacities,  # [N]
    width,
    height,
    tiles_x,
    tiles_y,
):  # -> tile_start [C * n_tiles + 1] int64, gid [n_isect] int32, rows [n_isect, 4] int8, cam_start, box_start, ent
    """Lists of the Gaussians meeting each tile, front to back, with the rows of the tile each
    may touch: the tiles of each pixel box, less those its alpha >= ALPHA_MIN ellipse misses
    (gsplat's tile culling), and per kept entry the ellipse's row range inside each half of the
    tile (its left and right HALF columns), counted from the tile's top row.

    Also, for `reduce_grads`: cam_start (where each camera's valid Gaussians start when all
    cameras' are put back to back), box_start (where the candidate tiles of camera c's j-th Gaussian start)
    and ent (each candidate tile's entry in gid, or -1 where culled). The geometry and the counting sort by
    tile both run in parallel over chunks of the Gaussians (per-chunk tile counts keep the front-to-back order)."""
    # alpha >= ALPHA_MIN iff sigma <= smax
    smax = np.log(np.maximum(opacities.astype(np.float64), ALPHA_MIN) / ALPHA_MIN)
    box_start = _box_starts(order, n_valid, pix_box)
    cam_start = np.zeros(n_valid.shape[0] + 1, dtype=np.int64)
    np.cumsum(n_valid, out=cam_start[1:])
    n_chunks = max(1, min(int(cam_start[-1]), _CHUNKS_PER_THREAD * numba.get_num_threads()))
    counts = np.zeros((n_chunks, n_valid.shape[0] * tiles_x * tiles_y), dtype=np.int64)
    cand = np.empty((box_start[-1, -1], 4), dtype=np.int8)  # small: fresh memory costs page faults
    _tile_hits(order, cam_start, means2d, conics, smax, pix_box, width, height, box_start, tiles_x, cand, counts)
    tile_start, gid, rows, ent = _tile_lists(order, cam_start, pix_box, box_start, cand, counts, tiles_x, tiles_y)
    return tile_start, gid, rows, cam_start, box_start, ent


_CHUNKS_PER_THREAD = 4  # binning's chunks of Gaussians per thread (their costs differ: more chunks balance them)


@njit(cache=True)
def _box_starts(order, n_valid, pix_box):  # -> box_start [C, N + 1] int64 (box_start[-1, -1]: the total)
    """Where the candidate tiles of each camera's j-th Gaussian start in one flat array over all cameras."""
    n_cam, n = order.shape
    box_start = np.zeros((n_cam, n + 1), dtype=np.int64)
    total = 0
    for c in range(n_cam):
        for j in range(n_valid[c]):
            tx0, tx1, ty0, ty1 = _tile_range(pix_box, c, order[c, j])
            box_start[c, j] = total
            total += (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
        box_start[c, n_valid[c] :] = total
    return box_start


@njit(cache=True, parallel=True)
def _tile_lists(order, cam_start, pix_box, box_start, cand, counts, tiles_x, tiles_y):  # -> tile_start, gid, rows, ent
    """Counting sort of the kept candidates by tile, keeping each camera's front-to-back order: chunk q of
    the Gaussians writes each tile's entries after those of the chunks before it (chunks in parallel)."""
    n_chunks, n_all = counts.shape
    n_tiles = tiles_x * tiles_y
    tile_start = np.zeros(n_all + 1, dtype=np.int64)
    fill = np.empty((n_chunks, n_all), dtype=np.int64)
    for t in range(n_all):
        f = tile_start[t]
        for q in range(n_chunks):
            fill[q, t] = f
            f += counts[q, t]
        tile_start[t + 1] = f
    gid = np.empty(tile_start[-1], dtype=np.int32)
    rows = np.empty((tile_start[-1], 4), dtype=np.int8)
    ent = np.empty(cand.shape[0], dtype=np.int64)
    total = cam_start[-1]
    for q in prange(n_chunks):
        c = 0
        for f in range(q * total // n_chunks, (q + 1) * total // n_chunks):
            c = _camera_of(cam_start, f, c)
            j = f - cam_start[c]
            g = order[c, j]
            r = box_start[c, j]
            tx0, tx1, ty0, ty1 = _tile_range(pix_box, c, g)
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    if _hits(cand, r):
                        t = c * n_tiles + ty * tiles_x + tx
                        e = fill[q, t]
                        gid[e] = g
                        for i in range(4):
                            rows[e, i] = cand[r, i]
                        fill[q, t] = e + 1
                        ent[r] = e
                    else:
                        ent[r] = -1
                    r += 1
    return tile_start, gid, rows, ent


@njit(cache=True, inline="always")
def _tile_origin(t, tiles_x, n_tiles, width, height):  # -> cam, px0, py0, pw, ph
    cam = t // n_tiles
    tt = t - cam * n_tiles
    ty = tt // tiles_x
    tx = tt - ty * tiles_x
    px0, py0 = tx * TILE, ty * TILE
    return cam, px0, py0, min(TILE, width - px0), min(TILE, height - py0)


@njit(cache=True, inline="always")
def _pixel(lx, ly):  # -> index in a tile's buffers of the pixel at column lx, row ly of the tile
    return (lx >> _HALF_SHIFT) * _HALF_PX + ly * HALF + (lx & (HALF - 1))


@njit(cache=True)
def _pixel_offsets(fdt):  # -> x [TILE * TILE], y [TILE * TILE]: column and row in the tile of buffer index i
    i = np.arange(TILE * TILE)
    return ((i // _HALF_PX) * HALF + (i & (HALF - 1))).astype(fdt), ((i >> _HALF_SHIFT) & (TILE - 1)).astype(fdt)


# Each tile keeps its per-pixel values in one buffer, at fixed offsets, indexed by unsigned integers (_U): LLVM
# then sees every access of a compositing loop at a constant distance from the others and vectorises the loop
# without run-time overlap tests, and numba adds no negative-index fix-up. With one array per value and slices of
# them, each half-tile span began with over a hundred instructions of slicing and overlap tests (the forward's two
# loops take about 70 per vector of 8 pixels, and a span has 7 vectors on average in the target scene).
_U = np.uint64
_NPX = TILE * TILE
# the offsets, globals so that they are constants in the compiled loops (a kernel's locals reach its prange body as
# arguments): forward_tiles' pixel x (at 0), pixel y, alpha then weight, T and the colour channels, backward_tiles'
# pixel x (at 0), pixel y, weight, T, rest, c . v_C, exp(-sigma) and the channels of v_C
_FW_Y, _FW_W, _FW_T, _FW_C = (_U(i * _NPX) for i in range(1, 5))
_BW_Y, _BW_W, _BW_T, _BW_R, _BW_CD, _BW_V, _BW_C = (_U(i * _NPX) for i in range(1, 8))


@njit(cache=True, inline="always")
def _span(h, ya, yb):  # -> (i0, n) uint64: rows ya..yb of half h are buffer indices i0 .. i0 + n - 1
    return _U(h * _HALF_PX + ya * HALF), _U((yb + 1 - ya) * HALF)


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model="numpy")
def forward_tiles(
    means2d,  # [C, N, 2]
    conics,  # [C, N, 3]
    opacities,  # [N]
    colors,  # [C, N, D] per camera, or [1, N, D] shared by every camera
    background,  # [D]
    rows,  # [n_isect, 4] int8: rows of each half tile each entry may touch (from bin_tiles)
    tile_start,  # [C * n_tiles + 1] int64
    gid,  # [n_isect] int32
    width,
    height,
    tiles_x,
    tiles_y,
    out_img,  # [C, H, W, D] written
    out_t,  # [C, H, W] written: final transmittance
    out_last,  # [C, H, W] int32 written: position in the tile's list of the last contributing Gaussian, -1 if none
):
    """Composite every tile front to back, in the float type of the inputs (all of one dtype)."""
    n_tiles = tiles_x * tiles_y
    n_all = tile_start.shape[0] - 1
    d = colors.shape[2]
    npx = TILE * TILE
    fdt = means2d.dtype
    f = fdt.type
    zero, one, half = f(0.0), f(1.0), f(0.5)
    a_max, a_min, t_min, s_clamp = f(ALPHA_MAX), f(ALPHA_MIN), f(T_MIN), f(_SIGMA_CLAMP)
    pix_x, pix_y = _pixel_offsets(fdt)
    for t in prange(n_all):
        cam, px0, py0, pw, ph = _tile_origin(t, tiles_x, n_tiles, width, height)
        ccam = min(cam, colors.shape[0] - 1)  # the camera's colours (0 when shared)
        start, end = tile_start[t], tile_start[t + 1]
        # one buffer (see _U): pixel x and y, alpha then weight of the current entry, T (negated once the pixel is
        # spent, and -1 outside the image: no separate mask), and the d channels of colour
        buf = np.zeros((4 + d) * npx, fdt)
        buf[:_FW_Y] = pix_x
        buf[_FW_Y:_FW_W] = pix_y
        buf[_FW_T:_FW_C] = -one
        for ly in range(ph):
            for lx in range(pw):
                buf[_FW_T + _U(_pixel(lx, ly))] = one
        last = np.full(npx, -1, np.int32)
        n_active = pw * ph
        for k in range(start, end):
            if n_active == 0:
                break
            g = gid[k]
            kk = np.int32(k - start)
            minus1 = np.int32(-1)
            mx = f(means2d[cam, g, 0]) - f(px0) - half  # the centre relative to the tile's first pixel centre
            my = f(means2d[cam, g, 1]) - f(py0) - half
            ca, cb, cc = f(conics[cam, g, 0]), f(conics[cam, g, 1]), f(conics[cam, g, 2])
            ha, hc = half * ca, half * cc
            op = f(opacities[g])
            c0 = f(colors[ccam, g, 0])
            for h in range(2):
                ya, yb = np.int64(rows[k, 2 * h]), np.int64(rows[k, 2 * h + 1])
                if ya > yb:
                    continue
                i0, n = _span(h, ya, yb)
                # alpha first, in a loop of its own (0 where sigma < 0: below ALPHA_MIN), then the compositing:
                # two short loops keep fewer values live than one, and the exp's long chain of dependent
                # instructions overlaps across pixels instead of stalling the compositing's
                for j in range(n):
                    p = i0 + j
                    dx = mx - buf[p]
                    dy = my - buf[p + _FW_Y]
                    sigma = (ha * dx + cb * dy) * dx + hc * dy * dy  # 0.5 (a dx^2 + c dy^2) + b dx dy
                    alpha = min(a_max, op * exp_neg(min(max(sigma, zero), s_clamp)))
                    buf[p + _FW_W] = _select(sigma >= zero, alpha, zero)
                n_stop = zero
                for j in range(n):
                    p = i0 + j
                    alpha = buf[p + _FW_W]
                    tc = buf[p + _FW_T]
                    nt = tc * (one - alpha)
                    ok = (alpha >= a_min) & (tc > zero)
                    stop = ok & (nt <= t_min)
                    con = ok & (nt > t_min)
                    w = alpha * tc if con else zero
                    buf[p + _FW_W] = w
                    buf[p + _FW_C] += w * c0
                    buf[p + _FW_T] = _select(con, nt, _select(stop, -tc, tc))
                    last[p] = max(last[p], _select(con, kk, minus1))  # last[p] < kk: kk where con, else unchanged
                    n_stop += one if stop else zero
                n_active -= np.int64(n_stop)
                for ch in range(1, d):
                    cv = f(colors[ccam, g, ch])
                    b_ch = _FW_C + _U(ch * npx)
                    for j in range(n):
                        p = i0 + j
                        buf[p + b_ch] += buf[p + _FW_W] * cv
        for ly in range(ph):
            for lx in range(pw):
                y, x = py0 + ly, px0 + lx
                i = _pixel(lx, ly)
                tf = abs(buf[_FW_T + _U(i)])
                for ch in range(d):
                    out_img[cam, y, x, ch] = buf[_FW_C + _U(ch * npx + i)] + tf * f(background[ch])
                out_t[cam, y, x] = tf
                out_last[cam, y, x] = last[i]


@njit(cache=True, parallel=True, fastmath=_FASTMATH, error_model="numpy")
def backward_tiles(  # noqa: C901  (one fused numba pass over each tile, for speed)
    means2d,  # [C, N, 2]
    conics,  # [C, N, 3]
    opacities,  # [N]
    colors,  # [C, N, D] per camera, or [1, N, D] shared by every camera
    background,  # [D]
    rows,  # [n_isect, 4] int8: rows of each half tile each entry may touch (from bin_tiles)
    tile_start,  # [C * n_tiles + 1] int64
    gid,  # [n_isect] int32
    width,
    height,
    tiles_x,
    tiles_y,
    t_final,  # [C, H, W] from forward_tiles
    last_idx,  # [C, H, W] int32 from forward_tiles
    v_img,  # [C, H, W, D] cotangent of the images
    v_alpha,  # [C, H, W] cotangent of the alphas
    out_geo,  # [n_isect, 6] written: d/d (mx, my, conic a, b, c, opacity) per list entry
    out_col,  # [n_isect, D] written: d/d colour per list entry
):
    """Walk each tile's list back from its last contributing Gaussian; every entry's row is written."""
    n_tiles = tiles_x * tiles_y
    n_all = tile_start.shape[0] - 1
    d = colors.shape[2]
    npx = TILE * TILE
    fdt = means2d.dtype
    f = fdt.type
    zero, one, half = f(0.0), f(1.0), f(0.5)
    a_max, a_min, s_clamp = f(ALPHA_MAX), f(ALPHA_MIN), f(_SIGMA_CLAMP)
    pix_x, pix_y = _pixel_offsets(fdt)
    for t in prange(n_all):
        start, end = tile_start[t], tile_start[t + 1]
        if end == start:
            continue
        cam, px0, py0, pw, ph = _tile_origin(t, tiles_x, n_tiles, width, height)
        ccam = min(cam, colors.shape[0] - 1)  # the camera's colours (0 when shared)
        # one buffer (see _U): pixel x and y, weight of the current entry, T, rest, c . v_C, exp(-sigma) of the
        # current entry (-1 where sigma < 0), and the d channels of v_C; rest: sum over later Gaussians of
        # (c . v_C) alpha T, plus T_N (bg . v_C) - T_N v_alpha
        buf = np.zeros((7 + d) * npx, fdt)
        buf[:_BW_Y] = pix_x
        buf[_BW_Y:_BW_W] = pix_y
        last = np.full(npx, -1, np.int32)  # pixels outside the image never match
        row_kmax = np.full((2, TILE), -1, np.int64)  # per half row, the last list position any of its pixels uses
        for ly in range(ph):
            for lx in range(pw):
                y, x = py0 + ly, px0 + lx
                i = _pixel(lx, ly)
                tf = f(t_final[cam, y, x])
                buf[_BW_T + _U(i)] = tf
                bgdot = zero
                for ch in range(d):
                    buf[_BW_C + _U(ch * npx + i)] = f(v_img[cam, y, x, ch])
                    bgdot += f(background[ch]) * f(v_img[cam, y, x, ch])
                buf[_BW_R + _U(i)] = tf * bgdot - tf * f(v_alpha[cam, y, x])
                last[i] = last_idx[cam, y, x]
                h = lx >> _HALF_SHIFT
                row_kmax[h, ly] = max(row_kmax[h, ly], np.int64(last[i]))
        kmax = row_kmax.max()
        out_geo[start + kmax + 1 : end] = 0.0  # behind every pixel's last contribution
        out_col[start + kmax + 1 : end] = 0.0
        for kk in range(kmax, -1, -1):
            k = start + kk
            g = gid[k]
            mx = f(means2d[cam, g, 0]) - f(px0) - half
            my = f(means2d[cam, g, 1]) - f(py0) - half
            ca, cb, cc = f(conics[cam, g, 0]), f(conics[cam, g, 1]), f(conics[cam, g, 2])
            ha, hc = half * ca, half * cc
            op = f(opacities[g])
            c0 = f(colors[ccam, g, 0])
            k32 = np.int32(kk)
            # sums of v_sigma times dx, dy, dx^2, dx dy, dy^2: d sigma / d (mx, my, a, b, c) are linear in them
            g_x = zero
            g_y = zero
            g_xx = zero
            g_xy = zero
            g_yy = zero
            g_o = zero
            g_c0 = zero
            n_hit = zero
            for ch in range(d):
                out_col[k, ch] = 0.0
            for h in range(2):
                ya, yb = np.int64(rows[k, 2 * h]), np.int64(rows[k, 2 * h + 1])
                while ya <= yb and row_kmax[h, ya] < kk:  # rows spent before k cost nothing
                    ya += 1
                while yb >= ya and row_kmax[h, yb] < kk:
                    yb -= 1
                if ya > yb:
                    continue
                i0, n = _span(h, ya, yb)
                for j in range(n):  # the exp in a loop of its own, as in forward_tiles
                    p = i0 + j
                    dx = mx - buf[p]
                    dy = my - buf[p + _BW_Y]
                    sigma = (ha * dx + cb * dy) * dx + hc * dy * dy
                    # -1 where sigma < 0: alpha = -op < ALPHA_MIN, as the forward skipped it
                    buf[p + _BW_V] = _select(sigma >= zero, exp_neg(min(max(sigma, zero), s_clamp)), -one)
                if d > 1:  # c . v_C per pixel (inline below when d == 1)
                    for j in range(n):
                        p = i0 + j
                        buf[p + _BW_CD] = c0 * buf[p + _BW_C]
                    for ch in range(1, d):
                        cv = f(colors[ccam, g, ch])
                        b_ch = _BW_C + _U(ch * npx)
                        for j in range(n):
                            p = i0 + j
                            buf[p + _BW_CD] += cv * buf[p + b_ch]
                for j in range(n):
                    p = i0 + j
                    dx = mx - buf[p]
                    dy = my - buf[p + _BW_Y]
                    vis = buf[p + _BW_V]
                    raw = op * vis
                    alpha = min(a_max, raw)
                    ok = (alpha >= a_min) & (k32 <= last[p])
                    ra = one / (one - alpha)
                    tr = buf[p + _BW_T]
                    tb = tr * ra  # T before this Gaussian
                    w = alpha * tb
                    v0 = buf[p + _BW_C]
                    cdj = _select(d > 1, buf[p + _BW_CD], c0 * v0)
                    rs = buf[p + _BW_R]
                    v_al = cdj * tb - rs * ra
                    wv = _select(ok, w, zero)
                    # updates by arithmetic, not `_select(ok, new, old)`: LLVM turns the store of a select of the value
                    # loaded from the same place into a masked store (vmaskmovps), slow on AMD Zen 1-3
                    buf[p + _BW_T] = tr * _select(ok, ra, one)  # tb where ok, else tr (x * 1 is x exactly)
                    buf[p + _BW_R] = rs + cdj * wv  # rs + cdj * w where ok, else rs
                    buf[p + _BW_W] = wv
                    g_c0 += wv * v0
                    gate = ok & (raw < a_max)  # the clamp at ALPHA_MAX passes no gradient
                    v_sig = -raw * v_al if gate else zero
                    g_o += vis * v_al if gate else zero
                    sx = v_sig * dx
                    sy = v_sig * dy
                    g_xx += sx * dx
                    g_xy += sx * dy
                    g_yy += sy * dy
                    g_x += sx
                    g_y += sy
                    n_hit += one if ok else zero
                for ch in range(1, d):
                    b_ch = _BW_C + _U(ch * npx)
                    sc = zero
                    for j in range(n):
                        p = i0 + j
                        sc += buf[p + _BW_W] * buf[p + b_ch]
                    out_col[k, ch] += sc
            out_col[k, 0] = g_c0
            if n_hit > zero:
                out_geo[k, 0] = ca * g_x + cb * g_y
                out_geo[k, 1] = cb * g_x + cc * g_y
                out_geo[k, 2] = half * g_xx
                out_geo[k, 3] = g_xy
                out_geo[k, 4] = half * g_yy
                out_geo[k, 5] = g_o
            else:
                out_geo[k] = 0.0


@njit(cache=True, parallel=True)
def reduce_grads(
    order,  # [C, N] int64 (as given to bin_tiles_indexed)
    cam_start,  # [C + 1] int64 from bin_tiles_indexed
    box_start,  # [C, N + 1] int64 from bin_tiles_indexed
    ent,  # [n_cand] int64 from bin_tiles_indexed: each candidate tile's list entry, -1 where culled
    geo,  # [n_isect, 6]
    col,  # [n_isect, D]
    v_means2d,  # [C, N, 2] written for the valid Gaussians (zeros elsewhere)
    v_conics,  # [C, N, 3] written likewise
    v_opac,  # [C, N] written likewise: per camera, summed over cameras by the caller
    v_colors,  # [C, N, D] zeros, accumulated likewise: per camera, summed over cameras by the caller
):
    """Sum the per-entry gradient rows per Gaussian, the Gaussians in parallel: a Gaussian's entries are its
    kept candidate tiles, found through `ent` in tile order (the order of the lists: the same sums as adding
    the rows in list order)."""
    d = col.shape[1]
    for f in prange(cam_start[-1]):
        c = _camera_of(cam_start, f, 0)
        j = f - cam_start[c]
        g = order[c, j]
        s0, s1, s2, s3, s4, s5 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for r in range(box_start[c, j], box_start[c, j + 1]):
            k = ent[r]
            if k < 0:
                continue
            s0 += geo[k, 0]
            s1 += geo[k, 1]
            s2 += geo[k, 2]
            s3 += geo[k, 3]
            s4 += geo[k, 4]
            s5 += geo[k, 5]
            for ch in range(d):
                v_colors[c, g, ch] += col[k, ch]
        v_means2d[c, g, 0] = s0
        v_means2d[c, g, 1] = s1
        v_conics[c, g, 0] = s2
        v_conics[c, g, 1] = s3
        v_conics[c, g, 2] = s4
        v_opac[c, g] = s5
