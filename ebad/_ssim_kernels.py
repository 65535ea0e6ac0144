"""SSIM and L1 in one fused numba pass, and its adjoint in another: every training loss's image terms.

The five local moments of SSIM (means of a and b, of a^2, b^2 and ab) are a Gaussian window
over the reflect-padded images. The window is separable: along the rows of the padded images
(all five row sums at once), then down the columns, which also forms the SSIM map, its
derivatives with respect to the five moments when a gradient is wanted, and the sums of S and
of |a - b| that the losses need. The backward applies the adjoint of the same two passes to
those derivatives times the upstream gradient (a map, or one constant per image for a mean),
folds the reflect padding back onto the image and adds the L1 term's gradient.

Each kernel is ONE parallel region over bands of rows: waking numba's worker threads costs
about 0.1 ms per region on the 2-core machine on numba's workqueue layer (see
``splat_cpu._numba_impl`` for the layers), about half of what the SSIM of one 173x130 image
costs forward and backward. A forward band recomputes the ``win - 1`` padded rows it shares
with the next one (about a fifth more row sums); the backward's bands share nothing, because
each padded row belongs to one image row. The reflect padding (torch's "reflect": the edge
pixel is not repeated) is an index map, so no padded copy is made.
``ebad.losses`` wraps the kernels in autograd Functions; ``ebad.losses.ssim_map_kornia`` is the
reference they are tested against.

Arrays are [N, H, W] (N = batch x channels) float32 or float64, H and W larger than ``win // 2``,
with ``g`` the window's ``win`` 1-D weights (summing to 1).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

import splat_cpu._numba_impl  # noqa: F401  (chooses numba's threading layer before any kernel here launches)

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # FMA and reassociation; no nan/inf assumptions
C1, C2 = 0.01 ** 2, 0.03 ** 2  # kornia's constants for a data range of 1
DEN_EPS = 1e-12  # kornia's: added to the denominator
BAND = 24  # image rows per task: few enough tasks to start, enough to share 2 threads evenly


def num_tasks(N: int, H: int) -> int:
    """The forward's tasks for [N, H, W] images: the rows of its per-task ``sums``, image by image
    (``sums.reshape(N, -1, 2).sum(1)`` are the images' sums)."""
    return N * (-(-H // BAND))


@njit(cache=True)
def _reflect_map(size, pad):  # pragma: no cover - jit
    """idx[x] for x in [0, size + 2 pad): the image index of padded index x (torch's reflect)."""
    idx = np.empty(size + 2 * pad, np.int64)
    for x in range(size + 2 * pad):
        v = x - pad
        if v < 0:
            v = -v
        elif v >= size:
            v = 2 * (size - 1) - v
        idx[x] = v
    return idx


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_forward(a, b, g, s_map, coef, want_grad, sums):  # pragma: no cover - jit
    """Per task (``num_tasks``), into ``sums`` [tasks, 2]: the sum of the SSIM map and of |a - b|
    over its band. The map into ``s_map`` [N, H, W] unless it is empty; with ``want_grad``,
    dS/d(mu_a, mu_b, s_aa = s_bb, s_ab) into ``coef`` [4, N, H, W] (the raw second moments,
    before subtracting mu^2; S has the same derivative with respect to s_aa and s_bb)."""
    N, H, W = a.shape
    win = g.shape[0]
    pad = win // 2
    Wp = W + 2 * pad
    ridx = _reflect_map(H, pad)
    cidx = _reflect_map(W, pad)
    want_map = s_map.shape[0] > 0
    nb = (H + BAND - 1) // BAND
    for task in prange(N * nb):
        n = task // nb
        i0 = (task % nb) * BAND
        i1 = min(i0 + BAND, H)
        nr = i1 - i0 + win - 1  # the padded rows i0 .. i1 + win - 2 feed output rows i0 .. i1 - 1
        rows = np.empty((5, nr, W), a.dtype)
        xa = np.empty(Wp, a.dtype)
        xb = np.empty(Wp, a.dtype)
        for r in range(nr):  # along each padded row: the five row sums
            src = ridx[i0 + r]
            xa[pad:pad + W] = a[n, src]
            xb[pad:pad + W] = b[n, src]
            for e in range(pad):  # the reflected edges
                xa[e] = a[n, src, cidx[e]]
                xb[e] = b[n, src, cidx[e]]
                xa[W + pad + e] = a[n, src, cidx[W + pad + e]]
                xb[W + pad + e] = b[n, src, cidx[W + pad + e]]
            r0 = rows[0, r]
            r1 = rows[1, r]
            r2 = rows[2, r]
            r3 = rows[3, r]
            r4 = rows[4, r]
            r0[:] = 0.0
            r1[:] = 0.0
            r2[:] = 0.0
            r3[:] = 0.0
            r4[:] = 0.0
            for k in range(win):
                w = g[k]
                for j in range(W):
                    x = xa[j + k]
                    y = xb[j + k]
                    r0[j] += w * x
                    r1[j] += w * y
                    r2[j] += w * x * x
                    r3[j] += w * y * y
                    r4[j] += w * x * y
        m = np.empty((5, W), a.dtype)
        s_sum = 0.0
        l1_sum = 0.0
        for i in range(i0, i1):  # down the columns: the moments, the map and its derivatives
            m[:] = 0.0
            for k in range(win):
                w = g[k]
                for c in range(5):
                    src = rows[c, i - i0 + k]
                    mc = m[c]
                    for j in range(W):
                        mc[j] += w * src[j]
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
                den = b1 * b2 + DEN_EPS
                s = a1 * a2 / den
                s_sum += s
                l1_sum += abs(a[n, i, j] - b[n, i, j])
                if want_map:
                    s_map[n, i, j] = s
                if want_grad:
                    # S = a1 a2 / den: d/dmu1 = (2 mu2 (a2 - a1) - S 2 mu1 (b2 - b1)) / den, and so on
                    coef[0, n, i, j] = (2.0 * mu2 * (a2 - a1) - s * 2.0 * mu1 * (b2 - b1)) / den
                    coef[1, n, i, j] = (2.0 * mu1 * (a2 - a1) - s * 2.0 * mu2 * (b2 - b1)) / den
                    coef[2, n, i, j] = -s * b1 / den  # d/ds_aa and d/ds_bb alike
                    coef[3, n, i, j] = 2.0 * a1 / den
        sums[task, 0] = s_sum
        sums[task, 1] = l1_sum


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_backward(a, b, g, coef, grad_s, gs_const, l1_coef, grad_a, grad_b, want_a, want_b):  # pragma: no cover - jit
    """The gradients of sum(G * S) + sum_n l1_coef[n] * sum(|a_n - b_n|) with respect to ``a`` and
    ``b``, into ``grad_a`` and ``grad_b`` [N, H, W] (each written when wanted), with G the map
    ``grad_s`` [N, H, W], or, when ``grad_s`` is empty, ``gs_const[n]`` [N] over all of image n."""
    _, N, H, W = coef.shape
    win = g.shape[0]
    pad = win // 2
    Wp = W + 2 * pad
    cidx = _reflect_map(W, pad)
    const = grad_s.shape[0] == 0
    nb = (H + BAND - 1) // BAND
    # constants (and gs_const, l1_coef) in the images' dtype: a float64 factor makes numba compute
    # a float32 loop in float64 (it promotes float32 x float64), which made this backward 1.5x
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
        cols = np.empty((4, W), a.dtype)  # adjoint of the column pass, on one padded row
        t = np.empty((4, Wp), a.dtype)  # adjoint of the row pass, on that row
        ga = np.empty(W, a.dtype)
        gb = np.empty(W, a.dtype)
        for i in range(i0, i1):
            ga[:] = 0.0
            gb[:] = 0.0
            for side in range(3):  # the padded rows that reflect onto image row i: itself, above, below
                if side == 0:
                    q = i + pad
                elif side == 1:
                    if i < 1 or i > pad:
                        continue
                    q = pad - i
                else:
                    if i > H - 2 or i < H - 1 - pad:
                        continue
                    q = pad + 2 * (H - 1) - i
                cols[:] = 0.0
                for k in range(win):
                    ii = q - k
                    if ii < 0 or ii >= H:
                        continue
                    w = g[k]
                    for c in range(4):
                        if (c == 0 and not want_a) or (c == 1 and not want_b):
                            continue
                        src = coef[c, n, ii]
                        dst = cols[c]
                        if const:
                            wg = w * gs_const[n]
                            for j in range(W):
                                dst[j] += wg * src[j]
                        else:
                            gs = grad_s[n, ii]
                            for j in range(W):
                                dst[j] += w * gs[j] * src[j]
                t[:] = 0.0
                for k in range(win):
                    w = g[k]
                    for c in range(4):
                        src = cols[c]
                        tc = t[c]
                        for j in range(W):
                            tc[j + k] += w * src[j]
                # the product rule onto a and b, folded back onto the image: the inside, then the
                # reflected edges (x < pad and x >= W + pad)
                ar = a[n, i]
                br = b[n, i]
                if want_a:
                    for j in range(W):
                        ga[j] += t[0, j + pad] + two * ar[j] * t[2, j + pad] + br[j] * t[3, j + pad]
                if want_b:
                    for j in range(W):
                        gb[j] += t[1, j + pad] + two * br[j] * t[2, j + pad] + ar[j] * t[3, j + pad]
                for e in range(2 * pad):
                    x = e if e < pad else W + e
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
