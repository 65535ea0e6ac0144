"""The event model both EDI and the contrast estimators rest on, and the checks of their inputs.

Convention: intensities are linear in [0, 1]; events fire on changes of log(I + LOG_EPS);
c is in natural-log units, one value or a pair (c_pos for p = +1, c_neg for p = -1). Between
instants f and t

    I(t) + eps = (I(f) + eps) * exp(E(t) - E(f)),   E(t) = c_pos * N+(T0, t) - c_neg * N-(T0, t)

and the blurry frame is the mean over the exposure, B = (1/T) integral I(t) dt. Hence

    L(f) = (B + eps) * exp(r_f) - eps,   r_f = E(f) - log((1/T) integral exp(E(t)) dt).

``edi_log_ratio`` computes r_f (one pass over the exposure's events), ``latent_from_ratio``
the latent. ``deblur``, ``estimate_c`` and ``medi`` are built on these two.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, TypeAlias

import numpy as np

from ._kernels import edi_pass, edi_pass_binned, edi_pass_reference
from .cfa import check_pattern, demosaic, mosaic
from .errors import InputError
from .events import EventStream, events_in_window, seconds_to_us

if TYPE_CHECKING:
    import torch

__all__ = [
    "LOG_EPS",
    "SATURATION",
    "Contrast",
    "parse_c",
    "check_exposure",
    "check_image",
    "check_frames",
    "check_times",
    "edi_log_ratio",
    "latent_from_ratio",
    "check_gamma",
    "linearize",
    "linearize_saturated",
    "apply_gamma",
    "ImageArray",
    "ContrastLike",
    "EdiImpl",
    "check_cfa",
    "to_mosaic",
    "colour_latents",
    "ColourFromMosaic",
]

#: Offset in log(I + LOG_EPS) for linear intensities in [0, 1]: a black pixel has log
#: intensity log(1e-3) = -6.9 instead of -inf; used by the event model everywhere in edi
#: (and by event simulators that want to be consistent with it).
LOG_EPS: float = 1e-3

#: A blurry pixel at or above this linear value is saturated: its true mean intensity is
#: unknown, so EDI leaves it as it is (the pixel is listed in ``DeblurReport.saturated``).
SATURATION: float = 0.99

#: Float images may exceed [0, 1] by this much (rounding in the caller's arithmetic); they
#: are clipped. Anything further out is refused.
RANGE_TOL: float = 1e-6

#: the range a response exponent (``gamma``) may take: recorded = irradiance ** gamma
GAMMA_RANGE = (0.2, 5.0)

#: an image or a stack of images as the public functions take them: numpy (floats in [0, 1] or
#: unsigned integers, ``to_unit_range``) or a torch tensor (on the CPU or not; read, never kept)
ImageArray: TypeAlias = "np.ndarray | torch.Tensor"
#: a contrast threshold as the public functions take it: one c, or (c_pos, c_neg) (``parse_c``)
ContrastLike: TypeAlias = "float | tuple[float, float] | Contrast"
#: the EDI pass: "fast" (numba, exact), "reference" (numpy, exact), "binned" (``n_bins`` bins)
EdiImpl = Literal["fast", "reference", "binned"]

#: how a colour latent is made from the per-pixel latents of a CFA frame's mosaic (``colour_latents``)
ColourFromMosaic = Literal["latents", "ratio", "pixel"]

_IMPLS = {"fast": edi_pass, "reference": edi_pass_reference}


class Contrast(NamedTuple):
    """A contrast-threshold pair in natural-log units: ``pos`` for p = +1 events, ``neg``
    for p = -1. A tuple, so it goes wherever (c_pos, c_neg) does (``deblur(c=...)``)."""

    pos: float
    neg: float

    @property
    def mean(self) -> float:
        """(pos + neg) / 2, the single c that moves the log intensity by the same amount per
        balanced pair of events."""
        return 0.5 * (self.pos + self.neg)


def parse_c(c: Any, name: str = "c") -> Contrast:
    """A float or a (c_pos, c_neg) pair -> ``Contrast``, validated (finite, > 0)."""
    if isinstance(c, (tuple, list, np.ndarray)) or (hasattr(c, "shape") and getattr(c, "ndim", 0) == 1):
        try:
            vals = [float(v) for v in c]
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be a float or a pair (c_pos, c_neg), got {c!r}") from exc
        if len(vals) != 2:
            raise InputError(f"{name} must be a float or a pair (c_pos, c_neg), got {len(vals)} values")
    else:
        try:
            vals = [float(c)] * 2
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be a float or a pair (c_pos, c_neg), got {c!r}") from exc
    for v in vals:
        if not math.isfinite(v) or v <= 0:
            raise InputError(f"{name} must be finite and > 0, got {c!r}")
    return Contrast(vals[0], vals[1])


def check_exposure(exposure: Any, name: str = "exposure") -> tuple[float, float]:
    """(t_start, t_end) seconds, finite, t_end >= t_start."""
    try:
        t_s, t_e = (float(v) for v in np.asarray(exposure, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be (t_start, t_end) in seconds, got {exposure!r}") from exc
    if not (math.isfinite(t_s) and math.isfinite(t_e)):
        raise InputError(f"{name} must be finite, got ({t_s}, {t_e})")
    if t_e < t_s:
        raise InputError(f"{name} ends before it starts: t_end {t_e} < t_start {t_s}")
    return t_s, t_e


def to_unit_range(img: Any, name: str) -> np.ndarray:
    """An image (numpy or torch, any shape) -> float64 numpy in [0, 1].

    Convention: unsigned integer images are divided by their dtype's maximum (uint8 by 255,
    uint16 by 65535, ...: the range a camera or PNG writes); float images must already be
    linear intensity in [0, 1] (values within ``RANGE_TOL`` outside are clipped). Anything
    else (signed integers, booleans, floats outside [0, 1]) raises ``InputError`` naming
    ``name`` and the range found.
    """
    if hasattr(img, "detach") and type(img).__module__.startswith("torch"):
        img = img.detach().cpu().numpy()
    a = np.asarray(img)
    if a.dtype.kind == "u":
        return a.astype(np.float64) / float(np.iinfo(a.dtype).max)
    if a.dtype.kind != "f":
        raise InputError(
            f"{name} has dtype {a.dtype}: pass an unsigned integer image (uint8, uint16: divided by "
            f"the dtype's maximum) or floats in [0, 1]"
        )
    a = a.astype(np.float64)
    finite = np.isfinite(a)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        raise InputError(f"{name} has a non-finite value at {tuple(int(i) for i in bad)}")
    if a.size:
        lo, hi = float(a.min()), float(a.max())
        if lo < -RANGE_TOL or hi > 1.0 + RANGE_TOL:
            raise InputError(
                f"{name} must be linear intensity in [0, 1], found values in [{lo:.6g}, {hi:.6g}] "
                f"(divide 8-bit data by 255, 16-bit by 65535, or pass the integer array)"
            )
        a = np.clip(a, 0.0, 1.0)
    return a


def check_image(img: Any, name: str, events: EventStream | None) -> tuple[np.ndarray, bool]:
    """img [H, W] or [H, W, D] -> (float64 [H, W, D] in [0, 1], whether it was a torch tensor).

    The size must match the events' sensor when ``events`` is given."""
    is_torch = hasattr(img, "detach") and type(img).__module__.startswith("torch")
    shape = tuple(np.shape(img))
    if len(shape) not in (2, 3):
        raise InputError(f"{name} must be [H, W] or [H, W, D], got shape {shape}")
    arr = to_unit_range(img, name)
    if arr.ndim == 2:
        arr = arr[..., None]
    if events is not None and (arr.shape[0], arr.shape[1]) != (events.height, events.width):
        raise InputError(
            f"{name} is {arr.shape[0]}x{arr.shape[1]} (HxW) but the events' sensor is {events.height}x{events.width}"
        )
    return arr, is_torch


def check_frames(frames: Any, exposures: Any, events: EventStream) -> tuple[np.ndarray, np.ndarray]:
    """frames [H, W(, D)] or [F, H, W(, D)] and exposures [2] or [F, 2] -> frames [F, H, W, D]
    float64 in [0, 1] (see ``to_unit_range``) and exposures [F, 2] seconds, checked."""
    ex = np.asarray(exposures, dtype=np.float64)
    shape = tuple(np.shape(frames))
    single = ex.ndim == 1
    if single:
        ex = ex[None]
    if ex.ndim != 2 or ex.shape[1] != 2:
        raise InputError(f"exposures must be [2] or [F, 2] seconds, got shape {tuple(ex.shape)}")
    # one frame: [H, W] or [H, W, D] matching the sensor; several: [F, H, W] or [F, H, W, D]
    one = len(shape) == 2 or (len(shape) == 3 and single and shape[:2] == (events.height, events.width))
    items = [frames] if one else [frames[i] for i in range(shape[0])] if len(shape) in (3, 4) else None
    if items is None or len(items) != ex.shape[0]:
        raise InputError(
            f"frames must be [H, W(, D)] or [F, H, W(, D)] matching exposures [F, 2]; got frames "
            f"{shape} and exposures {tuple(ex.shape)}"
        )
    fr = np.stack([check_image(f, f"frames[{i}]", events)[0] for i, f in enumerate(items)])
    for i in range(ex.shape[0]):
        check_exposure(ex[i], f"exposures[{i}]")
    return fr, ex


def check_times(times: Any, t_s: float, t_e: float) -> tuple[np.ndarray, bool]:
    """times -> [F] float64 seconds inside the exposure, and whether a single instant was asked for."""
    if times is None:
        return np.array([0.5 * (t_s + t_e)]), True
    if hasattr(times, "detach"):
        times = times.detach().cpu().numpy()
    arr = np.asarray(times, dtype=np.float64)
    single = arr.ndim == 0
    arr = arr.reshape(-1)
    if arr.size == 0:
        raise InputError("times must hold at least one instant")
    if not np.isfinite(arr).all():
        raise InputError(f"times must be finite, got {arr.tolist()}")
    tol = 1e-9 + 1e-12 * abs(t_e)
    out = (arr < t_s - tol) | (arr > t_e + tol)
    if out.any():
        i = int(np.flatnonzero(out)[0])
        raise InputError(f"times[{i}] = {arr[i]} s is outside the exposure [{t_s}, {t_e}] s")
    return np.clip(arr, t_s, t_e), single


def edi_log_ratio(
    events: EventStream,
    exposure: tuple[float, float],  # seconds
    times: np.ndarray,  # [F] seconds inside the exposure
    c: tuple[float, float],
    impl: EdiImpl = "fast",
    n_bins: int | None = None,
) -> tuple[np.ndarray, int]:
    """[F, H, W] float64 r_f = E(f) - log((1/T) integral exp(E(t)) dt), and the event count.

    The exposure is [seconds_to_us(t_start), seconds_to_us(t_end)) on the events' clock, and
    its events are those of ``events_in_window``. The latent is L(f) = (B + eps) exp(r_f) - eps.
    ``impl`` is "fast" (numba), "reference" (numpy per pixel) or "binned" (needs ``n_bins``:
    E sampled at bin centres).
    """
    t_s, t_e = exposure
    H, W = events.height, events.width
    t0_us, t1_us = seconds_to_us(t_s), seconds_to_us(t_e)
    if impl not in _IMPLS and impl != "binned":
        raise InputError(f"impl must be one of 'fast', 'reference', 'binned', got {impl!r}")
    if impl == "binned" and (not n_bins or n_bins < 1):
        raise InputError("impl='binned' needs n_bins >= 1")
    if t1_us <= t0_us:
        return np.zeros((len(times), H, W)), 0
    i0, i1 = events_in_window(events, t_s, t_e)
    if i1 == i0:
        return np.zeros((len(times), H, W)), 0
    order = np.argsort(times, kind="stable")
    inst = np.clip(np.asarray(times, np.float64)[order] * 1e6, t0_us, t1_us)
    args = (
        events.t[i0:i1],
        events.x[i0:i1],
        events.y[i0:i1],
        events.p[i0:i1],
        W,
        H,
        float(t0_us),
        float(t1_us),
        inst,
        float(c[0]),
        float(c[1]),
    )
    if impl == "binned":
        assert n_bins is not None  # checked above for impl="binned"
        logmean, Ef = edi_pass_binned(*args, n_bins=int(n_bins))
    else:
        logmean, Ef = _IMPLS[impl](*args)
    r_sorted = Ef - logmean[None, :]
    r = np.empty_like(r_sorted)
    r[order] = r_sorted
    return r.reshape(len(times), H, W), i1 - i0


def latent_from_ratio(
    b: np.ndarray,  # [H, W, D] float64
    r: np.ndarray,  # [F, H, W] float64 log ratios
    saturation: float = SATURATION,
) -> tuple[np.ndarray, np.ndarray]:
    """[F, H, W, D] latents L = (B + eps) exp(r) - eps clipped to [0, 1]; saturated pixels keep B.

    Also returns the [H, W] bool mask of saturated pixels (B >= saturation in any channel)."""
    # exp of a huge r would overflow; anything above log(2 / eps) is clipped to 1 anyway
    r_c = np.minimum(r, math.log(2.0 / LOG_EPS))
    lat = (b[None] + LOG_EPS) * np.exp(r_c)[..., None] - LOG_EPS
    sat = (b >= saturation).any(axis=-1)  # [H, W]
    if sat.any():
        lat[:, sat, :] = b[sat][None]
    return np.clip(lat, 0.0, 1.0), sat  # type: ignore[return-value]  # numpy stubs: any(axis=...) may be a scalar


def check_gamma(gamma: Any, name: str = "gamma") -> float:
    """The exponent of a power response (recorded = irradiance ** gamma), validated: finite and
    in ``GAMMA_RANGE``; 1 is linear."""
    try:
        g = float(gamma)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a number (recorded = irradiance ** {name}), got {gamma!r}") from exc
    if not (math.isfinite(g) and GAMMA_RANGE[0] <= g <= GAMMA_RANGE[1]):
        raise InputError(f"{name} must be in [{GAMMA_RANGE[0]}, {GAMMA_RANGE[1]}] (1: linear), got {gamma!r}")
    return g


def linearize(
    recorded: np.ndarray,  # [..., D] recorded values in [0, 1]
    gamma: float,
) -> np.ndarray:
    """Irradiance (relative, in [0, 1]) from values recorded through ``recorded = irradiance ** gamma``.

    Convention: blur averages irradiance and events see its log, so EDI and the contrast
    estimate work on ``linearize(frame, gamma)``; ``apply_gamma`` maps a latent back."""
    return recorded if gamma == 1.0 else np.power(recorded, 1.0 / gamma)


def linearize_saturated(
    recorded: np.ndarray,  # [..., D] recorded values in [0, 1]
    gamma: float,
    saturation: float = SATURATION,  # recorded units
) -> tuple[np.ndarray, float]:
    """``linearize(recorded, gamma)`` and the irradiance threshold t with the saturation rule kept on
    the recorded values: ``irradiance >= t`` exactly where ``recorded >= saturation``.

    The power is not strictly monotone in floating point (for gamma > 1 two neighbouring recorded
    values can give one irradiance), so a value just below ``saturation`` could be classed
    saturated after the transform; values at the edge are moved by one ulp to keep the rule."""
    if gamma == 1.0:
        return recorded, float(saturation)
    lin = linearize(recorded, gamma)
    t = linearize(np.asarray(saturation, dtype=lin.dtype), gamma)
    sat = recorded >= saturation
    return np.where(sat, np.maximum(lin, t), np.minimum(lin, np.nextafter(t, 0.0))), float(t)


def apply_gamma(
    irradiance: np.ndarray,  # [..., D] relative irradiance in [0, 1]
    gamma: float,
) -> np.ndarray:
    """Recorded values ``irradiance ** gamma`` (the inverse of ``linearize``)."""
    return irradiance if gamma == 1.0 else np.power(irradiance, gamma)


def check_cfa(cfa: Any, name: str = "cfa") -> str | None:
    """None or a Bayer pattern of ``edi.cfa`` (``InputError`` naming ``name`` otherwise)."""
    return None if cfa is None else check_pattern(cfa, name)


def to_mosaic(img: np.ndarray, cfa: str, name: str) -> np.ndarray:  # [..., H, W, D] -> [..., H, W, 1]
    """The mosaic a colour DAVIS recorded: each pixel's own channel of an RGB image (the camera's
    demosaic keeps it exactly), or a raw mosaic (D = 1) as it is; ``InputError`` naming ``name`` else."""
    D = img.shape[-1]
    if D == 1:
        return img
    if D != 3:
        raise InputError(f"{name}: with a cfa, frames must be RGB (3 channels) or a raw mosaic (1), got {D} channels")
    return np.asarray(mosaic(img, cfa))[..., None]


def colour_latents(
    b: np.ndarray,  # [H, W, 3] the blurry RGB frame, irradiance (linearised)
    r: np.ndarray,  # [F, H, W] per-pixel log ratios of the frame's mosaic (``edi_log_ratio``)
    lat_raw: np.ndarray,  # [F, H, W, 1] per-pixel latents of the mosaic, recorded units
    cfa: str,
    gamma: float,
    saturation: float,  # in irradiance units (``latent_from_ratio``)
    how: ColourFromMosaic = "latents",
) -> tuple[np.ndarray, np.ndarray]:
    """[F, H, W, 3] colour latents of a CFA frame (recorded units) and the [H, W] saturated mask.

    Each pixel's events follow its own channel, so the mosaic's per-pixel latents ``lat_raw`` are
    exact; the other two channels of a pixel have no events of their own. ``how``:

    * "latents": the per-pixel latents demosaiced (``edi.cfa.demosaic``, in recorded units as the
      camera software demosaics): the colour frame the camera would have given for the sharp mosaic;
    * "ratio": the per-pixel log ratios r demosaiced and applied to the blurry RGB frame,
      L_c = (B_c + eps) exp(r_c) - eps (each pixel's own channel is the same as with "latents");
    * "pixel": each pixel's own log ratio r applied to all three channels of the blurry RGB frame,
      L_c = (B_c + eps) exp(r) - eps: the ratio at full resolution, assuming the hue is locally
      constant over the exposure's motion (the assumption of every demosaic); measured best.
    """
    if how == "latents":
        lat = np.clip(demosaic(lat_raw[..., 0], cfa), 0.0, 1.0)
        return lat, (np.asarray(mosaic(b, cfa)) >= saturation)
    if how not in ("ratio", "pixel"):
        raise InputError(f"how must be 'latents', 'ratio' or 'pixel', got {how!r}")
    sat = np.asarray((b >= saturation).any(axis=-1))  # [H, W]
    r_c = demosaic(r, cfa) if how == "ratio" else np.repeat(np.asarray(r)[..., None], 3, -1)  # [F, H, W, 3]
    r_c = np.minimum(r_c, math.log(2.0 / LOG_EPS))
    lat = (b[None] + LOG_EPS) * np.exp(r_c) - LOG_EPS
    if sat.any():
        lat[:, sat, :] = b[sat][None]
    return apply_gamma(np.clip(lat, 0.0, 1.0), gamma), sat
