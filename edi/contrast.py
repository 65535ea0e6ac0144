"""Contrast-threshold estimation from frames and their events.

Two estimators (each an energy of c, every evaluation one EDI pass per frame used):

* ``single`` (one blurry frame). The default energy, ``"flow"``, asks the latent video of
  the exposure to obey brightness constancy. For an image moving with a flow v,
  d log L / dt = -grad(log L) . v. EDI gives both sides for a trial c: over each of K
  sub-intervals of the exposure the change of log(L + eps) at a pixel is c times its signed
  event count (exact), and the spatial gradient is that of the sub-interval's mean log
  latent. In each patch of about ``FLOW_PATCH`` pixels a side (tiling the frame) the best v
  is fitted by least squares; the energy is the residual left over every patch, relative to
  the event-driven change. At the true c one flow per patch explains the events; a c too
  small leaves the blurry frame's gradients (too weak for the events), a c too large adds
  ghost edges that move with no flow. The events get back the crossings the pixels'
  hysteresis hid (an event after a reversal of polarity needs a change of 2c), the gradient
  is the exact derivative of the smoothed latent, and every product in the fit's normal
  equations takes one factor from each half of a checkerboard of the pixels, so that a pixel's
  own threshold error does not enter squared (``_flow_setup`` says what each removed).
  ``"paper"`` is the EDI paper's energy as it states it: total variation of the mid-exposure
  latent (relative to the blurry frame's) minus ``paper_weight`` times the normalised
  cross-correlation of the Sobel magnitudes of the latent and of the event integral (integral
  over the exposure of E(t)). It is kept for
  comparison: measured on ``moving_texture`` and the ray-cast scenes its minimum lies at
  the low end of the bracket (the latent's TV grows with c faster than the correlation),
  see ``benchmarks/calibration.py``.
* ``consistency`` (two or more frames; mEDI's relation). For consecutive frames i, i+1
  with latents L_i, L_{i+1} at their exposure centres, log(L_{i+1} + eps) - log(L_i + eps)
  = c_pos N+ - c_neg N- over the events between the centres, up to the frames' noise and the
  quantisation of the counts; the counts carry the change of the modelled quantisation
  residual (``_mean_residual``: EDI's latent holds its exposure's mean residual). The pair
  comes from moment equations with the neighbours' changes of exposure-mean counts as
  instruments (``_consistency_pairs``, ``_consistency_update``), and the latents are
  recomputed with the new pair until it stops moving (the root of update(c) = c). The least
  squares on c N it replaces weighted each pixel by N^2, which favours the low-threshold
  pixels (they fire more), and read c well below the true mean under a per-pixel mismatch
  (issue 11; figures in docs/results.md).

The 1-D searches use ``scipy.optimize.minimize_scalar(method="bounded")`` on log c. When
the minimum sits at an end of the bracket the energy has no interior minimum: the report's
``at_bound`` is set, a warning is logged, and the estimate should not be trusted (give c,
or more frames for the consistency estimator). A single-frame flow estimate whose fit explains
less than ``FLOW_MIN_EXPLAINED`` of the events' own changes is reported the same way
(``ContrastReport.reliable`` is False, ``explained`` says how much): the events do not follow
the frame's blur, and where the search stops then means nothing.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Literal

import numba
import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.optimize import minimize_scalar

from ._kernels import hidden_crossings, mean_residual
from .errors import InputError
from .events import EventStream, events_in_window, seconds_to_us
from .model import (
    LOG_EPS,
    SATURATION,
    Contrast,
    ImageArray,
    check_cfa,
    check_frames,
    check_gamma,
    edi_log_ratio,
    linearize_saturated,
    to_mosaic,
)

__all__ = ["estimate_c", "estimate_contrast", "ContrastReport", "minimize_log", "Method", "SingleEnergy"]

log = logging.getLogger(__name__)

#: search interval of c (natural-log units); DAVIS sensors are typically 0.1 to 0.5
DEFAULT_BRACKET = (0.03, 1.5)
#: search interval of the ratio c_pos / c_neg
RATIO_BRACKET = (1.0 / 3.0, 3.0)
#: an estimate within this factor of a bracket end is "at the bound"
BOUND_FACTOR = 1.02
#: flow energy: sub-intervals of the exposure, patch side (px), smoothing (px), border (px)
FLOW_SUBINTERVALS = 4
FLOW_PATCH = 16
FLOW_SMOOTH = 1.0
FLOW_BORDER = 2
#: flow energy on a Bayer mosaic's sub-grids (``_single_energy``): the patch side in sub-grid pixels,
#: the same sensor area as FLOW_PATCH on a grey frame. Measured on ``moving_texture(cfa="RGGB")``
#: 40 x 56, seeds 0-4: mean |c - 0.2| 0.0053 with 8, 0.0239 with 16; a smoothing below 1 sub-grid px
#: breaks the halves' normalised convolution (estimates at the bracket ends), so FLOW_SMOOTH stays
FLOW_SUB_PATCH = FLOW_PATCH // 2
#: flow energy: a patch direction whose noise-free gradient energy (the eigenvalue of the halves'
#: product) is small against FLOW_RIDGE times the patch's gradient energy explains little (``_flow_setup``)
FLOW_RIDGE = 0.01

#: consistency: a pixel's instrument sums over its 8 neighbours (``_consistency_pairs``)
_NEIGHBOURS = np.array([[1.0, 1.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
#: consistency on a Bayer mosaic: its 8 nearest neighbours behind the same filter (2 px away), whose
#: events follow the same channel
_NEIGHBOURS_CFA = np.zeros((5, 5))
_NEIGHBOURS_CFA[::2, ::2] = 1.0
_NEIGHBOURS_CFA[2, 2] = 0.0
#: consistency: the residual between two events of opposite polarity, in units of the closing
#: event's threshold and signed like it: TURN_A u^2 - TURN_B u over the interval's fraction u
#: (``_mean_residual``)
TURN_A, TURN_B = 2.0 + math.sqrt(3.0), 1.0 + math.sqrt(3.0)
#: consistency: per consecutive pair of frames (i, i+1): i, N+, N-, z+, z- [H, W], pixels saturated in neither
#: frame and those that fired, [H, W] bool (``_consistency_pairs``)
_Pair = tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: consistency: fixed-point iterations and relative tolerance
CONSISTENCY_ITERS = 20
#: consistency: points of the coarse scan of log c that brackets the root
CONSISTENCY_GRID = 10
CONSISTENCY_RTOL = 1e-4
#: flow energy: a pixel's reversal (an event of the other polarity than its last) hides one crossing
#: of the last event's level; it is put back where ``_mean_residual``'s turn parabola
#: TURN_A u^2 - TURN_B u returns to 0, at the fraction TURN_B / TURN_A (0.73) of the interval
TURN_CROSSING = TURN_B / TURN_A

#: what a single-frame estimate at the low end of the bracket means (appended to the report's message):
#: measured on the real ni_joint frames keyboard, toy and text_cambridge (benchmarks/calibration.py),
#: whose events moved the scene by 1.4 to 1.6 px while the frame's blur spans 24 to 40 px
LOW_END_HINT = (
    "; at the low end the events account for the frame's blur at no c (the energy grows from the "
    "smallest c: what the events add to the latent does not move with the frame's blur): check that the "
    "events cover the whole exposure and that the exposure times are right"
)

#: the share of the events' own changes the flow energy's fit must explain at the estimate (1 - the
#: energy) for a single-frame estimate to be trusted. Measured (``python -m benchmarks.calibration``,
#: 10 seeds of every generator): the frames' own events explain at least 0.53 of their changes on
#: every synthetic generator (0.53 on boxes_grey_weak, 0.71 with the realistic sensor, 0.99 on the
#: moving texture), the six real ni_joint frames 0.03-0.27 (their events saw a small part of the
#: blur, benchmarks/calibration.py), events unrelated to the frame 0.02-0.10
#: (tests/edi/test_contrast.py); the bound sits between the two groups
FLOW_MIN_EXPLAINED = 0.4
#: what an estimate whose events explain too little of their changes means (the report's message)
UNEXPLAINED_HINT = (
    "the events do not follow the frame's blur (events missing part of the exposure, wrong exposure "
    "times, or events of another frame), so no c is determined"
)

#: the single-frame energy (module docstring)
SingleEnergy = Literal["flow", "paper"]
#: ``estimate_contrast``'s ``method``: the estimator, or "auto" (module docstring)
Method = Literal["auto", "single", "consistency"]
#: the estimator a report's estimate came from, and its energy
Estimator = Literal["single", "consistency"]
EnergyName = Literal["flow", "paper", "consistency"]


@dataclass
class ContrastReport:
    """What ``estimate_contrast`` found."""

    c: Contrast  # the estimate, (c_pos, c_neg) (equal unless pair=True)
    method: Estimator  # "single" | "consistency"
    energy_name: EnergyName  # "flow" | "paper" | "consistency"
    bracket: tuple[float, float]  # the search interval of c
    energy: float  # energy at the estimate
    num_evals: int  # EDI passes over the frame(s) used
    evals: list[tuple[float, float]] = field(default_factory=list)  # (c, energy) of the search on c, in order
    saturated_fraction: float = 0.0  # fraction of pixels ignored as saturated
    gamma: float = 1.0  # response exponent the frames were linearised with (recorded = irradiance ** gamma)
    at_bound: bool = False  # the estimate sits at an end of the bracket: no interior minimum, distrust it
    message: str = ""  # what to do when the estimate is not reliable
    explained: float | None = None  # flow energy: the share of the events' changes its fit explains at the estimate

    @property
    def ratio(self) -> float:
        """c_pos / c_neg."""
        return self.c.pos / self.c.neg

    @property
    def reliable(self) -> bool:
        """Neither at a bracket end nor, for the flow energy, fitted to events that explain less than
        ``FLOW_MIN_EXPLAINED`` of their own changes."""
        return not self.at_bound and (self.explained is None or self.explained >= FLOW_MIN_EXPLAINED)


def minimize_log(
    f: Callable[[float], float],
    lo: float,
    hi: float,
    xatol: float = 1e-3,
    evals: list[tuple[float, float]] | None = None,
) -> tuple[float, float]:
    """Minimise f on [lo, hi] over log x (``minimize_scalar``, bounded); returns (x, f(x)).

    ``xatol`` is the absolute tolerance on log x (1e-3: 0.1% of x). Each evaluation is
    appended to ``evals`` as (x, f(x)) when given."""

    def g(u: float) -> float:
        v = float(f(math.exp(u)))
        if evals is not None:
            evals.append((math.exp(u), v))
        return v if math.isfinite(v) else math.inf

    res = minimize_scalar(g, bounds=(math.log(lo), math.log(hi)), method="bounded", options={"xatol": xatol})
    return math.exp(float(res.x)), float(res.fun)


def _pair(c: float, ratio: float) -> Contrast:
    r = math.sqrt(ratio)
    return Contrast(c * r, c / r)


def _grey(b: np.ndarray) -> np.ndarray:
    return b.mean(axis=-1)


def _valid_mask(b: np.ndarray, border: int) -> np.ndarray:
    """[H, W] pixels that are not saturated (nor next to one) and not within ``border`` of the edge."""
    valid = (b < SATURATION).all(axis=-1)
    if border:
        valid = ndimage.binary_erosion(valid, iterations=border, border_value=0)
    return valid  # type: ignore[return-value]  # numpy stubs: all(axis=...) may be a scalar


def _tiles(n: int, patch: int) -> np.ndarray:
    """Start indices of about n / patch nearly equal tiles covering 0..n-1 (every pixel in one)."""
    k = max(1, round(n / patch))
    return np.unique(np.round(np.linspace(0, n, k + 1)).astype(np.int64)[:-1])


def _with_hidden_crossings(events: EventStream, exposure: tuple[float, float]) -> EventStream:
    """The exposure's events plus one event at each crossing the pixels' hysteresis hid in it
    (``_kernels.hidden_crossings``, at the fraction ``TURN_CROSSING`` of the reversal's interval)."""
    t_s, t_e = exposure
    i0, i1 = events_in_window(events, t_s, t_e)
    win = events[i0:i1]
    vt, vpx, vp = hidden_crossings(
        events.t,
        events.x,
        events.y,
        events.p,
        events.width,
        events.height,
        seconds_to_us(t_s),
        seconds_to_us(t_e),
        TURN_CROSSING,
    )
    if len(vt) == 0:
        return win
    t = np.concatenate([win.t, vt])
    order = np.argsort(t, kind="stable")
    x = np.concatenate([win.x.astype(np.int64), vpx % events.width])[order]
    y = np.concatenate([win.y.astype(np.int64), vpx // events.width])[order]
    p = np.concatenate([win.p, vp])[order]
    return EventStream(t[order], x, y, p, events.width, events.height)


def _flow_setup(
    b: np.ndarray,
    exposure: tuple[float, float],
    events: EventStream,
    patch: int = FLOW_PATCH,
    k: int = FLOW_SUBINTERVALS,
) -> Callable[[float], Callable[[float], float]]:
    """ratio -> energy(c) of one blurry frame b [H, W, D]: the brightness-constancy residual relative
    to the events' change (``_flow_parts``; inf when nothing changed)."""
    parts = _flow_parts(b, exposure, events, patch, k)

    def for_ratio(ratio: float) -> Callable[[float], float]:
        f = parts(ratio)

        def energy(c: float) -> float:
            res, tot = f(c)
            return res / tot if tot > 0 else math.inf

        return energy

    return for_ratio


def _flow_parts(
    b: np.ndarray,
    exposure: tuple[float, float],
    events: EventStream,
    patch: int = FLOW_PATCH,
    k: int = FLOW_SUBINTERVALS,
) -> Callable[[float], Callable[[float], tuple[float, float]]]:
    """ratio -> c -> (residual, total) of one blurry frame b [H, W, D]: brightness-constancy residual
    (module docstring) and the events' smoothed change it is relative to; what does not depend on
    the ratio c_pos / c_neg is computed once.

    Integrated over a sub-interval [a, b) of the exposure, brightness constancy under a flow
    v is exact: log L(b) - log L(a) = -grad(mean over [a, b) of log L) . v (b - a). The left
    side is c times the signed count; the mean of log L over [a, b) is log(B + eps) + r(a) +
    (1 / (b - a)) sum over the events in [a, b) of their increment times (b - t_i). Three
    things keep the fitted c from drifting away from the sensor's (issue 11; the decomposition
    measured on ``moving_texture`` frames, also with events computed from the texture without
    quantisation):

    * the events include the crossings the pixels' hysteresis hid (``_with_hidden_crossings``):
      a DVS pixel needs a change of 2c to fire after a reversal, so its events miss one step at
      every turn of its intensity and the latent's changes come out short, by more for larger
      c; the energy made that up with a larger c, where a sensor firing at fixed levels, which
      has no hysteresis, reads c (``test_the_bias_rising_with_c_was_the_sensors_hysteresis``);
    * the gradient is the exact derivative of the Gaussian-smoothed latent (derivative-of-
      Gaussian filters, the change smoothed by the same Gaussian), not central differences of
      it, which flatten the texture's finer periods and read c high even with unquantised
      events;
    * every product in the fit's normal equations (sum g g^T and sum g d) takes one factor from
      each half of a checkerboard of the pixels (each half's latent smoothed by normalised
      convolution): a pixel's own threshold error (per-pixel mismatch) and quantisation are noise
      in the gradients that a larger c amplifies, and squared they explained less of the change
      at larger c; across the halves the noise is independent and drops out. What mismatch
      leaves is that low thresholds fire more: the events see a harmonic mean of the thresholds,
      a little below their mean (figures of each point: docs/results.md, "Figures quoted in the
      code").

    The patches tile the whole frame. Per patch, the flow solves the normal equations with the
    halves' symmetric product A: a direction where A is not positive explains nothing, and one
    with an eigenvalue small against the patch's gradient energy explains little
    (lambda / (lambda^2 + eps^2), eps = FLOW_RIDGE times that energy: a patch with one edge, or
    none, must not explain the change through a near-singular A); a patch explains at most its
    change and at least nothing. On events that have nothing to do with the frame the energy
    is flat near 1 (nothing explained at any c), and where the search stops then means nothing."""
    t_s, t_e = exposure
    lb = np.log(_grey(b) + LOG_EPS)  # [H, W]
    H, W = lb.shape
    valid = _valid_mask(b, FLOW_BORDER).astype(np.float64)
    bounds = t_s + (t_e - t_s) * np.arange(k + 1) / k
    aug = _with_hidden_crossings(events, exposure)
    # the sub-interval of each event, by the rule of edi_log_ratio's instants (E(f) sums the events before f)
    inst_us = np.clip(bounds * 1e6, seconds_to_us(t_s), seconds_to_us(t_e))
    sub = np.clip(np.searchsorted(inst_us, aug.t.astype(np.float64), side="right") - 1, 0, k - 1)
    weight = (bounds[sub + 1] - aug.times_s()) / (bounds[1] - bounds[0])  # share of the rest of its sub-interval
    key = sub * (H * W) + aug.y.astype(np.int64) * W + aug.x
    # per polarity, [K, H, W]: the count in each sub-interval, and the mean over it of the count since t_s
    # (the count before it plus each of its events' share of the rest of it); both exact, so with
    # lme = log((1/T) int exp(E)) (the one part that is not linear in c, the same for every sub-interval)
    #   change of log L over sub-interval k = c_pos count+_k - c_neg count-_k,
    #   mean of log L over it              = log(B + eps) + c_pos mean+_k - c_neg mean-_k - lme
    count, mean = [], []
    for pol in (1, -1):
        sel = aug.p == pol
        n = np.bincount(key[sel], minlength=k * H * W).reshape(k, H, W).astype(np.float64)
        tail = np.bincount(key[sel], weights=weight[sel], minlength=k * H * W).reshape(k, H, W)
        count.append(n)
        mean.append(np.cumsum(n, axis=0) - n + tail)
    ty, tx = _tiles(H, patch), _tiles(W, patch)

    def tile(a: np.ndarray) -> np.ndarray:  # [H, W] -> [ty, tx]: sums over the tiles (masked)
        return np.add.reduceat(np.add.reduceat(a * valid, ty, axis=0), tx, axis=1)

    def sum_k(a: np.ndarray, b_: np.ndarray) -> np.ndarray:  # [K, H, W] twice -> [H, W]: sum over k of a b
        return np.einsum("khw,khw->hw", a, b_)

    def gauss(a: np.ndarray, oy: int, ox: int) -> np.ndarray:  # [..., H, W]: Gaussian or its derivative
        a = ndimage.gaussian_filter1d(a, FLOW_SMOOTH, axis=-2, order=oy, mode="mirror")
        return ndimage.gaussian_filter1d(a, FLOW_SMOOTH, axis=-1, order=ox, mode="mirror")

    # the halves of a checkerboard; mirrored at the border (not reflected), a half stays a
    # checkerboard beyond it, so its smoothed mask G * m is constant to 1e-4 and has no gradient:
    # the normalised convolution G * (m f) / G * m has the derivative G' * (m f) / G * m
    yy, xx = np.indices((H, W))
    halves = [((yy + xx) % 2 == i).astype(np.float64) for i in (0, 1)]
    inv_den = [1.0 / gauss(m, 0, 0) for m in halves]

    def grad(f: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
        """x and y derivatives of the normalised convolution of half h of f [..., H, W]"""
        fm = f * halves[h]
        return gauss(fm, 0, 1) * inv_den[h], gauss(fm, 1, 0) * inv_den[h]

    # the filters are linear: everything but lme is filtered once
    d_parts = [gauss(n, 0, 0) for n in count]  # [K, H, W] smoothed counts, per polarity
    g_lb = [grad(lb, h) for h in (0, 1)]  # per half: x, y [H, W]
    g_mean = [[grad(m, h) for m in mean] for h in (0, 1)]  # per half, per polarity: x, y [K, H, W]

    def for_ratio(ratio: float) -> Callable[[float], tuple[float, float]]:
        s = math.sqrt(ratio)  # c_pos = c s, c_neg = c / s (``_pair``)
        # with these, the smoothed change is d = c D and half h's gradient g_h = c Q_h + S_h, where
        # S_h = grad(log(B + eps) - lme) is the same for every sub-interval: every sum over the
        # sub-intervals of a product is a polynomial in c whose coefficients are computed here
        D = s * d_parts[0] - d_parts[1] / s  # [K, H, W]
        Q = [[s * g_mean[h][0][i] - g_mean[h][1][i] / s for i in (0, 1)] for h in (0, 1)]
        U = [Q[0][i] + Q[1][i] for i in (0, 1)]
        sum_D, DD = D.sum(axis=0), tile(sum_k(D, D))
        sum_Q = [[q.sum(axis=0) for q in Q[h]] for h in (0, 1)]
        sum_U, UU = [u.sum(axis=0) for u in U], [sum_k(u, u) for u in U]
        QQ = [[sum_k(Q[0][i], Q[1][j]) for j in (0, 1)] for i in (0, 1)]  # half 0's i with half 1's j
        QD = [[sum_k(q, D) for q in Q[h]] for h in (0, 1)]

        def energy(c: float) -> tuple[float, float]:
            r, _ = edi_log_ratio(aug, exposure, bounds[:1], _pair(c, ratio))  # E(t_s) - lme = -lme, [1, H, W]
            S = [[gl + gm for gl, gm in zip(g_lb[h], grad(r[0], h))] for h in (0, 1)]

            def cross(i: int, j: int) -> np.ndarray:  # tiles of sum_k g_0i g_1j
                return tile(
                    c * c * QQ[i][j] + c * (S[0][i] * sum_Q[1][j] + S[1][j] * sum_Q[0][i]) + k * S[0][i] * S[1][j]
                )

            # per patch: min_w sum (d + g . w)^2, explained part b^T A^-1 b with A = sum g g^T and
            # b = sum g d; each product of gradients is one of the half 0 with the half 1
            axx, ayy, axy = cross(0, 0), cross(1, 1), 0.5 * (cross(0, 1) + cross(1, 0))
            b_h = [[tile(c * c * QD[h][i] + c * S[h][i] * sum_D) for i in (0, 1)] for h in (0, 1)]
            dd = c * c * DD
            T = [S[0][i] + S[1][i] for i in (0, 1)]
            eps = (
                FLOW_RIDGE * 0.25 * sum(tile(c * c * UU[i] + 2 * c * T[i] * sum_U[i] + k * T[i] * T[i]) for i in (0, 1))
            )
            # A's eigenvalues lambda counted as lambda / (lambda^2 + eps^2), none below 0
            half_tr, half_df = 0.5 * (axx + ayy), 0.5 * (axx - ayy)
            rad = np.hypot(half_df, axy)
            theta = 0.5 * np.arctan2(axy, half_df)
            cos, sin = np.cos(theta), np.sin(theta)
            expl = np.zeros_like(dd)
            for lam, (ux, uy) in ((half_tr + rad, (cos, sin)), (half_tr - rad, (-sin, cos))):
                lam = np.maximum(lam, 0.0)
                proj = (ux * b_h[0][0] + uy * b_h[0][1]) * (ux * b_h[1][0] + uy * b_h[1][1])
                expl += proj * lam / (lam * lam + eps * eps + 1e-300)  # 0 where a patch has no gradient
            expl = np.clip(expl, 0.0, dd)
            tot = float(dd.sum())
            return float(tot - expl.sum()), tot

        return energy

    return for_ratio


def _sobel_mag(img: np.ndarray) -> np.ndarray:
    return np.hypot(ndimage.sobel(img, axis=1, mode="nearest"), ndimage.sobel(img, axis=0, mode="nearest"))


def _ncc(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    a = a[mask] - a[mask].mean()
    b = b[mask] - b[mask].mean()
    den = math.sqrt(float((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def _paper_energy(
    b: np.ndarray, exposure: tuple[float, float], events: EventStream, ratio: float, weight: float
) -> Callable[[float], float]:
    """energy(c) of the EDI paper (Pan et al. 2019, eq. 9): TV(L) - weight * xcorr(Sobel L, Sobel int E).

    TV is the mean anisotropic total variation of the mid-exposure latent divided by the
    blurry frame's (so the two terms are of order 1), the cross-correlation is normalised."""
    t_s, t_e = exposure
    g = _grey(b)
    mask = _valid_mask(b, FLOW_BORDER)
    i0, i1 = events_in_window(events, t_s, t_e)
    win = events[i0:i1]
    cp, cn = _pair(1.0, ratio)
    inc = np.where(win.p > 0, cp, -cn) * (t_e - win.times_s())  # each event's share of int E(t) dt
    e_int = np.bincount(
        win.y.astype(np.int64) * events.width + win.x, weights=inc, minlength=events.width * events.height
    ).reshape(events.height, events.width)
    sob_int = _sobel_mag(e_int)
    mid = np.array([0.5 * (t_s + t_e)])

    def tv(img: np.ndarray) -> float:
        gy, gx = np.gradient(img)
        return float((np.abs(gx) + np.abs(gy))[mask].mean())

    tv_b = max(tv(g), 1e-12)

    def energy(c: float) -> float:
        r, _ = edi_log_ratio(events, exposure, mid, _pair(c, ratio))
        lat = np.clip((g + LOG_EPS) * np.exp(np.minimum(r[0], math.log(2.0 / LOG_EPS))) - LOG_EPS, 0.0, 1.0)
        return tv(lat) / tv_b - weight * _ncc(_sobel_mag(lat), sob_int, mask)

    return energy


def _exposure_tails(events: EventStream, exposure: np.ndarray, polarity: int) -> np.ndarray:
    """[H, W] sum over the exposure's events of one polarity of (t_end - t_i) / T: the mean over
    the exposure of that polarity's count since t_start (0 for a sharp frame)."""
    t_s, t_e = float(exposure[0]), float(exposure[1])
    if t_e <= t_s:
        return np.zeros((events.height, events.width))
    i0, i1 = events_in_window(events, t_s, t_e)
    win = events[i0:i1]
    sel = win.p == polarity
    w = (t_e - win.times_s()[sel]) / (t_e - t_s)
    pix = win.y[sel].astype(np.int64) * events.width + win.x[sel]
    return np.bincount(pix, weights=w, minlength=events.width * events.height).reshape(events.height, events.width)


def _mean_residual(events: EventStream, exposures: np.ndarray) -> np.ndarray:
    """[F, 2, H, W]: the quantisation residual of each pixel, mean over each exposure (the
    frame's instant when t_start == t_end), in units of c_pos (row 0) and c_neg (row 1).

    A pixel's log intensity is its reference level (what c times the events give) plus a
    residual: 0 just after an event, +-c just before the next. EDI's latent carries the mean
    residual of its exposure, which differs between frames (a pixel rising in one frame sits
    about c/2 above its reference, falling in the next c/2 below), and the counts between frames
    do not see it. Over the fraction u of the interval between two events of a pixel, the
    residual is modelled, in units of the closing event's threshold c and with its sign, as

    * u, a ramp from 0 to c, between events of the same polarity (the intensity kept moving);
    * TURN_A u^2 - TURN_B u between events of opposite polarity (it turned): the parabola from
      0 to -c whose peak on the other side is c/2 high, the mean height of a peak that did not
      reach the threshold (its mean over the interval is -0.12 c, not 0: with 0 the estimate
      read c high on ``moving_texture``, where pixels turn often);
    * 0 before a pixel's first event (unknown).

    Row 0 is the mean over the intervals that end with a + event, row 1 with a - event, so the
    residual is c_pos row 0 - c_neg row 1.

    One pass over the stream (``edi._kernels.mean_residual``): its memory is the output's."""
    H, W = events.height, events.width
    if len(events) == 0:
        return np.zeros((len(exposures), 2, H, W))
    a_us, b_us = seconds_to_us(np.asarray(exposures, np.float64)).T  # [F] each
    out = mean_residual(events.t, events.x, events.y, events.p, W, H, a_us, b_us, TURN_A, TURN_B)
    return out.reshape(len(exposures), 2, H, W)


def _consistency_pairs(
    fr: np.ndarray, ex: np.ndarray, events: EventStream, cfa: str | None = None
) -> tuple[list[_Pair], float]:
    """Per consecutive pair (i, i+1) of frames: the counts N+, N- between the centres (negated
    when the centres run backwards) corrected by the change of the quantisation residual
    (``_mean_residual``), their instruments and the mask of pixels saturated in neither frame.

    The instruments are the 8 neighbours' changes of the exposure-mean count (events between
    the exposure starts, plus the later exposure's tails, minus the earlier's): what the blurry
    frames' ratio follows to first order. The neighbours' counts between the centres, used
    before, follow it less when the exposures fill most of the frame interval, and the
    relation's small errors then moved the estimate by several percent on ``moving_texture``.
    On a Bayer mosaic (``cfa``) the neighbours are the 8 nearest behind the same filter
    (``_NEIGHBOURS_CFA``): the others' events follow other channels."""
    neighbours = _NEIGHBOURS if cfa is None else _NEIGHBOURS_CFA
    centres = ex.mean(axis=1)
    # [F, H, W] (numpy's stubs type all(axis=...) as a scalar or an array)
    valid: np.ndarray = (fr < SATURATION).all(axis=-1) & (fr > 0.0).all(axis=-1)  # type: ignore[assignment]
    resid = _mean_residual(events, ex)  # [F, 2, H, W]
    tails: dict[tuple[int, int], np.ndarray] = {}  # (frame, polarity) -> _exposure_tails
    pairs = []
    for i in range(fr.shape[0] - 1):
        lo, hi = sorted((centres[i], centres[i + 1]))
        j0, j1 = events_in_window(events, lo, hi)
        win = events[j0:j1]
        sign = 1.0 if centres[i + 1] >= centres[i] else -1.0
        first, second = (i, i + 1) if sign > 0 else (i + 1, i)
        n_pos = sign * win.count_image(1).astype(np.float64)
        n_neg = sign * win.count_image(-1).astype(np.float64)
        k0, k1 = events_in_window(events, *sorted((ex[first, 0], ex[second, 0])))
        between = events[k0:k1]
        z = []
        for pol in (1, -1):
            for f in (first, second):
                if (f, pol) not in tails:  # each frame is in two pairs
                    tails[f, pol] = _exposure_tails(events, ex[f], pol)
            k = (
                between.count_image(pol) * (1.0 if ex[second, 0] >= ex[first, 0] else -1.0)
                + tails[second, pol]
                - tails[first, pol]
            )
            z.append(sign * ndimage.correlate(k, neighbours, mode="constant"))
        ok = valid[i] & valid[i + 1]
        fired = ok & ((n_pos != 0) | (n_neg != 0))
        n_pos = n_pos + resid[i + 1, 0] - resid[i, 0]
        n_neg = n_neg + resid[i + 1, 1] - resid[i, 1]
        if ((z[0] != 0) | (z[1] != 0))[ok].any():
            pairs.append((i, n_pos, n_neg, z[0], z[1], ok, fired))
        tails.pop((i, 1), None)  # frame i is in no later pair
        tails.pop((i, -1), None)
    return pairs, 1.0 - float(valid.mean())


def _consistency_update(
    fr: np.ndarray, ex: np.ndarray, events: EventStream, pairs: list[_Pair], c: Contrast, pair: bool
) -> tuple[Contrast, float]:
    """One step of the consistency estimator: latents with ``c`` -> the pair the relation gives.

    Per pixel D = log(L_{i+1} + eps) - log(L_i + eps) = c_pos N+ - c_neg N- + e, where e holds
    the frames' noise and the event quantisation (a pixel's count misses up to one step of its
    change). Both sides are noisy, so neither a least squares on c N (biased by the error of N,
    and weighting each pixel by N^2, which favours the low-threshold pixels that fire more and
    reads c low under mismatch) nor a selection of pixels by D or by
    N is unbiased. The instruments z+, z- (the 8 neighbours' changes of exposure-mean counts of
    each polarity, ``_consistency_pairs``) follow the true change of the pixel (motion and edges
    are smooth) but not its own noise, and over all pixels saturated in neither frame

        sum z+ D = c_pos sum z+ N+ - c_neg sum z+ N-,   sum z- D = c_pos sum z- N+ - c_neg sum z- N-

    (one c: sum z D = c sum z N, with z = z+ - z-, N = N+ - N-). Also returns the relative
    residual sum (D - c_pos N+ + c_neg N-)^2 / sum D^2 over the pixels that fired (the energy).
    """
    centres = ex.mean(axis=1)

    def log_latent(j: int) -> np.ndarray:  # log(L + eps) at the frame's centre, exact (no clipping)
        r, _ = edi_log_ratio(events, (ex[j, 0], ex[j, 1]), centres[j : j + 1], c)
        return np.log(fr[j].mean(axis=-1) + LOG_EPS) + r[0]

    frames = sorted({j for p in pairs for j in (p[0], p[0] + 1)})
    with ThreadPoolExecutor(max(1, min(len(frames), numba.get_num_threads()))) as pool:
        logs = dict(zip(frames, pool.map(log_latent, frames)))  # the EDI passes release the GIL
    m = np.zeros((2, 3))  # rows z+ / z-: sum z D, sum z N+, sum z N-
    res2 = tot2 = 0.0
    for i, n_pos, n_neg, z_pos, z_neg, ok, fired in pairs:
        d = (logs[i + 1] - logs[i]) * np.sign(centres[i + 1] - centres[i])
        for row, z in enumerate((z_pos, z_neg)):
            m[row] += ((z * d)[ok].sum(), (z * n_pos)[ok].sum(), (z * n_neg)[ok].sum())
        res2 += float(((d - c.pos * n_pos + c.neg * n_neg)[fired] ** 2).sum())
        tot2 += float((d[fired] ** 2).sum())
    energy = res2 / tot2 if tot2 > 0 else math.inf
    a = np.array([[m[0, 1], -m[0, 2]], [m[1, 1], -m[1, 2]]])
    if pair and abs(np.linalg.det(a)) > 1e-9 * (np.abs(a).max() ** 2 + 1e-300):
        sol = np.linalg.solve(a, m[:, 0])
        if (sol > 0).all():
            return Contrast(float(sol[0]), float(sol[1])), energy
    den = m[0, 1] - m[0, 2] - (m[1, 1] - m[1, 2])  # sum z N
    num = m[0, 0] - m[1, 0]  # sum z D
    if not (den > 0 and num > 0):
        raise InputError(
            "estimate_c: the events between consecutive frame centres do not follow the frames' "
            "changes; cannot use 'consistency'"
        )
    cm = float(num / den)
    return Contrast(cm, cm), energy


def _consistency(
    fr: np.ndarray,
    ex: np.ndarray,
    events: EventStream,
    pairs: list[_Pair],
    bracket: tuple[float, float],
    pair: bool,
    xatol: float,
) -> tuple[Contrast, float, int, list[tuple[float, float]]]:
    """The self-consistent pair: c = update(c) (``_consistency_update``).

    One c: the root of log(update(c) / c) in the bracket (``scipy.optimize.brentq`` on log c;
    the plain iteration converges slowly where the latents depend on c almost as much as the
    counts, long exposures close together), then the 2-D iteration of the pair from there;
    ``pair=False`` returns the pair's mean (one c fitted to N+ - N- reads far below the mean
    on a sensor with c_pos != c_neg, from every pixel that went up and down). Returns the
    pair, its energy, the number of update steps and the (c, energy) of each step."""
    from scipy.optimize import brentq

    history: list[tuple[float, float]] = []

    def step(c: Contrast, pair: bool) -> tuple[Contrast, float]:
        new, e = _consistency_update(fr, ex, events, pairs, c, pair)
        history.append((c.mean, e))
        return new, e

    def g(u: float) -> float:  # the root search is on the mean c (the pair's mean: with c_pos != c_neg
        c = math.exp(u)  # one c fitted to N+ - N- is biased by every pixel that went up and down)
        return math.log(step(Contrast(c, c), True)[0].mean / c)

    # the first stable crossing from below (g from + to -) on a coarse grid, then brentq: at
    # very large c the selection (a change of at least 1.5 c) empties and g turns positive again
    us = np.linspace(math.log(bracket[0]), math.log(bracket[1]), CONSISTENCY_GRID)
    c0 = None
    g_prev = g(us[0])
    if g_prev <= 0:
        c0 = bracket[0]  # the update points below the bracket
    for u0, u1 in zip(us[:-1], us[1:]):
        if c0 is not None:
            break
        g1 = g(u1)
        if g_prev > 0 >= g1:
            c0 = math.exp(brentq(g, u0, u1, xtol=xatol))
        g_prev = g1
    if c0 is None:
        c0 = bracket[1]  # the update points above the bracket
    c = Contrast(c0, c0)
    rooted = bracket[0] < c0 < bracket[1]
    new, e = step(c, rooted)
    if rooted:
        for _ in range(CONSISTENCY_ITERS):
            done = abs(new.pos - c.pos) <= CONSISTENCY_RTOL * c.pos and abs(new.neg - c.neg) <= CONSISTENCY_RTOL * c.neg
            c = new
            if done:
                break
            new, e = step(c, True)
    if not pair:
        c = Contrast(c.mean, c.mean)
    return c, e, len(history), history


@dataclass
class _Fit:
    """One estimator's result, before the report's checks."""

    est: Contrast  # (c_pos, c_neg), equal unless a pair was fitted
    energy: float  # the energy at the estimate
    n_pass: int  # EDI passes over the frame(s)
    evals: list[tuple[float, float]]  # (c, energy) of the search on c
    saturated: float  # fraction of pixels ignored as saturated
    method: Estimator
    energy_name: EnergyName


def _check_estimate_inputs(
    frames: ImageArray,
    exposures: npt.ArrayLike,
    events: EventStream,
    method: str,
    energy: str,
    bracket: tuple[float, float],
    gamma: float,
    cfa: str | None = None,
) -> tuple[np.ndarray, np.ndarray, tuple[float, float], float]:
    """The inputs checked: frames [F, H, W, D] linearised with ``gamma`` (with ``cfa``, their
    mosaic [F, H, W, 1]), exposures [F, 2], the bracket (lo, hi) and gamma; InputError (TypeError
    for ``events``) naming what is wrong."""
    if not isinstance(events, EventStream):
        raise TypeError(f"events must be an edi.EventStream, got {type(events).__name__}")
    fr, ex = check_frames(frames, exposures, events)
    if cfa is not None:
        fr = to_mosaic(fr, cfa, "frames")
    gamma = check_gamma(gamma)
    if gamma != 1.0:  # to irradiance; saturated (recorded) -> 1, the others stay below SATURATION
        lin, t = linearize_saturated(fr, gamma)
        fr = np.where(lin >= t, 1.0, np.minimum(lin, np.nextafter(SATURATION, 0.0)))
    lo, hi = (float(v) for v in bracket)
    if not (0 < lo < hi and math.isfinite(hi)):
        raise InputError(f"bracket must be 0 < lo < hi, got {bracket!r}")
    if method not in ("auto", "single", "consistency"):
        raise InputError(f"method must be 'auto', 'single' or 'consistency', got {method!r}")
    if energy not in ("flow", "paper"):
        raise InputError(f"energy must be 'flow' or 'paper', got {energy!r}")
    if (fr >= SATURATION).any(axis=-1).all():
        raise InputError(
            f"estimate_c: every pixel of the {fr.shape[0]} frame(s) is saturated (>= {SATURATION}); "
            "nothing to estimate c from: give c"
        )
    return fr, ex, (lo, hi), gamma


def _fit_consistency(
    fr: np.ndarray,
    ex: np.ndarray,
    events: EventStream,
    method: Method,
    bracket: tuple[float, float],
    pair: bool,
    xatol: float,
    cfa: str | None = None,
) -> tuple[_Fit | None, str, list[tuple[float, float]]]:
    """The consistency estimator where ``method`` asks for it and there are two frames or more.

    Returns its fit, or None when the single-frame energy is to be used instead; the reason of
    a fallback ("" if none); and the evaluations the single-frame search starts from (the
    consistency steps when the estimator ran but its estimate sat at a bracket end)."""
    if method == "single":
        return None, "", []
    if fr.shape[0] < 2:
        if method == "consistency":
            raise InputError("estimate_c(method='consistency') needs at least two frames")
        return None, "", []
    pairs, sat = _consistency_pairs(fr, ex, events, cfa)
    if not pairs:
        if method == "consistency":
            raise InputError("estimate_c: no pixel fired between consecutive frame centres; cannot use 'consistency'")
        return None, "", []
    lo, hi = bracket
    blurry = bool((ex[:, 1] > ex[:, 0]).any())
    try:
        est, e, n_steps, evals = _consistency(fr, ex, events, pairs, bracket, pair, xatol)
    except InputError as exc:
        if method != "auto" or not blurry:
            raise
        fallback = f"{exc}; used the single-frame energy of the most blurred frame"
        log.info("estimate_c: %s", fallback)
        return None, fallback, []
    if method == "auto" and blurry and not lo * BOUND_FACTOR <= est.mean <= hi / BOUND_FACTOR:
        # no self-consistent c in the bracket: one frame instead
        fallback = (
            f"consistency: no self-consistent c in the bracket (stopped at {est.mean:.4g}); "
            "used the single-frame energy of the most blurred frame"
        )
        log.info("estimate_c: %s", fallback)
        return None, fallback, evals
    return _Fit(est, e, n_steps * (len(pairs) + 1), evals, sat, "consistency", "consistency"), "", []


def _single_energy(
    b: np.ndarray,
    exposure: tuple[float, float],
    events: EventStream,
    energy: SingleEnergy,
    paper_weight: float,
    cfa: str | None = None,
) -> Callable[[float], Callable[[float], float]]:
    """ratio c_pos / c_neg -> energy(c) of one blurry frame b [H, W, D] (``_flow_setup`` or ``_paper_energy``).

    With ``cfa`` (b is the raw mosaic [H, W, 1]) the energy is that of the four sub-grids of the
    2x2 pattern, each a grey image of one filter with its own pixels' events (``_subgrids``), so
    that the spatial terms never see the pattern as texture: the flow energy's residuals and
    totals are summed over them, the paper energy is their mean."""
    if cfa is None:
        if energy == "flow":
            return _flow_setup(b, exposure, events)
        return lambda ratio: _paper_energy(b, exposure, events, ratio, paper_weight)
    subs = _subgrids(b, events)
    if energy == "paper":
        return lambda ratio: _mean_of([_paper_energy(bs, exposure, es, ratio, paper_weight) for bs, es in subs])
    parts = [_flow_parts(bs, exposure, es, FLOW_SUB_PATCH) for bs, es in subs]

    def for_ratio(ratio: float) -> Callable[[float], float]:
        fs = [p(ratio) for p in parts]

        def energy_c(c: float) -> float:
            res_tot = np.array([f(c) for f in fs])  # [4, 2]
            res, tot = float(res_tot[:, 0].sum()), float(res_tot[:, 1].sum())
            return res / tot if tot > 0 else math.inf

        return energy_c

    return for_ratio


def _mean_of(fs: list[Callable[[float], float]]) -> Callable[[float], float]:
    return lambda c: float(np.mean([f(c) for f in fs]))


def _subgrids(b: np.ndarray, events: EventStream) -> list[tuple[np.ndarray, EventStream]]:
    """The four sub-grids of a 2x2 Bayer mosaic b [H, W, 1]: per offset (x0, y0) in {0, 1}^2, the
    image b[y0::2, x0::2] and the events of those pixels, on the sub-grid's own pixel grid."""
    out = []
    ex, ey = events.x, events.y
    for y0 in (0, 1):
        for x0 in (0, 1):
            sub = b[y0::2, x0::2]
            sel = ((ex & 1) == x0) & ((ey & 1) == y0)
            ev = EventStream(
                events.t[sel], ex[sel] >> 1, ey[sel] >> 1, events.p[sel], int(sub.shape[1]), int(sub.shape[0])
            )
            out.append((sub, ev))
    return out


def _at_fixed_c(build: Callable[[float], Callable[[float], float]], c: float) -> Callable[[float], float]:
    """ratio -> energy at the fixed ``c``."""
    return lambda ratio: build(ratio)(c)


def _fit_single(
    fr: np.ndarray,
    ex: np.ndarray,
    events: EventStream,
    energy: SingleEnergy,
    bracket: tuple[float, float],
    pair: bool,
    xatol: float,
    paper_weight: float,
    evals: list[tuple[float, float]],
    cfa: str | None = None,
) -> _Fit:
    """The single-frame estimator on the most blurred frame: c by ``minimize_log``; with ``pair``,
    twice the ratio c_pos / c_neg at fixed c, then c at that ratio. The search on c at ratio 1
    appends to ``evals``."""
    lo, hi = bracket
    i = int(np.argmax(ex[:, 1] - ex[:, 0]))  # the most blurred frame
    j0, j1 = events_in_window(events, ex[i, 0], ex[i, 1])
    if ex[i, 1] <= ex[i, 0] or j1 == j0:
        raise InputError(
            "estimate_c: no blurry frame with events in its exposure and fewer than two frames to compare: give c"
        )
    sat = 1.0 - float((fr[i] < SATURATION).all(axis=-1).mean())
    exposure = (float(ex[i, 0]), float(ex[i, 1]))
    build = _single_energy(fr[i], exposure, events, energy, paper_weight, cfa)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-masked patch is handled, not an error
        c, e = minimize_log(build(1.0), lo, hi, xatol, evals)
        ratio = 1.0
        n_pass = len(evals)
        if pair:
            # alternate: the ratio c_pos / c_neg at fixed c, then c at that ratio
            for _ in range(2):
                ev_r: list[tuple[float, float]] = []
                ratio, _ = minimize_log(_at_fixed_c(build, c), *RATIO_BRACKET, xatol, ev_r)
                evals = []
                c, e = minimize_log(build(ratio), lo, hi, xatol, evals)
                n_pass += len(ev_r) + len(evals)
    return _Fit(_pair(c, ratio), e, n_pass, evals, sat, "single", energy)


def _bound_check(est: Contrast, bracket: tuple[float, float], pair: bool) -> tuple[bool, str]:
    """Whether the estimate (with ``pair``, also its ratio) sits at an end of its bracket, and what sits there."""
    lo, hi = bracket
    mean_c = est.mean
    at_bound = mean_c < lo * BOUND_FACTOR or mean_c > hi / BOUND_FACTOR
    what = f"c = {mean_c:.4g} is at an end of the bracket ({lo:g}, {hi:g})"
    if pair and not at_bound:
        rho = est.pos / est.neg
        at_bound = rho < RATIO_BRACKET[0] * BOUND_FACTOR or rho > RATIO_BRACKET[1] / BOUND_FACTOR
        what = f"c_pos / c_neg = {rho:.4g} is at an end of its bracket ({RATIO_BRACKET[0]:.3g}, {RATIO_BRACKET[1]:.3g})"
    return at_bound, what


def _unreliable_message(
    fit: _Fit, bracket: tuple[float, float], at_bound: bool, what: str, explained: float | None
) -> str:
    """What to do about an estimate at a bracket end or whose events explain too little ("" when
    neither); logged as a warning."""
    unexplained = explained is not None and explained < FLOW_MIN_EXPLAINED
    if not (at_bound or unexplained):
        return ""
    mean_c = fit.est.mean
    give = "give c (ebad deblur --c C or --c C_POS,C_NEG) or more frames (two or more use the consistency estimator)"
    message = "estimate_c: " + (
        f"{what} ({fit.method} estimator, {fit.energy_name} energy): the energy has no interior minimum; "
        if at_bound
        else ""
    )
    if unexplained:
        message += (
            f"at c = {mean_c:.4g} the frame's motion explains {explained:.0%} of its events' changes "
            f"(flow energy; at least {FLOW_MIN_EXPLAINED:.0%} where an estimate holds): {UNEXPLAINED_HINT}; "
        )
    message += f"this estimate is unreliable; {give}"
    if at_bound and fit.energy_name == "flow" and mean_c < bracket[0] * BOUND_FACTOR:
        message += LOW_END_HINT
    log.warning(message)
    return message


def _report(fit: _Fit, bracket: tuple[float, float], pair: bool, gamma: float, fallback: str) -> ContrastReport:
    """The report of a fit: bracket ends, the share of the events' changes explained, what to do."""
    if not all(math.isfinite(v) for v in fit.est):
        raise FloatingPointError("estimate_c produced a non-finite estimate; please report this")
    at_bound, what = _bound_check(fit.est, bracket, pair)
    explained = 1.0 - float(fit.energy) if fit.energy_name == "flow" else None
    message = _unreliable_message(fit, bracket, at_bound, what, explained)
    if fallback:
        message = (fallback + "; " + message) if message else fallback
    return ContrastReport(
        fit.est,
        fit.method,
        fit.energy_name,
        bracket,
        float(fit.energy),
        int(fit.n_pass),
        fit.evals,
        float(fit.saturated),
        gamma,
        at_bound,
        message,
        explained,
    )


def estimate_contrast(
    frames: ImageArray,  # [H, W(, D)] or [F, H, W(, D)], linear [0, 1]
    exposures: npt.ArrayLike,  # [2] or [F, 2] seconds
    events: EventStream,
    *,
    method: Method = "auto",
    energy: SingleEnergy = "flow",
    bracket: tuple[float, float] = DEFAULT_BRACKET,
    pair: bool = False,
    polarity: bool | None = None,
    xatol: float = 1e-3,
    paper_weight: float = 1.0,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> ContrastReport:
    """Estimate the contrast threshold c (natural-log units) from frames and their events, with
    what the estimators found (``estimate_c`` returns its ``c`` alone).

    Args:
        frames: one blurry frame [H, W(, D)] or several [F, H, W(, D)] (numpy or torch; see
            ``deblur`` for the accepted ranges).
        exposures: [2] or [F, 2] (t_start, t_end) seconds on the events' clock.
        events: the event stream.
        method: "single" (an energy of the most blurred frame), "consistency" (mEDI's
            relation between consecutive frames; needs F >= 2), or "auto" (consistency when
            F >= 2 and some pixel changed between frame centres, else single; also single
            when the consistency relation has no root in the bracket, which happens when the
            exposures fill most of the frame interval: the report's message says so).
        energy: the single-frame energy, "flow" (brightness constancy of the latent video,
            the default) or "paper" (the EDI paper's TV and edge correlation).
        bracket: search interval for c (single) and the range an estimate must fall in.
        pair: estimate (c_pos, c_neg) separately (else both are the one c fitted).
            ``polarity`` is the old name of ``pair``.
        xatol: tolerance of the searches in log c.
        paper_weight: weight of the edge term of the "paper" energy.
        gamma: the frames' response, recorded = irradiance ** gamma (1: linear). The frames
            are linearised before anything else, so c is in log-irradiance units, the units of
            the events. With the wrong gamma the estimate is about gamma_true / gamma x c:
            frame-to-frame consistency and the single-frame energy only see gamma x c (c in the
            frames' units). gamma is not estimated: the consistency estimate keeps gamma x c and
            its residual nearly the same for any gamma in a wide range (benchmarks/calibration.py),
            so the frames and events do not tell gamma; give it.
        cfa: the Bayer pattern of a colour DAVIS (``edi.cfa``), or None. Each pixel's events
            follow its own channel, so the estimate works on the frames' mosaic (RGB frames are
            mosaicked; raw [.., H, W] or [..., H, W, 1] frames are the mosaic): the latents are
            per pixel, and the spatial terms (the flow energy's gradients, the consistency
            estimator's neighbours) use only pixels behind the same filter. One c is shared by
            the channels: on ``moving_texture(cfa="RGGB")`` (40 x 56, seeds 0-4, c = 0.2) the
            shared estimate's mean |c - 0.2| was 0.0053 from one frame and 0.0018 from three,
            one c per filter's sub-grid 0.0129 and 0.0021 (with a per-pixel mismatch of 0.03:
            0.0068 / 0.0024 shared, 0.0106 / 0.0066 per channel); events as luminance read
            0.39 / 0.41 off.

    Returns:
        A ``ContrastReport``: ``c`` is the estimate, an ``edi.Contrast(pos, neg)`` (both equal
        to the one c fitted when ``pair`` is False; ``c.mean`` is that c either way). An
        estimate at an end of ``bracket`` is logged as a warning and flagged ``at_bound``; one
        whose events explain too little of their changes is logged too, and either way
        ``reliable`` is False and ``message`` says what to do.

    Raises:
        InputError: bad shapes, ranges or bracket; no frame with events to estimate from.
    """
    if polarity is not None:
        pair = bool(polarity)
    cfa = check_cfa(cfa)
    fr, ex, (lo, hi), gamma = _check_estimate_inputs(frames, exposures, events, method, energy, bracket, gamma, cfa)
    fit, fallback, evals = _fit_consistency(fr, ex, events, method, (lo, hi), pair, xatol, cfa)
    if fit is None:
        fit = _fit_single(fr, ex, events, energy, (lo, hi), pair, xatol, paper_weight, evals, cfa)
    return _report(fit, (lo, hi), pair, gamma, fallback)


def estimate_c(
    frames: ImageArray,  # [H, W(, D)] or [F, H, W(, D)], linear [0, 1]
    exposures: npt.ArrayLike,  # [2] or [F, 2] seconds
    events: EventStream,
    *,
    method: Method = "auto",
    energy: SingleEnergy = "flow",
    bracket: tuple[float, float] = DEFAULT_BRACKET,
    pair: bool = False,
    polarity: bool | None = None,
    xatol: float = 1e-3,
    paper_weight: float = 1.0,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> Contrast:
    """The contrast threshold (c_pos, c_neg) in natural-log units: ``estimate_contrast(...).c``
    (the arguments are its own). With ``pair`` False both are the one c fitted (``.mean``
    gives it as a float); an estimate that is not reliable is logged as a warning, and
    ``estimate_contrast`` says why."""
    return estimate_contrast(
        frames,
        exposures,
        events,
        method=method,
        energy=energy,
        bracket=bracket,
        pair=pair,
        polarity=polarity,
        xatol=xatol,
        paper_weight=paper_weight,
        gamma=gamma,
        cfa=cfa,
    ).c
