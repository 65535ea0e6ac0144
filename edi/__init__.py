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
    deblur(blur, exposure, events, times=None, c=None, gamma=1.0) -> [H, W(, D)] | [F, H, W(, D)]
    estimate_c(frames, exposures, events, pair=False, gamma=1.0, return_report=False)
        -> float | Contrast (pair=True), and a ContrastReport
    medi(frames, exposures, events, c=None) -> [F, H, W(, D)]
    moving_texture(...) -> SyntheticSequence        # seeded synthetic ground truth
"""
from .contrast import ContrastReport, estimate_c
from .deblur import DeblurReport, deblur
from .errors import CorruptFileError, EbadError, EventError, InputError
from .events import EventStream, events_in_window, seconds_to_us
from .io import AedatRecording, infer_time_unit, read_aedat4, read_events
from .medi import medi
from .model import LOG_EPS, SATURATION, Contrast, apply_gamma, linearize, parse_c
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
    "DeblurReport",
    "estimate_c",
    "ContrastReport",
    "medi",
    "read_events",
    "read_aedat4",
    "AedatRecording",
    "infer_time_unit",
]
