"""edi: event streams and the Event-based Double Integral (Pan et al., CVPR 2019).

Public API::

    EventStream, EventError, InputError, EbadError  # validated event arrays; the errors
    seconds_to_us(t) -> int | int64 array           # the one seconds -> us conversion (nearest, ties even)
    events_in_window(events, t0, t1) -> (i0, i1)    # the one window rule: t0 <= t < t1
    read_events(path, t_unit=None, width=None, height=None, return_unit=False) -> EventStream
    read_aedat4(path) -> AedatRecording(events, frames, exposures, t0)
    LOG_EPS, SATURATION                             # log(I + LOG_EPS); saturated pixels
    Contrast(pos, neg), parse_c(c)                  # a threshold pair; float | pair -> Contrast
    linearize(img, gamma), apply_gamma(img, gamma)  # recorded = irradiance ** gamma, both ways
    deblur(blur, exposure, events, times=None, c=None, gamma=1.0, cfa=None) -> [H, W(, D)] | [F, H, W(, D)]
        (numpy in, numpy out; torch in, torch out)
    deblur_with_report(...same...) -> (latents, DeblurReport)
    estimate_c(frames, exposures, events, pair=False, gamma=1.0, cfa=None) -> Contrast   # .mean: the one c
    estimate_contrast(...same...) -> ContrastReport  # .c, .reliable, .message, ...
    medi(frames, exposures, events, c=None, cfa=None) -> [F, H, W(, D)]
    moving_texture(..., cfa=None) -> SyntheticSequence  # seeded synthetic ground truth (cfa: a colour DAVIS)
    cfa: a colour DAVIS's Bayer pattern ("RGGB", ...): each pixel's events follow its own channel, so
        EDI, mEDI and the c estimate work per pixel of the frames' mosaic (RGB frames demosaiced
        by the camera's software, or raw mosaics); RGB in, demosaiced latents out; raw in, raw out
    edi.cfa: CFA_PATTERNS, channel_map, mosaic, demosaic, transform_pattern  # colour DAVIS Bayer filter
"""

from .contrast import ContrastReport, estimate_c, estimate_contrast
from .deblur import DeblurReport, deblur, deblur_with_report
from .errors import CorruptFileError, EbadError, EventError, InputError
from .events import EventStream, events_in_window, seconds_to_us
from .io import AedatRecording, infer_time_unit, read_aedat4, read_events
from .medi import medi
from .model import LOG_EPS, SATURATION, Contrast, ContrastLike, ImageArray, apply_gamma, linearize, parse_c
from .moving_texture import moving_texture

__all__ = [
    "EventStream",
    "EbadError",
    "EventError",
    "CorruptFileError",
    "InputError",
    "Contrast",
    "parse_c",
    "linearize",
    "apply_gamma",
    "events_in_window",
    "moving_texture",
    "seconds_to_us",
    "LOG_EPS",
    "SATURATION",
    "deblur",
    "deblur_with_report",
    "DeblurReport",
    "estimate_c",
    "estimate_contrast",
    "ContrastLike",
    "ImageArray",
    "ContrastReport",
    "medi",
    "read_events",
    "read_aedat4",
    "AedatRecording",
    "infer_time_unit",
]
