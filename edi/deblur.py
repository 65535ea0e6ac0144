"""EDI: the Event-based Double Integral (Pan et al., CVPR 2019), exact and one-pass.

Model (Convention: intensities linear in [0, 1], c in natural-log units): events fire on
changes of log(I + LOG_EPS), so between instants f and t

    I(t) + eps = (I(f) + eps) * exp(E(t) - E(f)),   E(t) = c_pos * N+(T0, t) - c_neg * N-(T0, t)

and the blurry frame is the mean over the exposure, B = (1/T) integral I(t) dt. Hence

    L(f) = (B + eps) / ((1/T) integral exp(E(t) - E(f)) dt) - eps
         = (B + eps) * exp(E(f) - log((1/T) integral exp(E(t)) dt)) - eps.

E(t) is piecewise constant between events, so the integral is an exact sum over the
inter-event intervals of every pixel, and one pass over the events serves all instants.
With eps = 0 this is the EDI paper's L = B T / integral exp(c E); eps keeps a black
pixel black (0, not NaN) and bounds the gain on dark pixels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from ._kernels import edi_pass, edi_pass_binned, edi_pass_reference
from .events import EventStream

__all__ = ["LOG_EPS", "SATURATION", "deblur", "DeblurReport", "edi_log_ratio", "parse_c"]

#: Offset in log(I + LOG_EPS) for linear intensities in [0, 1]: a black pixel has log
#: intensity log(1e-3) = -6.9 instead of -inf; used by the event model everywhere in edi
#: (and by event simulators that want to be consistent with it).
LOG_EPS: float = 1e-3

#: A blurry pixel at or above this linear value is saturated: its true mean intensity is
#: unknown, so EDI leaves it as it is (the pixel is listed in ``DeblurReport.saturated``).
SATURATION: float = 0.99

_IMPLS = {"fast": edi_pass, "reference": edi_pass_reference}


@dataclass
class DeblurReport:
    """What ``deblur(..., return_report=True)`` did besides the image."""

    c: tuple[float, float]  # (c_pos, c_neg) used
    num_events: int  # events inside the exposure
    saturated: np.ndarray  # [H, W] bool: pixels left as B because B >= SATURATION (any channel)
    c_report: Any = None  # the ContrastReport when c was estimated
    notes: list[str] = field(default_factory=list)


def parse_c(c: Any, name: str = "c") -> tuple[float, float]:
    """A float or a (c_pos, c_neg) pair -> (c_pos, c_neg), validated (finite, > 0)."""
    if isinstance(c, (tuple, list, np.ndarray)) or (hasattr(c, "shape") and getattr(c, "ndim", 0) == 1):
        vals = [float(v) for v in c]
        if len(vals) != 2:
            raise ValueError(f"{name} must be a float or a pair (c_pos, c_neg), got {len(vals)} values")
    else:
        try:
            vals = [float(c)] * 2
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a float or a pair (c_pos, c_neg), got {c!r}") from exc
    for v in vals:
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be finite and > 0, got {c!r}")
    return vals[0], vals[1]


def _check_exposure(exposure: Any, name: str = "exposure") -> tuple[float, float]:
    try:
        t_s, t_e = (float(v) for v in np.asarray(exposure, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be (t_start, t_end) in seconds, got {exposure!r}") from exc
    if not (math.isfinite(t_s) and math.isfinite(t_e)):
        raise ValueError(f"{name} must be finite, got ({t_s}, {t_e})")
    if t_e < t_s:
        raise ValueError(f"{name} ends before it starts: t_end {t_e} < t_start {t_s}")
    return t_s, t_e


def _check_image(blur: Any, name: str, events: EventStream | None) -> tuple[np.ndarray, bool]:
    """blur -> float64 [H, W, D] numpy, and whether the input was a torch tensor."""
    is_torch = hasattr(blur, "detach") and hasattr(blur, "dtype") and type(blur).__module__.startswith("torch")
    arr = blur.detach().cpu().double().numpy() if is_torch else np.asarray(blur, dtype=np.float64)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise ValueError(f"{name} must be [H, W] or [H, W, D], got shape {tuple(np.shape(blur))}")
    if not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} has a non-finite value at {tuple(int(i) for i in bad)}")
    if events is not None and (arr.shape[0], arr.shape[1]) != (events.height, events.width):
        raise ValueError(
            f"{name} is {arr.shape[0]}x{arr.shape[1]} (HxW) but the events' sensor is "
            f"{events.height}x{events.width}"
        )
    return arr, is_torch


def _check_times(times: Any, t_s: float, t_e: float) -> tuple[np.ndarray, bool]:
    """times -> [F] float64 seconds and whether a single instant was asked for."""
    if times is None:
        return np.array([0.5 * (t_s + t_e)]), True
    if hasattr(times, "detach"):
        times = times.detach().cpu().numpy()
    arr = np.asarray(times, dtype=np.float64)
    single = arr.ndim == 0
    arr = arr.reshape(-1)
    if arr.size == 0:
        raise ValueError("times must hold at least one instant")
    if not np.isfinite(arr).all():
        raise ValueError(f"times must be finite, got {arr.tolist()}")
    tol = 1e-9 + 1e-12 * abs(t_e)
    out = (arr < t_s - tol) | (arr > t_e + tol)
    if out.any():
        i = int(np.flatnonzero(out)[0])
        raise ValueError(f"times[{i}] = {arr[i]} s is outside the exposure [{t_s}, {t_e}] s")
    return np.clip(arr, t_s, t_e), single


def edi_log_ratio(
    events: EventStream,
    exposure: tuple[float, float],  # seconds
    times: np.ndarray,  # [F] seconds inside the exposure
    c: tuple[float, float],
    impl: str = "fast",
    n_bins: int | None = None,
) -> tuple[np.ndarray, int]:
    """[F, H, W] float64 r_f = E(f) - log((1/T) integral exp(E(t)) dt), and the event count.

    The latent is L(f) = (B + eps) exp(r_f) - eps. ``impl`` is "fast" (numba), "reference"
    (numpy per pixel) or "binned" (needs ``n_bins``: E sampled at bin centres).
    """
    t_s, t_e = exposure
    H, W = events.height, events.width
    t0_us, t1_us = t_s * 1e6, t_e * 1e6
    if t1_us <= t0_us:
        return np.zeros((len(times), H, W)), 0
    i0 = int(np.searchsorted(events.t, np.int64(math.ceil(t0_us - 1e-6)), side="left"))
    i1 = int(np.searchsorted(events.t, np.int64(math.ceil(t1_us - 1e-6)), side="left"))
    i1 = max(i0, i1)
    if i1 == i0:
        return np.zeros((len(times), H, W)), 0
    order = np.argsort(times, kind="stable")
    inst = np.asarray(times, np.float64)[order] * 1e6
    args = (events.t[i0:i1], events.x[i0:i1], events.y[i0:i1], events.p[i0:i1], W, H, t0_us, t1_us, inst, c[0], c[1])
    if impl == "binned":
        if not n_bins or n_bins < 1:
            raise ValueError("impl='binned' needs n_bins >= 1")
        logmean, Ef = edi_pass_binned(*args, n_bins=int(n_bins))
    elif impl in _IMPLS:
        logmean, Ef = _IMPLS[impl](*args)
    else:
        raise ValueError(f"impl must be one of 'fast', 'reference', 'binned', got {impl!r}")
    r_sorted = Ef - logmean[None, :]
    r = np.empty_like(r_sorted)
    r[order] = r_sorted
    return r.reshape(len(times), H, W), i1 - i0


def latent_from_ratio(
    b: np.ndarray,  # [H, W, D] float64
    r: np.ndarray,  # [F, H, W] float64 log ratios
    saturation: float = SATURATION,
) -> tuple[np.ndarray, np.ndarray]:
    """[F, H, W, D] latents L = (B + eps) exp(r) - eps clipped to [0, 1]; saturated pixels keep B."""
    # exp of a huge r would overflow; anything above log(2 / eps) is clipped to 1 anyway
    r_c = np.minimum(r, math.log(2.0 / LOG_EPS))
    lat = (b[None] + LOG_EPS) * np.exp(r_c)[..., None] - LOG_EPS
    sat = (b >= saturation).any(axis=-1)  # [H, W]
    if sat.any():
        lat[:, sat, :] = b[sat][None]
    return np.clip(lat, 0.0, 1.0), sat


def deblur(
    blur: Any,  # [H, W] or [H, W, D], linear [0, 1], numpy or torch
    exposure: tuple[float, float],  # (t_start, t_end) seconds, on the events' clock
    events: EventStream,
    times: float | Sequence[float] | None = None,  # None: mid-exposure; a float; or [F] instants
    c: float | tuple[float, float] | None = None,  # None: estimated from this frame
    *,
    impl: str = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    return_report: bool = False,
):
    """Sharp latent image(s) of a blurry frame from the events of its exposure (EDI).

    Args:
        blur: [H, W] or [H, W, D] linear intensity in [0, 1] (numpy or torch).
        exposure: (t_start, t_end) in seconds, on the clock of ``events``.
        events: the stream; only events with t_start <= t < t_end are used.
        times: None (mid-exposure), one instant, or a sequence of F instants (seconds, inside
            the exposure). A sequence gives [F, H, W(, D)].
        c: contrast threshold: a float, (c_pos, c_neg), or None to estimate it from this
            frame with ``estimate_c``.
        impl: "fast" (numba, exact), "reference" (numpy, exact) or "binned" (``n_bins``).
        saturation: blurry pixels at or above it are returned unchanged and reported.
        return_report: also return a ``DeblurReport``.

    Returns:
        [H, W(, D)] or [F, H, W(, D)] latents in [0, 1], the input's kind: torch float32 for a
        tensor, numpy float64 otherwise; same trailing layout as ``blur``. A sharp frame
        (t_start == t_end) or a frame without events returns B.

    Convention: L(f) = (B + eps) / ((1/T) integral exp(E(t) - E(f)) dt) - eps, eps = LOG_EPS.
    """
    if not isinstance(events, EventStream):
        raise TypeError(f"events must be an edi.EventStream, got {type(events).__name__}")
    b, is_torch = _check_image(blur, "blur", events)
    t_s, t_e = _check_exposure(exposure)
    inst, single = _check_times(times, t_s, t_e)
    c_report = None
    if c is None:
        from .contrast import estimate_c  # local: contrast imports this module

        if t_e > t_s and len(events.slice_time(t_s, t_e)) > 0:
            c_est, c_report = estimate_c(b, np.array([t_s, t_e]), events, return_report=True)
            cc = (c_est, c_est)
        else:
            cc = (1.0, 1.0)  # unused: no events, B is returned
    else:
        cc = parse_c(c)
    r, n_ev = edi_log_ratio(events, (t_s, t_e), inst, cc, impl=impl, n_bins=n_bins)
    lat, sat = latent_from_ratio(b, r, saturation)
    if not np.isfinite(lat).all():  # internal invariant: inputs were finite, exp was clipped
        raise FloatingPointError("deblur produced a non-finite latent; please report this")
    if np.ndim(blur) == 2:
        lat = lat[..., 0]
    if single:
        lat = lat[0]
    if is_torch:
        import torch

        lat = torch.from_numpy(lat.astype(np.float32))
    if return_report:
        notes = []
        if t_e == t_s:
            notes.append("sharp frame (t_start == t_end): returned B")
        elif n_ev == 0:
            notes.append("no events in the exposure: returned B")
        return lat, DeblurReport(c=cc, num_events=n_ev, saturated=sat, c_report=c_report, notes=notes)
    return lat
