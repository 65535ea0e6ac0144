"""SSIM in two fused numba passes, and its adjoint: the SSIM term of every training loss.

The five local moments of SSIM (means of a and b, of a^2, b^2 and ab) are a Gaussian window
over the reflect-padded images. The window is separable, so the forward is one pass along the
rows of the padded images (all five row sums at once) and one pass down the columns, which
also forms the SSIM map and, when a gradient is wanted, its derivatives with respect to the
five moments. The backward applies the adjoint of the same two passes to those derivatives
times the upstream gradient and gathers them onto the padded inputs (the reflect padding's own
adjoint is torch's). ``ebad.losses.ssim_map`` wraps them in an autograd Function;
``ebad.losses.ssim_map_kornia`` is the reference they are tested against.

Arrays are [N, H, W] (N = batch x channels) float32 or float64; the padded inputs are
[N, H + 2p, W + 2p] for a window of 2p + 1 taps ``g`` (its 1-D weights, summing to 1).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # FMA and reassociation; no nan/inf assumptions
C1, C2 = 0.01 ** 2, 0.03 ** 2  # kornia's constants for a data range of 1
DEN_EPS = 1e-12  # kornia's: added to the denominator


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_forward(ap, bp, g, s_map, coef, want_grad):  # pragma: no cover - jit
    """SSIM map into ``s_map`` [N, H, W]; with ``want_grad``, dS/d(mu_a, mu_b, s_aa = s_bb, s_ab)
    into ``coef`` [4, N, H, W] (the moments' raw second moments, before subtracting mu^2; S has
    the same derivative with respect to s_aa and s_bb, so one plane serves both)."""
    N, H, W = s_map.shape
    win = g.shape[0]
    Hp = H + win - 1
    rows = np.empty((5, N, Hp, W), ap.dtype)
    for r in prange(N * Hp):  # along each padded row: the five row sums
        n = r // Hp
        q = r % Hp
        r0 = rows[0, n, q]
        r1 = rows[1, n, q]
        r2 = rows[2, n, q]
        r3 = rows[3, n, q]
        r4 = rows[4, n, q]
        r0[:] = 0.0
        r1[:] = 0.0
        r2[:] = 0.0
        r3[:] = 0.0
        r4[:] = 0.0
        for k in range(win):
            w = g[k]
            for j in range(W):
                x = ap[n, q, j + k]
                y = bp[n, q, j + k]
                r0[j] += w * x
                r1[j] += w * y
                r2[j] += w * x * x
                r3[j] += w * y * y
                r4[j] += w * x * y
    for r in prange(N * H):  # down the columns: the moments, the map and its derivatives
        n = r // H
        i = r % H
        m = np.zeros((5, W), ap.dtype)
        for k in range(win):
            w = g[k]
            for c in range(5):
                src = rows[c, n, i + k]
                mc = m[c]
                for j in range(W):
                    mc[j] += w * src[j]
        for j in range(W):
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
            s_map[n, i, j] = s
            if want_grad:
                # S = a1 a2 / den: d/dmu1 = (2 mu2 (a2 - a1) - S 2 mu1 (b2 - b1)) / den, and so on
                coef[0, n, i, j] = (2.0 * mu2 * (a2 - a1) - s * 2.0 * mu1 * (b2 - b1)) / den
                coef[1, n, i, j] = (2.0 * mu1 * (a2 - a1) - s * 2.0 * mu2 * (b2 - b1)) / den
                coef[2, n, i, j] = -s * b1 / den  # d/ds_aa and d/ds_bb alike
                coef[3, n, i, j] = 2.0 * a1 / den


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def ssim_backward(ap, bp, g, coef, grad_s, grad_ap, grad_bp, want_a, want_b):  # pragma: no cover - jit
    """The gradients of sum(grad_s * S) with respect to the padded inputs: ``grad_ap``,
    ``grad_bp`` [N, H + 2p, W + 2p] (each written when wanted)."""
    _, N, H, W = coef.shape
    win = g.shape[0]
    Hp = H + win - 1
    Wp = W + win - 1
    # coef's planes: mu_a (0), mu_b (1), s_aa and s_bb (2, the same derivative), s_ab (3);
    # a needs 0, 2 and 3, b needs 1, 2 and 3
    cols = np.zeros((4, N, Hp, W), ap.dtype)  # adjoint of the column pass, on the padded rows
    for r in prange(N * Hp):
        n = r // Hp
        q = r % Hp
        for k in range(win):
            i = q - k
            if i < 0 or i >= H:
                continue
            w = g[k]
            gs = grad_s[n, i]
            for c in range(4):
                if (c == 0 and not want_a) or (c == 1 and not want_b):
                    continue
                src = coef[c, n, i]
                dst = cols[c, n, q]
                for j in range(W):
                    dst[j] += w * gs[j] * src[j]
    for r in prange(N * Hp):  # adjoint of the row pass, and the product rule onto a and b
        n = r // Hp
        q = r % Hp
        t = np.zeros((4, Wp), ap.dtype)
        for k in range(win):
            w = g[k]
            for c in range(4):
                src = cols[c, n, q]
                tc = t[c]
                for j in range(W):
                    tc[j + k] += w * src[j]
        for x in range(Wp):
            av = ap[n, q, x]
            bv = bp[n, q, x]
            if want_a:
                grad_ap[n, q, x] = t[0, x] + 2.0 * av * t[2, x] + bv * t[3, x]
            if want_b:
                grad_bp[n, q, x] = t[1, x] + 2.0 * bv * t[2, x] + av * t[3, x]


def gauss_taps(win: int, sigma: float = 1.5) -> np.ndarray:
    """The 1-D Gaussian window of ``win`` taps (kornia's: sigma 1.5, normalised)."""
    x = np.arange(win, dtype=np.float64) - (win - 1) / 2
    g = np.exp(-(x * x) / (2 * sigma * sigma))
    return g / g.sum()
