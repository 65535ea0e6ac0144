"""The per-event passes behind EDI, in two implementations tested against each other.

``edi_pass`` (numba, the fast path) and ``edi_pass_reference`` (plain numpy, float64,
per pixel, obviously correct) compute, for one exposure [T0, T1] and F instants f_k:

    logmean[px] = log( (1/T) * integral_{T0}^{T1} exp(E_px(t)) dt )      # [H*W]
    Ef[k, px]   = E_px(f_k)                                              # [F, H*W]

where E_px(t) is the sum of the increments (c_pos for p = +1, -c_neg for p = -1) of the
events at pixel px with T0 <= t_i < t (piecewise constant, so the integral is an exact
sum over the inter-event intervals). The running integral is kept as a log-sum-exp pair
(m, s) in float64, so 10^4 events at one pixel with c = 1 cannot overflow.

``edi_pass_binned`` is the naive time-binned version (E sampled at bin centres) used as a
check that the exact sum is the limit of fine binning, and as the benchmark baseline.
"""
from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _edi_pass_numba(t, x, y, p, width, npix, t0_us, t1_us, inst_us, c_pos, c_neg):  # pragma: no cover - jit
    n_inst = inst_us.shape[0]
    E = np.zeros(npix, np.float64)
    last = np.full(npix, t0_us, np.float64)
    # running max exponent; it starts at -inf (no interval yet), not at 0: with E far below 0
    # from the first interval on (800 negative events at t0, c = 1), a start at 0 would
    # make every dt * exp(E - 0) underflow to 0
    m = np.full(npix, -np.inf)
    s = np.zeros(npix, np.float64)  # running sum of dt * exp(E - m)
    Ef = np.zeros((n_inst, npix), np.float64)
    k = 0
    M = t.shape[0]
    for i in range(M):
        ti = np.float64(t[i])
        while k < n_inst and inst_us[k] <= ti:
            Ef[k, :] = E
            k += 1
        px = np.int64(y[i]) * width + np.int64(x[i])
        e = E[px]
        dt = ti - last[px]
        if dt > 0.0:
            mp = m[px]
            if e > mp:
                s[px] = s[px] * np.exp(mp - e) + dt
                m[px] = e
            else:
                s[px] += dt * np.exp(e - mp)
        last[px] = ti
        if p[i] > 0:
            E[px] = e + c_pos
        else:
            E[px] = e - c_neg
    while k < n_inst:
        Ef[k, :] = E
        k += 1
    T = t1_us - t0_us
    logmean = np.empty(npix, np.float64)
    for px in range(npix):
        e = E[px]
        dt = t1_us - last[px]
        mp = m[px]
        sp = s[px]
        if dt > 0.0:
            if e > mp:
                sp = sp * np.exp(mp - e) + dt
                mp = e
            else:
                sp += dt * np.exp(e - mp)
        logmean[px] = mp + np.log(sp / T)
    return logmean, Ef


def edi_pass(
    t: np.ndarray,  # [M] int64 us, sorted, all in [t0_us, t1_us)
    x: np.ndarray,  # [M] int32
    y: np.ndarray,  # [M] int32
    p: np.ndarray,  # [M] int8 in {-1, +1}
    width: int,
    height: int,
    t0_us: float,
    t1_us: float,
    inst_us: np.ndarray,  # [F] float64, sorted
    c_pos: float,
    c_neg: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Fast path: returns (logmean [H*W], Ef [F, H*W]) in float64; see the module docstring."""
    assert t1_us > t0_us
    return _edi_pass_numba(
        t, x, y, p, int(width), int(width) * int(height), float(t0_us), float(t1_us),
        np.ascontiguousarray(inst_us, dtype=np.float64), float(c_pos), float(c_neg),
    )


def edi_pass_reference(t, x, y, p, width, height, t0_us, t1_us, inst_us, c_pos, c_neg):
    """Reference: per pixel, the explicit list of intervals and np.logaddexp; float64."""
    npix = width * height
    T = t1_us - t0_us
    logmean = np.full(npix, 0.0)
    Ef = np.zeros((len(inst_us), npix))
    pix = y.astype(np.int64) * width + x.astype(np.int64)
    inc = np.where(p > 0, c_pos, -c_neg).astype(np.float64)
    for px in np.unique(pix):
        sel = pix == px
        tt = t[sel].astype(np.float64)
        ee = np.concatenate([[0.0], np.cumsum(inc[sel])])  # E on each interval
        bounds = np.concatenate([[t0_us], tt, [t1_us]])
        dts = np.diff(bounds)
        keep = dts > 0
        logmean[px] = np.logaddexp.reduce(np.log(dts[keep]) + ee[keep]) - np.log(T)
        for k, f in enumerate(inst_us):
            Ef[k, px] = ee[np.searchsorted(tt, f, side="left")]  # events with t < f
    return logmean, Ef


def edi_pass_binned(t, x, y, p, width, height, t0_us, t1_us, inst_us, c_pos, c_neg, n_bins: int):
    """Naive time-binned EDI: E sampled at the centres of ``n_bins`` equal bins.

    Each bin's events are added with ``np.add.at`` and exp(E) is summed per bin (the way
    many EDI re-implementations work). The instants are evaluated exactly, as above.
    """
    npix = width * height
    edges = np.linspace(t0_us, t1_us, n_bins + 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    pix = y.astype(np.int64) * width + x.astype(np.int64)
    inc = np.where(p > 0, c_pos, -c_neg).astype(np.float64)
    tf = t.astype(np.float64)
    cut = np.searchsorted(tf, centres, side="left")  # events before each centre
    E = np.zeros(npix)
    m = np.zeros(npix)
    acc = np.zeros(npix)
    prev = 0
    # running log-sum-exp so that large c * counts stay finite, as in the fast path
    m = np.full(npix, -np.inf)
    for b in range(n_bins):
        sl = slice(prev, cut[b])
        np.add.at(E, pix[sl], inc[sl])
        prev = cut[b]
        new_m = np.maximum(m, E)
        acc = acc * np.exp(m - new_m) + np.exp(E - new_m)
        m = new_m
    logmean = m + np.log(acc / n_bins)
    cut_f = np.searchsorted(tf, inst_us, side="left")
    Ef = np.zeros((len(inst_us), npix))
    for k, c in enumerate(cut_f):
        np.add.at(Ef[k], pix[:c], inc[:c])
    return logmean, Ef
