"""mEDI (Pan et al., TPAMI 2020): all frames jointly, per pixel a tridiagonal least squares.

Unknowns x_i = log(L_i + eps), the log latent of frame i at its exposure centre. Data:
the frame-by-frame EDI latents y_i = log(EDI_i + eps); links: the events between
consecutive centres, d_i = E(centre_i -> centre_{i+1}), with x_{i+1} - x_i = d_i (the
event model). Per pixel and channel

    minimise  sum_i w_i (x_i - y_i)^2 + lam * sum_i (x_{i+1} - x_i - d_i)^2,

whose normal equations (W + lam D^T D) x = W y + lam D^T d share one tridiagonal matrix
per pixel (saturated frames get w_i = 1e-6 at that pixel, and are then carried by the
events from their neighbours); every pixel's system is solved with its own weights by a
vectorised Thomas algorithm (``solve_tridiagonal``). Large lam trusts the events, small lam
the frames; lam = 1 by default.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, overload

import numpy as np
import numpy.typing as npt

from .cfa import demosaic
from .contrast import estimate_c
from .errors import InputError
from .events import EventStream, events_in_window
from .model import (
    LOG_EPS,
    SATURATION,
    ContrastLike,
    ImageArray,
    check_cfa,
    check_frames,
    edi_log_ratio,
    latent_from_ratio,
    parse_c,
    to_mosaic,
)

if TYPE_CHECKING:
    import torch

__all__ = ["medi", "solve_tridiagonal"]

#: data weight of a saturated frame pixel: tiny, so the events carry it, yet the system stays regular
_SAT_WEIGHT = 1e-6


def solve_tridiagonal(
    lower: np.ndarray,  # [F - 1] sub-diagonal, shared by every system
    diag: np.ndarray,  # [F, ...] diagonal of each system
    upper: np.ndarray,  # [F - 1] super-diagonal, shared
    rhs: np.ndarray,  # [F, ...] right-hand sides
) -> np.ndarray:
    """Solve many tridiagonal systems at once (Thomas algorithm, no pivoting), [F, ...].

    Meant for diagonally dominant systems (mEDI's normal equations with weights > 0), where
    the elimination without pivoting is stable."""
    F = diag.shape[0]
    c = np.empty(diag.shape)
    x = np.empty(np.broadcast_shapes(diag.shape, rhs.shape))
    den = diag[0]
    c[0] = upper[0] / den if F > 1 else 0.0
    x[0] = rhs[0] / den
    for i in range(1, F):
        den = diag[i] - lower[i - 1] * c[i - 1]
        if i < F - 1:
            c[i] = upper[i] / den
        x[i] = (rhs[i] - lower[i - 1] * x[i - 1]) / den
    for i in range(F - 2, -1, -1):
        x[i] -= c[i] * x[i + 1]
    return x


@overload
def medi(
    frames: np.ndarray,
    exposures: npt.ArrayLike,
    events: EventStream,
    c: ContrastLike | None = None,
    *,
    lam: float = 1.0,
    saturation: float = SATURATION,
    cfa: str | None = None,
) -> np.ndarray: ...


@overload
def medi(
    frames: torch.Tensor,
    exposures: npt.ArrayLike,
    events: EventStream,
    c: ContrastLike | None = None,
    *,
    lam: float = 1.0,
    saturation: float = SATURATION,
    cfa: str | None = None,
) -> torch.Tensor: ...


def medi(
    frames: ImageArray,  # [F, H, W(, D)] linear [0, 1], numpy or torch
    exposures: npt.ArrayLike,  # [F, 2] seconds
    events: EventStream,
    c: ContrastLike | None = None,  # None: estimate_c on all frames
    *,
    lam: float = 1.0,
    saturation: float = SATURATION,
    cfa: str | None = None,
) -> ImageArray:
    """Sharp latents [F, H, W(, D)] at the exposure centres, all frames solved jointly.

    Args:
        frames: [F, H, W(, D)] blurry frames, linear [0, 1].
        exposures: [F, 2] (t_start, t_end) seconds, increasing centres.
        events: the stream covering the frames.
        c: contrast threshold, (c_pos, c_neg), or None (``estimate_c`` on the frames).
        lam: weight of the event links between consecutive frames.
        cfa: the Bayer pattern of a colour DAVIS (``edi.cfa``), or None. Each pixel's events
            follow its own channel, so the system is solved per pixel of the frames' mosaic
            (RGB frames are mosaicked; raw [F, H, W(, 1)] frames are the mosaic) and RGB frames
            get the demosaiced per-pixel latents, raw frames raw latents (as ``deblur``).

    Returns:
        The latents, the input's kind (torch float32 for a tensor), in [0, 1].
    """
    if not isinstance(events, EventStream):
        raise TypeError(f"events must be an edi.EventStream, got {type(events).__name__}")
    is_torch = hasattr(frames, "detach") and type(frames).__module__.startswith("torch")
    if np.ndim(frames) not in (3, 4):
        raise InputError(f"frames must be [F, H, W] or [F, H, W, D], got shape {tuple(np.shape(frames))}")
    grey_in = np.ndim(frames) == 3
    ex = np.asarray(exposures, dtype=np.float64)
    if ex.shape != (np.shape(frames)[0], 2):
        raise InputError(f"exposures must be [F, 2] = [{np.shape(frames)[0]}, 2], got {tuple(ex.shape)}")
    fr, ex = check_frames(frames, ex, events)
    cfa = check_cfa(cfa)
    rgb_in = cfa is not None and fr.shape[-1] == 3
    if cfa is not None:
        fr = to_mosaic(fr, cfa, "frames")
    centres = ex.mean(axis=1)
    if np.any(np.diff(centres) < 0):
        raise InputError("exposures must be in time order (increasing centres)")
    if not (np.isfinite(lam) and lam >= 0):
        raise InputError(f"lam must be finite and >= 0, got {lam}")
    cc = estimate_c(fr, ex, events, pair=True, cfa=cfa) if c is None else parse_c(c)
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
            j0, j1 = events_in_window(events, centres[i], centres[i + 1])
            win = events[j0:j1]
            d[i] = cc[0] * win.count_image(1) - cc[1] * win.count_image(-1)
        # normal equations per pixel and channel: tridiagonal, diag_i = w_i + lam * deg_i, off = -lam
        deg = np.full(F, 2.0)
        deg[0] = deg[-1] = 1.0
        wf = w.reshape(F, -1, 1)  # [F, P, 1]
        diag = np.broadcast_to(wf + lam * deg[:, None, None], (F, H * W, D))
        rhs = wf * y.reshape(F, -1, D)  # [F, P, D]
        dd = d.reshape(F - 1, -1)[..., None]
        rhs[:-1] -= lam * dd
        rhs[1:] += lam * dd
        out = solve_tridiagonal(np.full(F - 1, -lam), diag, np.full(F - 1, -lam), rhs)
        out = out.reshape(F, H, W, D)
    lat = np.clip(np.exp(out) - LOG_EPS, 0.0, 1.0)
    if rgb_in:
        assert cfa is not None  # rgb_in needs it
        lat = np.clip(demosaic(lat[..., 0], cfa), 0.0, 1.0)  # as deblur's colour_latents("latents")
    if not np.isfinite(lat).all():
        raise FloatingPointError("medi produced a non-finite latent; please report this")
    if grey_in:
        lat = lat[..., 0]
    if is_torch:
        import torch

        return torch.from_numpy(lat.astype(np.float32))
    return lat
