"""EDI: the Event-based Double Integral (Pan et al., CVPR 2019), exact and one-pass.

With the event model of ``edi.model`` the latent at an instant f of the exposure is

    L(f) = (B + eps) / ((1/T) integral exp(E(t) - E(f)) dt) - eps
         = (B + eps) * exp(E(f) - log((1/T) integral exp(E(t)) dt)) - eps.

E(t) is piecewise constant between events, so the integral is an exact sum over the
inter-event intervals of every pixel, and one pass over the events serves all instants.
With eps = 0 this is the EDI paper's L = B T / integral exp(c E); eps keeps a black
pixel black (0, not NaN) and bounds the gain on dark pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeAlias, overload

import numpy as np
import numpy.typing as npt

from .contrast import ContrastReport, estimate_contrast
from .errors import InputError
from .events import EventStream, events_in_window
from .model import (
    LOG_EPS,
    SATURATION,
    ColourFromMosaic,
    Contrast,
    ContrastLike,
    EdiImpl,
    ImageArray,
    apply_gamma,
    check_cfa,
    check_exposure,
    check_gamma,
    check_image,
    check_times,
    colour_latents,
    edi_log_ratio,
    latent_from_ratio,
    linearize_saturated,
    parse_c,
    to_mosaic,
)

if TYPE_CHECKING:
    import torch

__all__ = ["LOG_EPS", "SATURATION", "deblur", "deblur_with_report", "DeblurReport"]

#: how ``deblur`` makes the colour latent of an RGB frame with a cfa from its mosaic's per-pixel
#: latents (``model.colour_latents``). Against the true sharp RGB of ``moving_texture(cfa="RGGB")``
#: (40 x 56, true c, 3 runs of seeds 0-4) "latents" gave 21.73 / 21.69 / 21.66 dB, "ratio" 21.66 /
#: 21.78 / 21.57 (the blurry frame 13.7, events as luminance 11.2, the demosaic of the true sharp
#: mosaic 23.2): a tie within 0.1 dB; "pixel" gives 12.3 there (its channels are independent
#: random textures, the worst case for it). On the ray-cast colour-DAVIS world (``scenes.make_scene(
#: "boxes", cfa="RGGB")``, realistic sensor, 10 frames, c given) "pixel" gives 22.63 dB, "latents"
#: 20.58, the blurry frames 19.73 (tests/edi/test_cfa_pixel_colour.py), and ebad's novel views follow
#: (docs/results.md, colour DAVIS). Natural scenes' channels are correlated (the hue is locally
#: constant, the assumption of every demosaic), so "pixel" is the default.
COLOUR_FROM_MOSAIC: ColourFromMosaic = "pixel"

#: the instants of ``deblur``: None (mid-exposure), one instant, or [F] instants, seconds
Times: TypeAlias = "float | Sequence[float] | np.ndarray | torch.Tensor | None"


@dataclass
class DeblurReport:
    """What ``deblur_with_report`` did besides the image."""

    c: Contrast  # (c_pos, c_neg) used
    num_events: int  # events inside the exposure
    saturated: np.ndarray  # [H, W] bool: pixels left as B because B >= SATURATION (any channel)
    c_report: ContrastReport | None = None  # the estimator's report when c was estimated
    notes: list[str] = field(default_factory=list)


@overload
def deblur(
    blur: np.ndarray,
    exposure: npt.ArrayLike,
    events: EventStream,
    times: Times = None,
    c: ContrastLike | None = None,
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> np.ndarray: ...


@overload
def deblur(
    blur: torch.Tensor,
    exposure: npt.ArrayLike,
    events: EventStream,
    times: Times = None,
    c: ContrastLike | None = None,
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> torch.Tensor: ...


def deblur(
    blur: ImageArray,  # [H, W] or [H, W, D], linear [0, 1], numpy or torch
    exposure: npt.ArrayLike,  # (t_start, t_end) seconds, on the events' clock
    events: EventStream,
    times: Times = None,  # None: mid-exposure; a float; or [F] instants
    c: ContrastLike | None = None,  # None: estimated from this frame
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> ImageArray:
    """Sharp latent image(s) of a blurry frame from the events of its exposure (EDI).

    Args:
        blur: [H, W] or [H, W, D] linear intensity in [0, 1] (numpy or torch). Unsigned
            integer images are divided by their dtype's maximum (uint8 by 255, uint16 by
            65535); floats outside [0, 1], signed integers and booleans raise ``InputError``.
        exposure: (t_start, t_end) in seconds, on the clock of ``events``.
        events: the stream; only events with t_start <= t < t_end are used.
        times: None (mid-exposure), one instant, or a sequence of F instants (seconds, inside
            the exposure). A sequence gives [F, H, W(, D)].
        c: contrast threshold: a float, (c_pos, c_neg) (e.g. an ``edi.Contrast``), or None to
            estimate it from this frame with ``estimate_contrast`` (``deblur_with_report``'s
            report holds that estimator's report, which says whether the estimate is
            trustworthy: ``reliable``, ``at_bound``, ``explained``).
        impl: "fast" (numba, exact), "reference" (numpy, exact) or "binned" (``n_bins``).
        saturation: blurry pixels at or above it are returned unchanged and reported.
        gamma: the frame's response, recorded = irradiance ** gamma (1: linear). The frame is
            linearised, deblurred (blur is a mean of irradiance, events see its log) and the
            latent mapped back, so the output is in the frame's recorded units; ``c`` is then
            in log-irradiance units (an estimate with ``gamma`` = 1 on a non-linear frame
            reads about gamma x c, c in the frame's units, see ``estimate_c``).

    Returns:
        [H, W(, D)] or [F, H, W(, D)] latents in [0, 1], the input's kind: torch float32 for a
        tensor, numpy float64 otherwise; same trailing layout as ``blur``. A sharp frame
        (t_start == t_end) or a frame without events returns B.

    Convention: L(f) = (B + eps) / ((1/T) integral exp(E(t) - E(f)) dt) - eps, eps = LOG_EPS.
    """
    return deblur_with_report(
        blur, exposure, events, times, c, impl=impl, n_bins=n_bins, saturation=saturation, gamma=gamma, cfa=cfa
    )[0]


@overload
def deblur_with_report(
    blur: np.ndarray,
    exposure: npt.ArrayLike,
    events: EventStream,
    times: Times = None,
    c: ContrastLike | None = None,
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> tuple[np.ndarray, DeblurReport]: ...


@overload
def deblur_with_report(
    blur: torch.Tensor,
    exposure: npt.ArrayLike,
    events: EventStream,
    times: Times = None,
    c: ContrastLike | None = None,
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> tuple[torch.Tensor, DeblurReport]: ...


def deblur_with_report(
    blur: ImageArray,  # [H, W] or [H, W, D], linear [0, 1], numpy or torch
    exposure: npt.ArrayLike,  # (t_start, t_end) seconds, on the events' clock
    events: EventStream,
    times: Times = None,  # None: mid-exposure; a float; or [F] instants
    c: ContrastLike | None = None,  # None: estimated from this frame
    *,
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
    saturation: float = SATURATION,
    gamma: float = 1.0,
    cfa: str | None = None,
) -> tuple[ImageArray, DeblurReport]:
    """``deblur`` (the same arguments and latents) and a ``DeblurReport`` of what it did: the c
    used, the events in the exposure, the saturated pixels, the estimator's report when c was
    estimated, and notes (a sharp frame, no events)."""
    if not isinstance(events, EventStream):
        raise TypeError(f"events must be an edi.EventStream, got {type(events).__name__}")
    if not (0.0 < float(saturation) <= 1.0):
        raise InputError(f"saturation must be in (0, 1], got {saturation!r}")
    b, is_torch = check_image(blur, "blur", events)
    gamma = check_gamma(gamma)
    cfa = check_cfa(cfa)
    rgb = b  # with a cfa, EDI runs on the mosaic and the colour latent comes from it at the end
    if cfa is not None:
        b = to_mosaic(b, cfa, "blur")
    t_s, t_e = check_exposure(exposure)
    inst, single = check_times(times, t_s, t_e)
    c_report = None
    if c is None:
        i0, i1 = events_in_window(events, t_s, t_e)
        if t_e > t_s and i1 > i0:
            c_report = estimate_contrast(b, np.array([t_s, t_e]), events, gamma=gamma, cfa=cfa)
            cc = parse_c(c_report.c.mean)
        else:
            cc = Contrast(1.0, 1.0)  # unused: no events, B is returned
    else:
        cc = parse_c(c)
    r, n_ev = edi_log_ratio(events, (t_s, t_e), inst, cc, impl=impl, n_bins=n_bins)
    # irradiance in, recorded values out; the saturation rule applies to the recorded values
    lin_b, sat_lin = linearize_saturated(b, gamma, saturation)
    lat, sat = latent_from_ratio(lin_b, r, sat_lin)
    lat = apply_gamma(lat, gamma)
    if cfa is not None and rgb.shape[-1] == 3:
        lin_rgb, sat_lin = linearize_saturated(rgb, gamma, saturation)
        lat, sat = colour_latents(lin_rgb, r, lat, cfa, gamma, sat_lin, COLOUR_FROM_MOSAIC)
    if not np.isfinite(lat).all():  # internal invariant: inputs were finite, exp was clipped
        raise FloatingPointError("deblur produced a non-finite latent; please report this")
    if np.ndim(blur) == 2:
        lat = lat[..., 0]
    if single:
        lat = lat[0]
    notes = []
    if t_e == t_s:
        notes.append("sharp frame (t_start == t_end): returned B")
    elif n_ev == 0:
        notes.append("no events in the exposure: returned B")
    report = DeblurReport(c=cc, num_events=n_ev, saturated=sat, c_report=c_report, notes=notes)
    if is_torch:
        import torch

        return torch.from_numpy(lat.astype(np.float32)), report
    return lat, report
