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
        t,
        x,
        y,
        p,
        int(width),
        int(width) * int(height),
        float(t0_us),
        float(t1_us),
        np.ascontiguousarray(inst_us, dtype=np.float64),
        float(c_pos),
        float(c_neg),
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


# --- the crossings a DVS pixel's hysteresis hides -------------------------------------------------
#
# A DVS pixel fires when log I moves a threshold away from its reference, the level of its last
# event. After an ON event at level L it fires OFF only at L - c, so when log I turns (rises to
# a peak below L + c, falls back), its return through L makes no event: a sensor quantising log I
# on fixed levels would fire an OFF event there, and after that both agree. ``hidden_crossings``
# puts that missing event back, of the reversing event's polarity, at the fraction ``frac`` of the
# interval between the pixel's previous event (t_prev) and the reversing one (t_i):
# t_prev + frac (t_i - t_prev), rounded to the microsecond; every reversal of the stream whose
# crossing falls in [t0_us, t1_us) is returned.


@numba.njit(cache=True, nogil=True)
def _hidden_crossings_numba(t, x, y, p, width, npix, t0_us, t1_us, frac):  # pragma: no cover - jit
    M = t.shape[0]
    last_t = np.zeros(npix, np.int64)
    last_p = np.zeros(npix, np.int8)  # 0: no event yet
    closed = np.zeros(npix, np.bool_)  # a pixel's first event at or after t1 has been seen
    n_open = 0  # pixels with an event before t1 whose first event at or after t1 is not seen yet
    out_t = np.empty(16, np.int64)
    out_px = np.empty(16, np.int64)
    out_p = np.empty(16, np.int8)
    n = 0
    t_stop = np.int64(-1)  # set at t1: no later reversal can put its crossing before t1
    for i in range(M):
        ti = t[i]
        if ti >= t1_us and t_stop < 0:
            for q in range(npix):  # a reversal at t_i puts its crossing at or after t_prev + frac (t_i - t_prev)
                if last_p[q] != 0 and not closed[q]:
                    if frac <= 0.0:  # every crossing sits at its pixel's previous event
                        t_stop = t[M - 1]
                        break
                    lim = last_t[q] + np.int64(np.ceil((t1_us - last_t[q]) / frac)) + 1
                    if lim > t_stop:
                        t_stop = lim
        if ti >= t1_us and (n_open == 0 or ti > t_stop):
            break
        px = np.int64(y[i]) * width + np.int64(x[i])
        if ti >= t1_us:
            if closed[px] or last_p[px] == 0:
                continue
            closed[px] = True
            n_open -= 1
        elif last_p[px] == 0:
            n_open += 1
        pi = p[i]
        if last_p[px] != 0 and pi != last_p[px]:
            tc = last_t[px] + np.int64(np.rint(frac * np.float64(ti - last_t[px])))
            if t0_us <= tc < t1_us:
                if n == out_t.shape[0]:
                    out_t = np.concatenate((out_t, np.empty(n, np.int64)))
                    out_px = np.concatenate((out_px, np.empty(n, np.int64)))
                    out_p = np.concatenate((out_p, np.empty(n, np.int8)))
                out_t[n] = tc
                out_px[n] = px
                out_p[n] = pi
                n += 1
        last_t[px] = ti
        last_p[px] = pi
    return out_t[:n], out_px[:n], out_p[:n]


def hidden_crossings(
    t: np.ndarray,  # [M] int64 us, sorted
    x: np.ndarray,  # [M]
    y: np.ndarray,  # [M]
    p: np.ndarray,  # [M] int8 in {-1, +1}
    width: int,
    height: int,
    t0_us: int,
    t1_us: int,
    frac: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fast path: (t [V] int64 us, pixel [V] int64 = y * width + x, p [V] int8) of the crossings
    hidden by the pixels' hysteresis that fall in [t0_us, t1_us), sorted by t, then pixel (see
    above). One pass over the stream up to the first event at or after t1_us of every pixel that
    fired before it."""
    assert 0.0 <= frac <= 1.0
    ct, cpx, cp = _hidden_crossings_numba(
        t,
        x,
        y,
        np.asarray(p, np.int8),
        int(width),
        int(width) * int(height),
        np.int64(t0_us),
        np.int64(t1_us),
        float(frac),
    )
    order = np.lexsort((cpx, ct))
    return ct[order], cpx[order], cp[order]


def hidden_crossings_reference(t, x, y, p, width, height, t0_us, t1_us, frac):
    """Reference: every event of the stream with its pixel's previous event (a stable sort by
    pixel, then time), the reversals' crossings, those in the window; sorted by t, then pixel."""
    pix = y.astype(np.int64) * width + x.astype(np.int64)
    order = np.lexsort((t, pix))  # stable: simultaneous events keep their stream order
    q, tt, pp = pix[order], t[order].astype(np.int64), np.asarray(p)[order].astype(np.int8)
    rev = np.zeros(len(q), bool)
    rev[1:] = (q[1:] == q[:-1]) & (pp[1:] != pp[:-1])
    i = np.flatnonzero(rev)
    tc = tt[i - 1] + np.rint(frac * (tt[i] - tt[i - 1]).astype(np.float64)).astype(np.int64)
    keep = (tc >= t0_us) & (tc < t1_us)
    tc, cpx, cp = tc[keep], q[i][keep], pp[i][keep]
    o = np.lexsort((cpx, tc))
    return tc[o], cpx[o], cp[o]


# --- the quantisation residual of the consistency relation ----------------------------------------
#
# ``edi.contrast._mean_residual``'s model: over the fraction u of the interval between a pixel's
# previous event (t_prev) and its next (t_i), the residual of its log intensity is, in units of the
# closing event's threshold and signed like it, u when both events have the same polarity (a ramp),
# turn_a u^2 - turn_b u when they differ (it turned), and unknown (0) before the pixel's first event.
# ``mean_residual`` is its mean over each exposure [A, B) (its value at A when B <= A), per polarity
# of the closing event, in one pass over the stream: each interval is added to the exposures it
# overlaps, found from the exposures sorted by start.


@numba.njit(cache=True, nogil=True)
def _mean_residual_numba(t, x, y, p, width, out, a_us, b_us, end, order, reach, turn_a, turn_b):  # pragma: no cover
    F = order.shape[0]
    npix = out.shape[2]
    last_t = np.zeros(npix, np.float64)
    last_p = np.zeros(npix, np.int8)  # 0: no event yet
    started = 0  # exposures (in start order) with a <= the current event's time
    for i in range(t.shape[0]):
        ti = np.float64(t[i])
        while started < F and a_us[order[started]] <= ti:
            started += 1
        px = np.int64(y[i]) * width + np.int64(x[i])
        pi = p[i]
        lp = last_p[px]
        tp = last_t[px]
        last_t[px] = ti
        last_p[px] = pi
        if lp == 0:
            continue
        ramp = (lp > 0) == (pi > 0)
        row = 0 if pi > 0 else 1
        length = ti - tp
        span = max(length, 1.0)
        j = started - 1
        while j >= 0 and reach[j] > tp:
            f = order[j]
            j -= 1
            if end[f] <= tp:
                continue
            if b_us[f] <= a_us[f]:  # an instant: the residual at a
                u = min(max((a_us[f] - tp) / span, 0.0), 1.0)
                out[f, row, px] = u if ramp else turn_a * u * u - turn_b * u
                continue
            u0 = (min(max(a_us[f], tp), ti) - tp) / span  # the part of the interval inside [a, b)
            u1 = (min(max(b_us[f], tp), ti) - tp) / span
            if ramp:
                v = 0.5 * (u1 * u1 - u0 * u0)
            else:
                v = turn_a / 3.0 * (u1 * u1 * u1 - u0 * u0 * u0) - turn_b / 2.0 * (u1 * u1 - u0 * u0)
            out[f, row, px] += v * length


def mean_residual(
    t: np.ndarray,  # [M] int us, sorted
    x: np.ndarray,  # [M]
    y: np.ndarray,  # [M]
    p: np.ndarray,  # [M] in {-1, +1}
    width: int,
    height: int,
    a_us: np.ndarray,  # [F] exposure starts, us
    b_us: np.ndarray,  # [F] exposure ends, us (<= the start: an instant)
    turn_a: float,
    turn_b: float,
) -> np.ndarray:
    """[F, 2, H*W] float64: the mean residual over each exposure per polarity of the closing
    event (row 0: +, row 1: -); see above."""
    a = np.ascontiguousarray(a_us, dtype=np.float64)
    b = np.ascontiguousarray(b_us, dtype=np.float64)
    instant = b <= a
    end = np.where(instant, a, b)  # the interval [t_prev, t_i) meets exposure f when a <= t_i and t_prev < end
    order = np.argsort(a, kind="stable")
    reach = np.maximum.accumulate(end[order])  # the latest end of the exposures order[0 .. j]
    out = np.zeros((len(a), 2, int(width) * int(height)))
    _mean_residual_numba(t, x, y, np.asarray(p, np.int8), int(width), out, a, b, end, order, reach, turn_a, turn_b)
    span = ~instant
    out[span] /= (b - a)[span, None, None]
    return out
