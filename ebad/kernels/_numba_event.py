"""L_ev in one numba pass, and its gradient in another (``ebad.losses.event_loss``).

At every pixel, the V log luminances l_k = log(max(L_k, 0) + eps) of consecutive virtual
instants and the ON / OFF counts between them give the V - 1 residuals
r_k = l_{k+1} - l_k - (c_pos N_on,k - c_neg N_off,k); the loss is the mean of |r| (l1) or of
r^2 (l2) over windows and pixels. The logs are numpy's (vectorised; numba's are scalar here);
the forward sums the loss, keeps g = d|r|/dr = sign(r) (or 2 r) per window and pixel, and sums
it against the counts for the thresholds' gradients; the backward turns it into the gradient
of every L_k: (g_{k-1} - g_k) / (L_k + eps), zero where L_k < 0 (the clamp).

Written as torch operations, the loss took a dozen full-image temporaries and their autograd.
With a colour DAVIS's filter (``ebad.losses.cfa_weights`` F) the log signal is
l_k = sum_d F_d log(max(X_k,d, 0) + eps) of the colour renders X, computed before ``event_forward``,
and ``event_backward`` gives the gradient of every X_k,d (grey: one channel, F_d = 1).

Here each direction is one parallel region over bands of rows. Arrays are float32 or float64:
L [V, H, W] (renders [V, H, W, D] in the backward), counts [V - 1, 2, H, W]. ``ebad.kernels.losses``
wraps the kernels in an autograd Function; ``ebad.losses.event_loss``'s torch code is the reference
they are tested against.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}  # vectorised sums and divisions; no nan/inf assumptions
BAND = 16  # image rows per task


def num_tasks(H: int) -> int:
    """The forward's tasks (rows of its ``sums``) for images of H rows."""
    return -(-H // BAND)


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def event_forward(log_L, counts, c_pos, c_neg, l2, g, sums):  # pragma: no cover - jit
    """Per task, into ``sums`` [tasks, 3]: the sum of |r| (or r^2 when ``l2``), of g N_on and of
    g N_off over its band, with g = dloss/dr before the mean (sign r, or 2 r) written to ``g``
    [V - 1, H, W]; ``log_L`` [V, H, W] are the log luminances."""
    V, H, W = log_L.shape
    for task in prange((H + BAND - 1) // BAND):
        y0 = task * BAND
        y1 = min(y0 + BAND, H)
        s = 0.0
        s_on = 0.0
        s_off = 0.0
        for k in range(V - 1):
            for y in range(y0, y1):
                for x in range(W):
                    on = counts[k, 0, y, x]
                    off = counts[k, 1, y, x]
                    r = log_L[k + 1, y, x] - log_L[k, y, x] - (c_pos * on - c_neg * off)
                    if l2:
                        s += r * r
                        gr = 2.0 * r
                    else:
                        s += abs(r)
                        gr = np.sign(r)
                    g[k, y, x] = gr
                    s_on += gr * on
                    s_off += gr * off
        sums[task, 0] = s
        sums[task, 1] = s_on
        sums[task, 2] = s_off


@njit(cache=True, inline="always")
def _g_diff(g, k, V, y, x):  # pragma: no cover - jit
    """g_{k-1} - g_k at pixel (y, x): the summed loss's gradient with respect to the log signal l_k."""
    d = 0.0
    if k > 0:
        d += g[k - 1, y, x]
    if k < V - 1:
        d -= g[k, y, x]
    return d


@njit(cache=True, parallel=True, fastmath=_FASTMATH)
def event_backward(X, F, g, scale, eps, grad_X):  # pragma: no cover - jit
    """``grad_X`` [V, H, W, D]: ``scale`` (the upstream gradient over the mean's count) times the
    gradient of the summed loss with respect to the renders X [V, H, W, D], from ``event_forward``'s
    ``g``. A colour DAVIS's log signal is l_k = sum_d F_d log(max(X_k,d, 0) + eps) with the channel
    fractions F [H, W, D] (``ebad.losses.cfa_weights``): scale (g_{k-1} - g_k) F_d / (X_k,d + eps),
    zero where X_k,d < 0. Grey luminances are X [V, H, W, 1] with an empty F [0, 0, 0] (F_d = 1):
    one kernel, one compilation per dtype, for both; the grey rows run a loop of their own (one
    channel, no fractions), as fast as a kernel for grey alone."""
    V, H, W, D = X.shape
    grey = F.size == 0 and D == 1
    for task in prange((H + BAND - 1) // BAND):
        y0 = task * BAND
        y1 = min(y0 + BAND, H)
        for k in range(V):
            for y in range(y0, y1):
                if grey:
                    for x in range(W):
                        d = _g_diff(g, k, V, y, x)
                        v = X[k, y, x, 0]
                        grad_X[k, y, x, 0] = scale * d / (v + eps) if v >= 0 else 0.0
                else:
                    for x in range(W):
                        d = _g_diff(g, k, V, y, x)
                        for ch in range(D):
                            v = X[k, y, x, ch]
                            grad_X[k, y, x, ch] = scale * d * F[y, x, ch] / (v + eps) if v >= 0 else 0.0
