"""SSIM and L1 in one fused numba pass, and its adjoint in another: every training loss's image terms.

The five local moments of SSIM (means of a and b, of a^2, b^2 and ab) are a Gaussian window
over the reflect-padded images. The window is separable: along the rows of the padded images
(all five row sums at once), then down the columns, which also forms the SSIM map, its
derivatives with respect to the five moments when a gradient is wanted, and the sums of S and
of |a - b| that the losses need. The backward applies the adjoint of the same two passes to
those derivatives times the upstream gradient (a map, or one constant per image for a mean),
folds the reflect padding back onto the image and adds the L1 term's gradient.

Each kernel is ONE parallel region over bands of rows: waking numba's worker threads costs as
much as a good part of a small image's SSIM (see ``splat_cpu._numba_impl`` for the layers, and
docs/results.md for the figures). A forward band recomputes the ``win - 1`` padded rows it shares
with the next one (about a fifth more row sums); the backward's bands share nothing, because
each padded row belongs to one image row. The reflect padding (torch's "reflect": the edge
pixel is not repeated) is an index map, so no padded copy is made.

The window's loops take seven taps at a time, written out (``TAPS``, ``window_taps``: a window of
other sizes is centred in a multiple of seven taps, zeros around it), and every pixel loop indexes
from its own counter, so that numba's loops over a row vectorise: each tap of a loop over taps
had loaded and stored every row sum again, and an index below the loop counter kept its negative-
index check (measured: docs/results.md, "Figures quoted in the code").
``ebad.kernels.losses`` wraps the kernels in autograd Functions; ``ebad.losses.ssim_map_kornia`` is the
reference they are tested against.

Arrays are [N, H, W] (N = batch x channels) float32 or float64, H and W larger than ``win // 2``,
with ``g`` the window's ``win`` 1-D weights (summing to 1).
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # FMA and reassociation; no nan/inf assumptions
C1, C2 = 0.01**2, 0.03**2  # kornia's constants for a data range of 1
DEN_EPS = 1e-12  # kornia's: added to the denominator
BAND = 24  # image rows per task: few enough tasks to start, enough to share 2 threads evenly
TAPS = 7  # taps the kernels' window loops take at a time, written out (``window_taps``)


def num_tasks(N: int, H: int) -> int:
    """The forward's tasks for [N, H, W] images: the rows of its per-task ``sums``, image by image
    (``sums.reshape(N, -1, 2).sum(1)`` are the images' sums)."""
    return N * (-(-H // BAND))


@njit(cache=True)
def _reflect_map(size, left, right):  # pragma: no cover - jit
    """idx[x] for x in [0, size + left + right): the image index of padded index x (torch's reflect
    within ``win // 2`` of the edge; clamped further out, where the zero taps of ``window_taps``
    padding make the value irrelevant)."""
    idx = np.empty(size + left + right, np.int64)
    for x in range(size + left + right):
        v = x - left
        if v < 0:
            v = -v
        if v >= size:
            v = 2 * (size - 1) - v
        idx[x] = min(max(v, 0), size - 1)
    return idx


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_forward(a, b, g, s_map, coef, want_grad, sums):  # pragma: no cover - jit
    """Per task (``num_tasks``), into ``sums`` [tasks, 2]: the sum of the SSIM map and of |a - b|
    over its band. The map into ``s_map`` [N, H, W] unless it is empty; with ``want_grad``,
    dS/d(mu_a, mu_b, s_aa = s_bb, s_ab) into ``coef`` [4, N, H, W] (the raw second moments,
    before subtracting mu^2; S has the same derivative with respect to s_aa and s_bb). ``g``: the
    window's taps as ``window_taps`` gives them (a multiple of ``TAPS``, each block of seven
    written out so that the loop over a row's pixels vectorises)."""
    N, H, W = a.shape
    T = g.shape[0]
    left = T // 2
    right = T - 1 - left
    Wp = W + T - 1
    ridx = _reflect_map(H, left, right)
    cidx = _reflect_map(W, left, right)
    want_map = s_map.shape[0] > 0
    nb = (H + BAND - 1) // BAND
    for task in prange(N * nb):
        n = task // nb
        i0 = (task % nb) * BAND
        i1 = min(i0 + BAND, H)
        nr = i1 - i0 + T - 1  # the padded rows i0 .. i1 + T - 2 feed output rows i0 .. i1 - 1
        rows = np.empty((5, nr, W), a.dtype)
        xa = np.empty(Wp, a.dtype)
        xb = np.empty(Wp, a.dtype)
        for r in range(nr):  # along each padded row: the five row sums
            src = ridx[i0 + r]
            xa[left : left + W] = a[n, src]
            xb[left : left + W] = b[n, src]
            for e in range(left):  # the reflected edges
                xa[e] = a[n, src, cidx[e]]
                xb[e] = b[n, src, cidx[e]]
            for e in range(W + left, Wp):
                xa[e] = a[n, src, cidx[e]]
                xb[e] = b[n, src, cidx[e]]
            r0 = rows[0, r]
            r1 = rows[1, r]
            r2 = rows[2, r]
            r3 = rows[3, r]
            r4 = rows[4, r]
            rows[:, r] = 0.0
            for blk in range(T // TAPS):
                o = blk * TAPS
                g0, g1, g2, g3, g4, g5, g6 = g[o], g[o + 1], g[o + 2], g[o + 3], g[o + 4], g[o + 5], g[o + 6]
                for j in range(W):
                    x0, x1, x2, x3, x4, x5, x6 = (
                        xa[o + j],
                        xa[o + j + 1],
                        xa[o + j + 2],
                        xa[o + j + 3],
                        xa[o + j + 4],
                        xa[o + j + 5],
                        xa[o + j + 6],
                    )
                    y0, y1, y2, y3, y4, y5, y6 = (
                        xb[o + j],
                        xb[o + j + 1],
                        xb[o + j + 2],
                        xb[o + j + 3],
                        xb[o + j + 4],
                        xb[o + j + 5],
                        xb[o + j + 6],
                    )
                    v0 = g0 * x0 + g1 * x1 + g2 * x2 + g3 * x3 + g4 * x4 + g5 * x5 + g6 * x6
                    v1 = g0 * y0 + g1 * y1 + g2 * y2 + g3 * y3 + g4 * y4 + g5 * y5 + g6 * y6
                    v2 = (
                        g0 * x0 * x0
                        + g1 * x1 * x1
                        + g2 * x2 * x2
                        + g3 * x3 * x3
                        + g4 * x4 * x4
                        + g5 * x5 * x5
                        + g6 * x6 * x6
                    )
                    v3 = (
                        g0 * y0 * y0
                        + g1 * y1 * y1
                        + g2 * y2 * y2
                        + g3 * y3 * y3
                        + g4 * y4 * y4
                        + g5 * y5 * y5
                        + g6 * y6 * y6
                    )
                    v4 = (
                        g0 * x0 * y0
                        + g1 * x1 * y1
                        + g2 * x2 * y2
                        + g3 * x3 * y3
                        + g4 * x4 * y4
                        + g5 * x5 * y5
                        + g6 * x6 * y6
                    )
                    r0[j] += v0
                    r1[j] += v1
                    r2[j] += v2
                    r3[j] += v3
                    r4[j] += v4
        m = np.empty((5, W), a.dtype)
        s_sum = 0.0
        l1_sum = 0.0
        for i in range(i0, i1):  # down the columns: the moments, the map and its derivatives
            ii = i - i0
            m[:] = 0.0
            for c in range(5):
                mc = m[c]
                for blk in range(T // TAPS):
                    o = ii + blk * TAPS
                    g0, g1, g2, g3 = g[blk * TAPS], g[blk * TAPS + 1], g[blk * TAPS + 2], g[blk * TAPS + 3]
                    g4, g5, g6 = g[blk * TAPS + 4], g[blk * TAPS + 5], g[blk * TAPS + 6]
                    q0, q1, q2, q3 = rows[c, o], rows[c, o + 1], rows[c, o + 2], rows[c, o + 3]
                    q4, q5, q6 = rows[c, o + 4], rows[c, o + 5], rows[c, o + 6]
                    for j in range(W):
                        mc[j] += (
                            g0 * q0[j] + g1 * q1[j] + g2 * q2[j] + g3 * q3[j] + g4 * q4[j] + g5 * q5[j] + g6 * q6[j]
                        )
            for j in range(W):
                # from here on in float64 on purpose (C1, C2 and 2.0 are Python floats): the variances are
                # differences of raw moments, which lose digits in float32 (SSIM of two equal flat images
                # read 1 + 3e-5)
                mu1 = m[0, j]
                mu2 = m[1, j]
                mu11 = mu1 * mu1
                mu22 = mu2 * mu2
                mu12 = mu1 * mu2
                a1 = 2.0 * mu12 + C1
                a2 = 2.0 * (m[4, j] - mu12) + C2
                b1 = mu11 + mu22 + C1
                b2 = (m[2, j] - mu11) + (m[3, j] - mu22) + C2
                inv = 1.0 / (b1 * b2 + DEN_EPS)
                s = a1 * a2 * inv
                s_sum += s
                l1_sum += abs(a[n, i, j] - b[n, i, j])
                if want_map:
                    s_map[n, i, j] = s
                if want_grad:
                    # S = a1 a2 / den: d/dmu1 = (2 mu2 (a2 - a1) - S 2 mu1 (b2 - b1)) / den, and so on
                    coef[0, n, i, j] = (2.0 * mu2 * (a2 - a1) - s * 2.0 * mu1 * (b2 - b1)) * inv
                    coef[1, n, i, j] = (2.0 * mu1 * (a2 - a1) - s * 2.0 * mu2 * (b2 - b1)) * inv
                    coef[2, n, i, j] = -s * b1 * inv  # d/ds_aa and d/ds_bb alike
                    coef[3, n, i, j] = 2.0 * a1 * inv
        sums[task, 0] = s_sum
        sums[task, 1] = l1_sum


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_backward(a, b, g, coef, grad_s, gs_const, l1_coef, grad_a, grad_b, want_a, want_b):  # noqa: C901  # pragma: no cover - jit (one fused numba pass, for speed)
    """The gradients of sum(G * S) + sum_n l1_coef[n] * sum(|a_n - b_n|) with respect to ``a`` and
    ``b``, into ``grad_a`` and ``grad_b`` [N, H, W] (each written when wanted), with G the map
    ``grad_s`` [N, H, W], or, when ``grad_s`` is empty, ``gs_const[n]`` [N] over all of image n.
    ``g`` as ``ssim_forward``'s."""
    _, N, H, W = coef.shape
    T = g.shape[0]
    left = T // 2
    right = T - 1 - left
    Wp = W + T - 1
    cidx = _reflect_map(W, left, right)
    const = grad_s.shape[0] == 0
    nb = (H + BAND - 1) // BAND
    # constants (and gs_const, l1_coef) in the images' dtype: a float64 factor makes numba compute
    # a float32 loop in float64 (it promotes float32 x float64), which made this backward markedly
    # slower (the forward's per-pixel map is float64 on purpose: see there)
    two = a.dtype.type(2.0)
    one = a.dtype.type(1.0)
    zero = a.dtype.type(0.0)
    # coef's planes: mu_a (0), mu_b (1), s_aa and s_bb (2, the same derivative), s_ab (3);
    # a needs 0, 2 and 3, b needs 1, 2 and 3
    for task in prange(N * nb):
        n = task // nb
        i0 = (task % nb) * BAND
        i1 = min(i0 + BAND, H)
        # the adjoint of the column pass on one padded row, with T - 1 zeros on each side so that
        # the adjoint of the row pass gathers T taps at every padded column
        cols = np.zeros((4, W + 2 * (T - 1)), a.dtype)
        t = np.empty((4, Wp), a.dtype)  # adjoint of the row pass, on that row
        gw = np.empty(T, a.dtype)  # the taps of the output rows that exist (0 elsewhere)
        gr = np.empty(T, np.int64)  # their rows (clamped where the tap is 0)
        ga = np.empty(W, a.dtype)
        gb = np.empty(W, a.dtype)
        for i in range(i0, i1):
            ga[:] = 0.0
            gb[:] = 0.0
            for side in range(3):  # the padded rows that reflect onto image row i: itself, above, below
                if side == 0:
                    q = i + left
                elif side == 1:
                    if i < 1 or i > left:
                        continue
                    q = left - i
                else:
                    if i > H - 2 or i < H - 1 - right:
                        continue
                    q = left + 2 * (H - 1) - i
                for k in range(T):  # output row q - k takes tap k of padded row q
                    ii = q - k
                    gw[k] = g[k] if 0 <= ii < H else zero
                    gr[k] = min(max(ii, 0), H - 1)
                for c in range(4):
                    if (c == 0 and not want_a) or (c == 1 and not want_b):
                        continue
                    dst = cols[c, T - 1 : T - 1 + W]
                    dst[:] = 0.0
                    for blk in range(T // TAPS):
                        o = blk * TAPS
                        w0, w1, w2, w3, w4, w5, w6 = (
                            gw[o],
                            gw[o + 1],
                            gw[o + 2],
                            gw[o + 3],
                            gw[o + 4],
                            gw[o + 5],
                            gw[o + 6],
                        )
                        p0, p1, p2, p3 = (
                            coef[c, n, gr[o]],
                            coef[c, n, gr[o + 1]],
                            coef[c, n, gr[o + 2]],
                            coef[c, n, gr[o + 3]],
                        )
                        p4, p5, p6 = coef[c, n, gr[o + 4]], coef[c, n, gr[o + 5]], coef[c, n, gr[o + 6]]
                        if const:
                            G = gs_const[n]
                            w0, w1, w2, w3, w4, w5, w6 = G * w0, G * w1, G * w2, G * w3, G * w4, G * w5, G * w6
                            for j in range(W):
                                dst[j] += (
                                    w0 * p0[j]
                                    + w1 * p1[j]
                                    + w2 * p2[j]
                                    + w3 * p3[j]
                                    + w4 * p4[j]
                                    + w5 * p5[j]
                                    + w6 * p6[j]
                                )
                        else:
                            s0, s1, s2, s3 = (
                                grad_s[n, gr[o]],
                                grad_s[n, gr[o + 1]],
                                grad_s[n, gr[o + 2]],
                                grad_s[n, gr[o + 3]],
                            )
                            s4, s5, s6 = grad_s[n, gr[o + 4]], grad_s[n, gr[o + 5]], grad_s[n, gr[o + 6]]
                            for j in range(W):
                                dst[j] += (
                                    w0 * s0[j] * p0[j]
                                    + w1 * s1[j] * p1[j]
                                    + w2 * s2[j] * p2[j]
                                    + w3 * s3[j] * p3[j]
                                    + w4 * s4[j] * p4[j]
                                    + w5 * s5[j] * p5[j]
                                    + w6 * s6[j] * p6[j]
                                )
                    # the adjoint of the row pass: padded column x gathers tap k from column x - k
                    src = cols[c]
                    tc = t[c]
                    tc[:] = 0.0
                    for blk in range(T // TAPS):
                        o = blk * TAPS
                        g0, g1, g2, g3, g4, g5, g6 = g[o], g[o + 1], g[o + 2], g[o + 3], g[o + 4], g[o + 5], g[o + 6]
                        # column x - k of the adjoint sits at T - 1 + x - k in src: for k = o + 6 .. o that
                        # is sv[x] .. sv[x + 6] (offsets from the loop's own index: no negative-index
                        # checks in the loop, which then vectorises)
                        sv = src[T - 1 - o - 6 :]
                        for x in range(Wp):
                            tc[x] += (
                                g6 * sv[x]
                                + g5 * sv[x + 1]
                                + g4 * sv[x + 2]
                                + g3 * sv[x + 3]
                                + g2 * sv[x + 4]
                                + g1 * sv[x + 5]
                                + g0 * sv[x + 6]
                            )
                # the product rule onto a and b, folded back onto the image: the inside, then the
                # reflected edges (x < left and x >= W + left)
                ar = a[n, i]
                br = b[n, i]
                if want_a:
                    for j in range(W):
                        ga[j] += t[0, j + left] + two * ar[j] * t[2, j + left] + br[j] * t[3, j + left]
                if want_b:
                    for j in range(W):
                        gb[j] += t[1, j + left] + two * br[j] * t[2, j + left] + ar[j] * t[3, j + left]
                for x in range(Wp):
                    if left <= x < W + left:
                        continue
                    col = cidx[x]
                    if want_a:
                        ga[col] += t[0, x] + two * ar[col] * t[2, x] + br[col] * t[3, x]
                    if want_b:
                        gb[col] += t[1, x] + two * br[col] * t[2, x] + ar[col] * t[3, x]
            lc = l1_coef[n]
            if lc != 0.0:
                for j in range(W):
                    d = a[n, i, j] - b[n, i, j]
                    sg = one if d > 0 else (-one if d < 0 else zero)
                    ga[j] += lc * sg
                    gb[j] -= lc * sg
            if want_a:
                grad_a[n, i, :] = ga
            if want_b:
                grad_b[n, i, :] = gb


def gauss_taps(win: int, sigma: float = 1.5) -> np.ndarray:
    """The 1-D Gaussian window of ``win`` taps (kornia's: sigma 1.5, normalised)."""
    x = np.arange(win, dtype=np.float64) - (win - 1) / 2
    g = np.exp(-(x * x) / (2 * sigma * sigma))
    return g / g.sum()


@functools.cache
def window_taps(win: int) -> np.ndarray:
    """``gauss_taps(win)`` centred in a multiple of ``TAPS`` taps, zeros around it: what the kernels
    take (seven taps, the default window, have no zeros; five become 0, g0 .. g4, 0). Computed once
    per window (every loss call asks), read-only."""
    T = TAPS * -(-win // TAPS)
    out = np.zeros(T)
    lo = T // 2 - win // 2
    out[lo : lo + win] = gauss_taps(win)
    out.setflags(write=False)
    return out
