"""mEDI (Pan et al., TPAMI 2020): all frames jointly, per pixel a tridiagonal least squares.

Unknowns x_i = log(L_i + eps), the log latent of frame i at its exposure centre. Data:
the frame-by-frame EDI latents y_i = log(EDI_i + eps); links: the events between
consecutive centres, d_i = E(centre_i -> centre_{i+1}), with x_{i+1} - x_i = d_i (the
event model). Per pixel and channel

    minimise  sum_i w_i (x_i - y_i)^2 + lam * sum_i (x_{i+1} - x_i - d_i)^2,

whose normal equations (W + lam D^T D) x = W y + lam D^T d share one tridiagonal matrix
across all pixels of equal weights (saturated frames get w_i = 1e-6 at that pixel, and are
then carried by the events from their neighbours). Large lam trusts the events, small lam
the frames; lam = 1 by default.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import solve_banded

from .contrast import estimate_c
from .model import LOG_EPS, SATURATION, check_exposure as _check_exposure, check_image as _check_image, edi_log_ratio, latent_from_ratio, parse_c
from .events import EventStream

__all__ = ["medi"]

#: data weight of a saturated frame pixel: tiny, so the events carry it, yet the system stays regular
_SAT_WEIGHT = 1e-6


def medi(
    frames: Any,  # [F, H, W(, D)] linear [0, 1], numpy or torch
    exposures: Any,  # [F, 2] seconds
    events: EventStream,
    c: float | tuple[float, float] | None = None,  # None: estimate_c on all frames
    *,
    lam: float = 1.0,
    saturation: float = SATURATION,
):
    """Sharp latents [F, H, W(, D)] at the exposure centres, all frames solved jointly.

    Args:
        frames: [F, H, W(, D)] blurry frames, linear [0, 1].
        exposures: [F, 2] (t_start, t_end) seconds, increasing centres.
        events: the stream covering the frames.
        c: contrast threshold, (c_pos, c_neg), or None (``estimate_c`` on the frames).
        lam: weight of the event links between consecutive frames.

    Returns:
        The latents, the input's kind (torch float32 for a tensor), in [0, 1].
    """
    if not isinstance(events, EventStream):
        raise TypeError(f"events must be an edi.EventStream, got {type(events).__name__}")
    is_torch = hasattr(frames, "detach")
    fr = frames.detach().cpu().double().numpy() if is_torch else np.asarray(frames, dtype=np.float64)
    grey_in = fr.ndim == 3
    if grey_in:
        fr = fr[..., None]
    if fr.ndim != 4:
        raise ValueError(f"frames must be [F, H, W] or [F, H, W, D], got shape {tuple(np.shape(frames))}")
    ex = np.asarray(exposures, dtype=np.float64)
    if ex.shape != (fr.shape[0], 2):
        raise ValueError(f"exposures must be [F, 2] = [{fr.shape[0]}, 2], got {tuple(ex.shape)}")
    for i in range(fr.shape[0]):
        _check_image(fr[i], f"frames[{i}]", events)
        _check_exposure(ex[i], f"exposures[{i}]")
    centres = ex.mean(axis=1)
    if np.any(np.diff(centres) < 0):
        raise ValueError("exposures must be in time order (increasing centres)")
    if not (np.isfinite(lam) and lam >= 0):
        raise ValueError(f"lam must be finite and >= 0, got {lam}")
    cc = parse_c(estimate_c(fr, ex, events)) if c is None else parse_c(c)
    F, H, W, D = fr.shape

    y = np.empty((F, H, W, D))
    w = np.empty((F, H, W))
    for i in range(F):
        r, _ = edi_log_ratio(events, (ex[i, 0], ex[i, 1]), centres[i : i + 1], cc)
        lat, sat = latent_from_ratio(fr[i], r, saturation)
        y[i] = np.log(lat[0] + LOG_EPS)
        w[i] = np.where(sat, _SAT_WEIGHT, 1.0)
    if F == 1 or lam == 0:
        out = y
    else:
        d = np.empty((F - 1, H, W))
        for i in range(F - 1):
            win = events.slice_time(centres[i], centres[i + 1])
            d[i] = cc[0] * win.count_image(1) - cc[1] * win.count_image(-1)
        # banded normal equations per pixel: diag_i = w_i + lam * deg_i, off = -lam
        deg = np.full(F, 2.0)
        deg[0] = deg[-1] = 1.0
        wf = w.reshape(F, -1)
        diag = wf + lam * deg[:, None]  # [F, P]
        rhs = (wf[..., None] * y.reshape(F, -1, D)).copy()  # [F, P, D]
        dd = d.reshape(F - 1, -1)[..., None]
        rhs[:-1] -= lam * dd
        rhs[1:] += lam * dd
        out = np.empty((F, H * W, D))
        # pixels share the matrix when they share the weights: group by weight pattern
        keys = np.packbits(wf > 0, axis=0)
        uniq, inv = np.unique(keys, axis=1, return_inverse=True)
        inv = inv.reshape(-1)
        for g in range(uniq.shape[1]):
            cols = np.flatnonzero(inv == g)
            ab = np.zeros((3, F))
            ab[0, 1:] = -lam
            ab[1] = diag[:, cols[0]]
            ab[2, :-1] = -lam
            sol = solve_banded((1, 1), ab, rhs[:, cols, :].reshape(F, -1))
            out[:, cols, :] = sol.reshape(F, len(cols), D)
        out = out.reshape(F, H, W, D)
    lat = np.clip(np.exp(out) - LOG_EPS, 0.0, 1.0)
    if not np.isfinite(lat).all():
        raise FloatingPointError("medi produced a non-finite latent; please report this")
    if grey_in:
        lat = lat[..., 0]
    if is_torch:
        import torch

        return torch.from_numpy(lat.astype(np.float32))
    return lat
