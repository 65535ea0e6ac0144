"""The training data: a capture prepared for the loop, with every "skip" decision made once.

``prepare(capture, cfg) -> TrainingData`` validates the capture, finds the training frames'
poses (the capture's, pycolmap SfM, or a static camera), chooses V per frame, estimates the
contrast threshold, sums the events between virtual instants and computes the EDI latents.
What it decided is the typed ``PrepareReport`` (written to ``metrics.json``).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal, cast, get_args

import numpy as np
import torch
from torch import Tensor

from edi import EventStream, seconds_to_us

from .config import Config
from .errors import UserError
from .gaussians import scene_scale
from .trajectory import virtual_instants
from .virtual_views import choose_num_views, event_counts, events_per_pixel

if TYPE_CHECKING:
    from scenes import Capture, TestView

log = logging.getLogger(__name__)

__all__ = [
    "TrainingData",
    "PrepareReport",
    "PoseSourceUsed",
    "PoseTrust",
    "ContrastSource",
    "prepare",
    "downscale",
    "focus_depth",
    "depth_range",
    "align_poses",
    "test_poses",
    "FOCUS_DEPTH_RANGE",
    "SPREAD_DEPTH_RANGE",
    "STATIC_SPREAD",
    "STATIC_DEPTH_RANGE",
    "STILL_CHANGED",
    "changed_fraction",
    "structured_events_per_pixel",
    "sharp_views",
    "SUPPORT_US",
    "EdiTables",
    "edi_tables",
    "EDI_SCALES",
]

# Intrinsics outside this horizontal/vertical field of view (degrees) are taken for a mistake
# (focal length in the wrong unit, or of another image size): no scene can be seen through them.
MIN_FOV_DEG, MAX_FOV_DEG = 1.0, 170.0
# 3D needs parallax: fewer posed training frames than this cannot place a Gaussian in depth.
MIN_TRAIN_FRAMES = 2

# The initial depth range when neither the config nor SfM points give one, as factors of:
FOCUS_DEPTH_RANGE = (0.4, 2.5)  # the depth of the point the optical axes converge on (inward-facing captures)
SPREAD_DEPTH_RANGE = (0.5, 2.0)  # the camera-spread scene scale (forward-facing captures: no such point)
# Cameras whose centres spread less than this (scene units, ``scene_scale``) did not move (a tripod,
# --trajectory.pose_source static): their spread sets no depth (it would start the scene within 5x
# the rasteriser's 0.01 near plane), so the depth range is the prior STATIC_DEPTH_RANGE instead, in
# front of the camera, and the scene scale is 1 (the geometric mean of that range).
STATIC_SPREAD = 0.1
STATIC_DEPTH_RANGE = (0.5, 2.0)
# A capture without poses (pose_source auto) whose frames all look like its first is a camera that did not move,
# posed as --trajectory.pose_source static without running SfM (which cannot register it and would spend a minute
# or more finding so): at most this fraction of the pixels of any training frame differs from the first frame's
# beyond their noise (``changed_fraction``). Measured: the static street recording 0.021 (its moving cars);
# moving cameras 0.53-0.75 (synthetic scenes, grey and RGB, seeds 0-2), 0.39-0.46 (their raw Bayer mosaics),
# 0.92 (slider_depth's slider).
STILL_CHANGED = 0.1


PoseSourceUsed = Literal["capture", "colmap", "static"]  # where a run's mid-exposure poses came from
PoseTrust = Literal["exact", "approximate", "none"]  # how far they are trusted
ContrastSource = Literal["config", "edi.estimate_c"]  # where the contrast thresholds came from


@dataclass
class PrepareReport:
    """What ``prepare`` decided (every "skip what the scene does not need" decision)."""

    pose_source: PoseSourceUsed  # where the mid-exposure poses came from: capture | colmap | static
    pose_trust: PoseTrust  # how far they are trusted: exact | approximate (capture.pose_trust; SfM: approximate)
    train_frames: int  # frames trained on
    channels: int  # D: 1 renders one channel (grey capture), 3 colour
    views: list[int]  # V per training frame (1: sharp, no trajectory)
    renders_per_pass: int  # sum of V: renders of one pass over the frames
    renders_without_skip: int  # what a pass would cost with the configured V for every frame
    c: tuple[float, float] | None = None  # contrast thresholds (c_pos, c_neg) in use (None: no events used)
    c_source: ContrastSource | None = None  # config | edi.estimate_c
    skipped: str | None = None  # a loss switched off for lack of data, and why
    events_per_pixel: list[float] | None = None  # events during each exposure per sensor pixel
    anchored_mid_poses: bool | None = None  # the trajectories keep the given mid-exposure poses
    # training frames with an exposure of non-zero length but no event in it (they train as sharp frames)
    frames_without_events: list[str] | None = None
    # events during each exposure per pixel that a neighbour's event supports (``structured_events_per_pixel``):
    # what decides sharpness, the sensor's isolated noise events left out
    structured_events_per_pixel: list[float] | None = None
    sharp_frames: int | None = None  # training frames given V = 1 (sharp)
    sharp_reason: str | None = None  # why those frames were treated as sharp
    # training frames SfM did not register: left out of training (a pose interpolated in time between
    # registered neighbours is not trusted to start a trajectory from)
    unregistered_frames: list[str] | None = None


#: the contrast scales s of ``EdiTables.logmean``: with a learnt response and a c estimated from the frames,
#: L_EDI's targets use c / gamma (``ebad.response.edi_targets``), here for gamma in [0.4, 2.5] (held at the
#: ends). Step 0.1: the linear interpolation's error in log((1/T) integral exp(s E)) is at most 0.1^2 / 8 x
#: the variance of E over the exposure (1.2e-3 for a pixel whose E spans 2, ten events of 0.2)
EDI_SCALES = tuple(round(0.4 + 0.1 * k, 4) for k in range(22))


@dataclass
class EdiTables:
    """What L_EDI's targets need to follow a learnt response (``ebad.response.edi_targets``): per
    training frame the events' log change E(u) at its target instants (the mid-exposure instant, or its
    V virtual instants when it has view latents) and the log mean of exp(s E(t)) over the exposure at
    the ``scales`` s, E in the units of ``TrainingData.c`` from the exposure's start."""

    scales: Tensor  # [K]
    e_at: list[Tensor]  # per frame [U, H, W] float32 (U = 1: mid-exposure; V: its virtual instants)
    logmean: list[Tensor]  # per frame [K, H, W] float32

    def targets(self, f: int, blurry: Tensor, response, c_recorded: bool) -> Tensor:  # -> [U, H, W, D]
        """Frame ``f``'s L_EDI targets for ``response``'s current curve (``blurry`` [H, W, D] its frame), detached:
        they follow the curve but pull on it only through the render (with their gradient the black level drifted
        from 0 to 0.17 on the realistic sensor, gamma 0.861, and the deblurred frames lost 0.7 dB)."""
        from edi import SATURATION

        from .response import edi_targets

        with torch.no_grad():
            return edi_targets(response, blurry, self.e_at[f], self.logmean[f], self.scales, c_recorded, SATURATION)

    def pooled(self, factor: int) -> EdiTables:
        """The tables at 1/``factor`` of the resolution (block means: the coarse phase's approximation)."""
        return dataclasses.replace(
            self, e_at=[_pool(e, factor) for e in self.e_at], logmean=[_pool(m, factor) for m in self.logmean]
        )


def edi_tables(
    exposures: np.ndarray,  # [F, 2] seconds
    events: EventStream,
    c: tuple[float, float],
    instants: list[list[float]],  # per frame its target instants (seconds)
    scales: tuple[float, ...],
) -> EdiTables:
    """``EdiTables`` of the frames: one EDI pass (``edi.model.edi_log_ratio``) per frame and scale."""
    from edi.model import edi_log_ratio

    e_at, logmean = [], []
    for f, times in enumerate(instants):
        ex = (float(exposures[f, 0]), float(exposures[f, 1]))
        start = np.array([ex[0]])
        lm = np.stack([-edi_log_ratio(events, ex, start, (s * c[0], s * c[1]))[0][0] for s in scales])
        r1 = edi_log_ratio(events, ex, np.asarray(times, np.float64), c)[0]  # E(u) - logmean(1)
        # + logmean(1): the table's own row when scale 1 is in it (s * c is then c exactly)
        e = r1 + (lm[scales.index(1.0)] if 1.0 in scales else -edi_log_ratio(events, ex, start, c)[0][0])
        e_at.append(torch.from_numpy(e.astype(np.float32)))
        logmean.append(torch.from_numpy(lm.astype(np.float32)))
    return EdiTables(torch.tensor(scales, dtype=torch.float32), e_at, logmean)


@dataclass
class TrainingData:
    """Everything the loop needs, precomputed from a capture (training frames only)."""

    frames: Tensor  # [F, H, W, D] blurry training frames
    targets: Tensor  # [F, H, W, D] what L_blur compares to (frames or EDI latents)
    latents: Tensor | None  # [F, H, W, D] EDI latents at mid-exposure, or None (no L_EDI)
    exposures: np.ndarray  # [F, 2] seconds
    names: list[str]
    c2w: Tensor  # [F, 4, 4] initial mid-exposure poses
    K: Tensor  # [3, 3]
    V: np.ndarray  # [F] virtual views per frame
    ev_counts: list[Tensor | None]  # per frame [V - 1, 2, H, W] ON/OFF counts between virtual instants, or None
    c: tuple[float, float] | None  # contrast thresholds (c_pos, c_neg) in use (None: no events used)
    scale: float  # scene scale (world units)
    depth_range: tuple[float, float]
    report: PrepareReport
    points: Tensor | None = None  # [P, 3] SfM points, when any
    point_colors: Tensor | None = None  # [P, D]
    test_views: list[TestView] = field(default_factory=list)  # the capture's test views that carry an image
    test_c2w: dict[str, np.ndarray] = field(default_factory=dict)  # their poses in this run's frame, by name
    events: EventStream | None = (
        None  # the events of L_ev and of the views' latents (kept to count them again when V changes)
    )
    # per frame [V, H, W, D] EDI latents at its virtual instants (loss.edi_instants views; None for a sharp
    # frame), else None
    view_latents: list[Tensor | None] | None = None
    # a colour DAVIS's Bayer pattern (capture.cfa, edi.cfa), or None; with it the model renders RGB
    cfa: str | None = None
    # [H, W, 3] the losses' cfa weights at this data's resolution (ebad.losses.cfa_weights: one-hot at the sensor's,
    # the blocks' channel fractions after ``downscale``): L_ev on each pixel's own channel, and L_blur / L_EDI through
    # ``losses.cfa_project`` when the frames are one-channel mosaics; None: no cfa, or loss.cfa_events luminance
    cfa_weights: Tensor | None = None
    # with a learnt response (model.response), L_EDI's targets follow the curve (``EdiTables``; per-frame EDI only)
    edi_tables: EdiTables | None = None

    @property
    def c_recorded(self) -> bool:
        """The contrast thresholds are in the recorded frames' log units: estimated from the frames
        (``edi.estimate_c`` on the recorded, possibly non-linear values, where a response
        b + (1 - b) (g E)^gamma shows gamma x c_true). A configured c (``loss.contrast``) is the
        events' own, log irradiance. With a learnt response L_ev compares in the units of c
        (``ebad.loop``, ``ebad.response``)."""
        return self.report.c_source == "edi.estimate_c"

    @property
    def channels(self) -> int:
        """The channels the model renders: 3 for a colour DAVIS (whatever its frames), else the frames'."""
        return 3 if self.cfa is not None else int(self.frames.shape[-1])

    @property
    def raw_mosaic(self) -> bool:
        """The frames (and targets, latents) are one-channel Bayer mosaics: L_blur and L_EDI compare the render's."""
        return self.cfa is not None and int(self.frames.shape[-1]) == 1

    @property
    def init_images(self) -> Tensor:
        """[F, H, W, channels] the images the Gaussians' colours start from: the latents (else the
        targets), demosaiced (``edi.cfa.demosaic``) when they are raw mosaics."""
        src = self.latents if self.latents is not None else self.targets
        if self.raw_mosaic and self.cfa is not None and src.shape[-1] == 1:
            from edi.cfa import demosaic

            return torch.from_numpy(np.ascontiguousarray(demosaic(src[..., 0].numpy(), self.cfa), dtype=np.float32))
        return src

    def set_views(self, V: np.ndarray) -> None:
        """New V per frame, in place: the event counts between the new virtual instants are
        counted again for the frames that have counts, and the report follows."""
        V = np.asarray(V, dtype=np.int64)
        if V.shape != self.V.shape or (V < 1).any() or ((V > 1) != (self.V > 1)).any():
            raise ValueError(
                f"new V {V.tolist()} must keep each frame's sharp (1) or blurry (> 1) status of {self.V.tolist()}"
            )
        changed = np.flatnonzero(V != self.V)
        needs_events = any(
            self.ev_counts[f] is not None or (self.view_latents is not None and self.view_latents[f] is not None)
            for f in changed
        )
        if needs_events and self.events is None:
            raise ValueError("the event counts and latents cannot follow a new V: the data keep no events")
        counts = list(self.ev_counts)
        views = None if self.view_latents is None else list(self.view_latents)
        for f in changed:
            if counts[f] is not None:
                assert self.events is not None  # needs_events, checked above
                counts[f] = event_counts(self.events, self.exposures[f], int(V[f]))
            if views is not None and views[f] is not None:
                assert self.events is not None  # needs_events, checked above
                assert self.c is not None  # view latents are made from events, and c with them (prepare)
                views[f] = view_latents(
                    self.frames[f].numpy(), self.exposures[f], self.events, int(V[f]), self.c, cfa=self.cfa
                )
                if self.edi_tables is not None:  # the targets' instants follow
                    e = edi_tables(
                        self.exposures[f : f + 1],
                        self.events,
                        self.c,
                        [_view_times(self.exposures[f], int(V[f]))],
                        (1.0,),
                    )
                    self.edi_tables.e_at[f] = e.e_at[0]
        self.V, self.ev_counts, self.view_latents = V, counts, views
        self.report.views, self.report.renders_per_pass = V.tolist(), int(V.sum())

    @property
    def height(self) -> int:
        return int(self.frames.shape[1])

    @property
    def width(self) -> int:
        return int(self.frames.shape[2])

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])


MIN_DOWNSCALED_SIDE = 8  # ``downscale`` refuses (and the coarse phase skips) frames smaller than this a side after it


def _pool(x: Tensor, factor: int) -> Tensor:  # [..., H, W] -> [..., H // factor, W // factor]
    lead = x.shape[:-2]
    y = torch.nn.functional.avg_pool2d(x.reshape(-1, 1, *x.shape[-2:]), factor)
    return y.reshape(*lead, *y.shape[-2:])


def _pool_hwd(x: Tensor, factor: int) -> Tensor:  # [F, H, W, D] -> [F, H // factor, W // factor, D]
    return _pool(x.permute(0, 3, 1, 2), factor).permute(0, 2, 3, 1).contiguous()


def downscale(data: TrainingData, factor: int) -> TrainingData:
    """The same training problem at 1/``factor`` of the resolution (the coarse phase of
    ``train.coarse_scale``): frames, targets and latents area-averaged over ``factor`` x
    ``factor`` blocks (the top-left H // factor x W // factor of them), event counts as the mean
    count per pixel of a block, intrinsics scaled (pixel centres at +0.5, so u' = u / factor).
    A colour DAVIS's ``cfa_weights`` become each block's channel fractions (1/4 R, 1/2 G, 1/4 B):
    L_ev compares a block's mean count with the fraction-weighted log change of the render's
    channels, L_blur / L_EDI a raw frame's block mean with the same weighting of the render
    (``ebad.losses``). Poses, V, c and the test views are shared with ``data`` (test views are
    scored at full size)."""
    if factor == 1:
        return data
    if factor < 1 or min(data.height, data.width) < MIN_DOWNSCALED_SIDE * factor:
        raise ValueError(f"cannot downscale {data.width} x {data.height} frames by {factor}")
    K = data.K.clone()
    K[:2] /= factor
    return dataclasses.replace(
        data,
        frames=_pool_hwd(data.frames, factor),
        targets=_pool_hwd(data.targets, factor),
        latents=None if data.latents is None else _pool_hwd(data.latents, factor),
        K=K,
        view_latents=None
        if data.view_latents is None
        else [None if v is None else _pool_hwd(v, factor) for v in data.view_latents],
        ev_counts=[None if e is None else _pool(e, factor) for e in data.ev_counts],
        cfa_weights=None if data.cfa_weights is None else _pool_hwd(data.cfa_weights[None], factor)[0],
        edi_tables=None if data.edi_tables is None else data.edi_tables.pooled(factor),
    )


def _pose_trust(trust: str) -> PoseTrust:
    """``Capture.effective_pose_trust`` (a capture checks it is one of ``PoseTrust``) as the report's type."""
    if trust not in get_args(PoseTrust):
        raise ValueError(f"pose trust must be one of {get_args(PoseTrust)}, got {trust!r}")
    return cast(PoseTrust, trust)


def _edi_at(
    frame: np.ndarray,  # [H, W, D] one blurry frame
    exposure: np.ndarray,
    events: EventStream,
    c: tuple[float, float],
    times: list[float],
    cfa: str | None = None,
) -> np.ndarray:
    """EDI latents of one frame at ``times`` (seconds), in one pass: [len(times), H, W, D], in [0, 1].

    ``cfa``: the capture's Bayer pattern (``Capture.cfa``): EDI per pixel of the mosaic (``edi.deblur``)."""
    import edi

    lat = edi.deblur(frame, (float(exposure[0]), float(exposure[1])), events, times=times, c=c, cfa=cfa)
    return np.clip(np.asarray(lat, dtype=np.float32).reshape(len(times), *frame.shape), 0, 1)


def _view_times(exposure: np.ndarray, V: int) -> list[float]:  # the V virtual instants in seconds
    t0, t1 = float(exposure[0]), float(exposure[1])
    return (t0 + virtual_instants(V, dtype=torch.float64) * (t1 - t0)).tolist()


def _target_instants(exposure: np.ndarray, views: bool, V: int) -> list[float]:
    """The instants of a frame's L_EDI targets (seconds): its V virtual instants, or mid-exposure."""
    return _view_times(exposure, V) if views else [0.5 * (float(exposure[0]) + float(exposure[1]))]


def view_latents(
    frame: np.ndarray,  # [H, W, D] one blurry frame
    exposure: np.ndarray,
    events: EventStream,
    V: int,
    c: tuple[float, float],
    cfa: str | None = None,
) -> Tensor:  # [V, H, W, D]
    """EDI latents of one frame at its V virtual instants (``virtual_instants``), in [0, 1]."""
    return torch.from_numpy(_edi_at(frame, exposure, events, c, _view_times(exposure, V), cfa))


def _train_indices(capture: Capture) -> list[int]:
    if not capture.split:
        return list(range(capture.num_frames))
    idx = [i for i, s in enumerate(capture.split) if s == "train"]
    if not idx:
        raise UserError("capture has no frame with split 'train'")
    return idx


def _check_capture(capture: Capture) -> None:
    """The capture is well formed (``Capture.validate``: shapes, dtypes, ranges, rigid poses) and its
    intrinsics can see a scene."""
    capture.validate()
    K = np.asarray(capture.K, dtype=np.float64)
    H, W = capture.height, capture.width
    fov = np.degrees(2 * np.arctan2(np.array([W, H]) / 2.0, np.abs(np.array([K[0, 0], K[1, 1]]))))
    if not (np.all(np.isfinite(fov)) and np.all(fov > MIN_FOV_DEG) and np.all(fov < MAX_FOV_DEG)):
        raise UserError(
            f"capture intrinsics: fx = {K[0, 0]:g}, fy = {K[1, 1]:g} give a field of view of "
            f"{fov[0]:.3g} x {fov[1]:.3g} degrees on {W} x {H} pixels, outside "
            f"({MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}); the focal lengths are in pixels"
        )
    if not (0 <= K[0, 2] <= W and 0 <= K[1, 2] <= H):
        raise UserError(
            f"capture intrinsics: principal point ({K[0, 2]:g}, {K[1, 2]:g}) lies outside the {W} x {H} image"
        )


def frames_without_events(events: EventStream, exposures: np.ndarray, names: list[str]) -> list[str]:
    """The names of the frames (exposures [F, 2] seconds) whose exposure lasts but holds no event of
    ``events`` (a stream with events). When no exposure holds any, ``UserError`` naming the
    exposure times and the events' time span: the events' times are in another unit or offset."""
    lasting = np.flatnonzero(exposures[:, 1] > exposures[:, 0])
    empty = [int(f) for f in lasting if np.subtract(*events.window(exposures[f, 0], exposures[f, 1])) == 0]
    if lasting.size and len(empty) == lasting.size:
        ex = ", ".join(f"[{a:.6g}, {b:.6g}]" for a, b in exposures[lasting[:4]])
        more = f" ... ({lasting.size} frames)" if lasting.size > 4 else ""
        t = np.asarray(events.t)
        raise UserError(
            f"capture: none of the {lasting.size} training exposures holds an event: exposures {ex}{more} s, "
            f"events from {t[0] * 1e-6:.6g} to {t[-1] * 1e-6:.6g} s ({len(t)} events); the events' times are "
            "likely in another unit or offset (capture.json: events.t_unit, events.t0_us, frames[].t_start)"
        )
    return [names[f] for f in empty]


#: background-activity filter: an event carries structure when one of its 8 neighbouring pixels fired within this
#: many microseconds of it (before or after). The realistic sensor's noise (about 1.1 events per pixel and second)
#: passes at about 8 x 1.1 x 2 x 5 ms = 9%: a still camera's 0.07 noise events per pixel in 50 ms leave 0.006
SUPPORT_US = 5000
#: at most this many events of one exposure are tested (evenly strided; the count is scaled back)
SUPPORT_SAMPLE = 50_000


def structured_events_per_pixel(
    events: EventStream,
    exposures: np.ndarray,  # [F, 2] seconds
    support_us: int = SUPPORT_US,
) -> np.ndarray:  # [F]
    """Events during each exposure that one of their 8 neighbouring pixels' events supports (within
    ``support_us`` before or after), per sensor pixel: a background-activity filter. Shot, leak and
    hot-pixel noise fires alone and is left out; a moving edge fires along itself and stays. Each
    exposure's events are tested against the events of [t_start - support_us, t_end + support_us),
    sorted once by (pixel, time); at most ``SUPPORT_SAMPLE`` of them, evenly strided."""
    W, H = events.width, events.height
    out = np.zeros(len(exposures))
    offsets = [(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dx or dy]
    for f, (a, b) in enumerate(np.asarray(exposures, np.float64)):
        i0, i1 = events.window(a, b)
        if i1 == i0:
            continue
        j0, j1 = events.index_range(seconds_to_us(a) - support_us, seconds_to_us(b) + support_us)
        t = events.t[j0:j1].astype(np.int64)
        pix = events.y[j0:j1].astype(np.int64) * W + events.x[j0:j1]
        span = (
            int(t[-1] - t[0]) + 2 * support_us + 1
        )  # keys pixel * span + time: one pixel's times never overlap another's
        tt = t - t[0] + support_us
        keys = np.sort(pix * span + tt)
        step = max(1, -(-(i1 - i0) // SUPPORT_SAMPLE))
        q = np.arange(i0 - j0, i1 - j0, step)
        q = q[np.argsort(pix[q] * span + tt[q], kind="stable")]  # by key: each neighbour's keys come sorted too,
        qx, qy, qt = pix[q] % W, pix[q] // W, tt[q]  # which searchsorted finds faster
        ok = np.zeros(len(q), bool)
        for dx, dy in offsets:
            nx, ny = qx + dx, qy + dy
            inside = (nx >= 0) & (nx < W) & (ny >= 0) & (ny < H)
            nk = (ny * W + nx) * span + qt
            pos = np.minimum(np.searchsorted(keys, nk - support_us), len(keys) - 1)
            ok |= inside & (keys[pos] >= nk - support_us) & (keys[pos] <= nk + support_us)
        out[f] = ok.sum() * (i1 - i0) / len(q) / (W * H)
    return out


def sharp_views(
    exposures: np.ndarray,  # [F, 2] seconds
    events: EventStream | None,
    num_views: int,
    adaptive: bool = True,
    sharp_events_per_pixel: float = 0.05,
) -> tuple[np.ndarray, list[float] | None, str]:
    """V per frame (``choose_num_views``), a frame being sharp (V = 1) when its exposure is empty or,
    with ``adaptive`` and events, when fewer than ``sharp_events_per_pixel`` of its events per pixel
    carry structure (``structured_events_per_pixel``: a still camera's noise events do not make it
    blurry). Returns (V [F], the structured events per pixel or None, why the sharp frames are sharp)."""
    exposures = np.asarray(exposures, dtype=np.float64)
    V = choose_num_views(exposures, events if adaptive else None, num_views, adaptive, sharp_events_per_pixel)
    structured: np.ndarray | None = None
    if adaptive and events is not None and len(events) > 0:
        structured = structured_events_per_pixel(events, exposures)
        V[structured < sharp_events_per_pixel] = 1
    empty = int((exposures[:, 1] <= exposures[:, 0]).sum())
    n = int((V == 1).sum())
    parts = [f"{empty} with an empty exposure"] if empty else []
    if structured is not None:
        quiet = int(((V == 1) & (exposures[:, 1] > exposures[:, 0])).sum())
        if quiet:
            raw = events_per_pixel(events, exposures)[V == 1]  # type: ignore[arg-type]  # events is set here
            parts.append(
                f"{quiet} with fewer than {sharp_events_per_pixel:g} structured events per pixel (events with a "
                f"neighbour's within {SUPPORT_US / 1000:g} ms; {raw.mean():.3g} events per pixel before this filter)"
            )
    elif adaptive and events is not None and n > empty:
        parts.append(f"{n - empty} as the event sensor saw nothing: the camera did not move")
    why = f"{n} of {len(V)} frames sharp" + (": " + "; ".join(parts) if parts and n else "")
    return V, None if structured is None else [round(float(v), 4) for v in structured], why


def changed_fraction(frames: np.ndarray, mosaic: bool = False) -> float:  # [F, H, W, D]
    """The largest fraction, over the frames, of a frame's pixels that differ from the first frame's by
    more than 3 standard deviations of the two frames' noise plus 0.01 (channel means; 2 x 2 block means
    of raw Bayer mosaics, ``mosaic``, whose filter pattern is no noise). A frame's noise
    is estimated robustly from its 2 x 2 second differences (their median absolute value / 0.6745 / 2:
    the difference of four pixels of noise sigma has deviation 2 sigma), so texture inflates it a
    little and never lowers it. 0 for a single frame."""
    f = np.asarray(frames, dtype=np.float32).mean(axis=-1)
    if mosaic:
        f = _pool(torch.from_numpy(f), 2).numpy()
    if len(f) < 2:
        return 0.0
    d2 = f[:, 1:, 1:] - f[:, :-1, 1:] - f[:, 1:, :-1] + f[:, :-1, :-1]
    sigma = np.median(np.abs(d2), axis=(1, 2)) / 0.6745 / 2
    tau = 3 * np.sqrt(sigma[0] ** 2 + sigma[1:] ** 2) + 0.01
    return float(max((np.abs(f[k] - f[0]) > tau[k - 1]).mean() for k in range(1, len(f))))


def _poses(capture: Capture, cfg: Config, idx: list[int]):
    """Mid-exposure poses of the training frames, SfM points and test-view poses when SfM ran."""
    src = cfg.trajectory.pose_source
    usable = capture.c2w is not None and (src == "capture" or capture.effective_pose_trust != "none")
    if src in ("auto", "capture") and usable:
        return np.asarray(capture.c2w, dtype=np.float64)[idx], None, None, "capture", idx, {}
    if src == "capture":
        raise UserError("--trajectory.pose_source is 'capture' but the capture has no poses (c2w)")
    if src == "auto" and len(idx) >= MIN_TRAIN_FRAMES:  # (one frame: nothing to compare, SfM says what it needs)
        changed = changed_fraction(np.asarray(capture.frames)[idx], mosaic=capture.raw_mosaic)
        if changed <= STILL_CHANGED:
            log.warning(
                "the camera did not move: at most %.1f%% of the pixels of any frame differ from the first frame "
                "beyond their noise (a moving camera changes more than %.0f%%); every frame starts at one pose, as "
                "with --trajectory.pose_source static (--trajectory.pose_source colmap runs SfM anyway)",
                100 * changed,
                100 * STILL_CHANGED,
            )
            src = "static"
    if src == "static":
        return np.repeat(np.eye(4)[None], len(idx), axis=0), None, None, "static", idx, {}
    from scenes.colmap import ColmapConfig, SfMError, estimate_poses

    try:  # every test image is registered with the frames: its pose is then in this run's frame
        est = estimate_poses(capture, ColmapConfig(test_views="all"))
    except SfMError as exc:
        raise SfMError(f"{exc} (for a camera that did not move, use --trajectory.pose_source static)") from exc
    keep = [i for i in idx if est.registered[i]]
    if len(keep) < 2:
        raise SfMError(
            f"pycolmap registered only {len(keep)} training frame(s); cannot reconstruct "
            "(for a camera that did not move, use --trajectory.pose_source static)"
        )
    pts = torch.from_numpy(np.asarray(est.points, dtype=np.float32)) if len(est.points) else None
    cols: Tensor | None = None
    if pts is not None:
        rgb = np.asarray(est.colors, dtype=np.float32)
        if rgb.max() > 1.0:
            rgb = rgb / 255.0
        if capture.channels == 1 and capture.cfa is None and rgb.shape[1] == 3:  # a raw mosaic's model is RGB
            rgb = rgb.mean(1, keepdims=True)
        cols = torch.from_numpy(rgb)
    return np.asarray(est.c2w, dtype=np.float64)[keep], pts, cols, "colmap", keep, dict(est.test_c2w)


def align_poses(
    ref_src: np.ndarray,  # [N, 4, 4] cameras in the frame the poses are in
    ref_dst: np.ndarray,  # [N, 4, 4] the same cameras in the target frame
    poses: np.ndarray,  # [..., 4, 4]
) -> np.ndarray:  # [..., 4, 4]
    """``poses`` moved into the target frame by the Sim(3) (Umeyama) that maps ``ref_src`` onto ``ref_dst``."""
    from scenes.colmap import align_similarity, apply_similarity

    return apply_similarity(poses, *align_similarity(ref_src, ref_dst))


def test_poses(
    capture: Capture,
    pose_source: str,
    idx: list[int],
    c2w: np.ndarray,  # [F, 4, 4] the run's train poses
    registered: dict[str, np.ndarray],
) -> dict[str, np.ndarray]:
    """The pose of every test view with an image, in the run's frame, by name: SfM's registration
    when there is one; else the capture's pose, as it is when the run uses the capture's poses, or
    moved by the Sim(3) between the capture's training poses and the run's (SfM) ones."""
    out: dict[str, np.ndarray] = {}
    for v in capture.test_views:
        if v.image is None:
            continue
        if v.name in registered:
            out[v.name] = np.asarray(registered[v.name], dtype=np.float64)
        elif v.c2w is not None and pose_source in ("capture", "static"):
            out[v.name] = np.asarray(v.c2w, dtype=np.float64)
        elif v.c2w is not None and capture.c2w is not None and len(idx) >= 2:
            out[v.name] = align_poses(np.asarray(capture.c2w, np.float64)[idx], c2w, np.asarray(v.c2w, np.float64))
    return out


def depth_range(
    cfg: Config,
    c2w: np.ndarray,  # [F, 4, 4]
    points: Tensor | None,
) -> tuple[float, float]:  # [P, 3]
    """The depth range of the fallback initialisation: the config's, else the 5th-95th percentile
    of SfM point depths, else ``FOCUS_DEPTH_RANGE`` x the focus depth, else ``SPREAD_DEPTH_RANGE``
    x the camera-spread scale, or ``STATIC_DEPTH_RANGE`` when the cameras spread less than
    ``STATIC_SPREAD`` (they did not move). (A synthetic scene's true depth range is never read.)"""
    if cfg.model.init_depth is not None:
        near, far = cfg.model.init_depth
        return float(near), float(far)
    if points is not None and len(points) > 0:
        R, t = c2w[:, :3, :3], c2w[:, :3, 3]
        z = np.einsum("fji,fnj->fni", R, points.numpy()[None] - t[:, None])[..., 2]
        z = z[z > 0]
        if z.size:
            return float(np.percentile(z, 5)), float(np.percentile(z, 95))
    d0 = focus_depth(c2w)
    if d0 is not None:
        return FOCUS_DEPTH_RANGE[0] * d0, FOCUS_DEPTH_RANGE[1] * d0
    s = scene_scale(c2w)
    if s < STATIC_SPREAD:
        return STATIC_DEPTH_RANGE
    return SPREAD_DEPTH_RANGE[0] * s, SPREAD_DEPTH_RANGE[1] * s


def focus_depth(c2w: np.ndarray) -> float | None:  # [F, 4, 4]
    """Median depth of the point the optical axes point at (least squares), or None when the
    axes are near parallel (forward-facing captures) or the point is not in front of them."""
    a = c2w[:, :3, 2]
    cen = c2w[:, :3, 3]
    P = np.eye(3)[None] - a[:, :, None] * a[:, None, :]  # [F, 3, 3]
    A = P.sum(0)
    b = np.einsum("fij,fj->i", P, cen)
    w = np.linalg.eigvalsh(A)
    if w[0] < 1e-3 * len(c2w):  # ill-conditioned: near parallel axes
        return None
    p = np.linalg.solve(A, b)
    z = np.einsum("fi,fi->f", p[None] - cen, a)
    if (z <= 0).any():
        return None
    return float(np.median(z))


def prepare(capture: Capture, cfg: Config) -> TrainingData:
    """Validate the capture and make every "skip what is not needed" decision (``TrainingData.report``)."""
    import time

    from .progress import Ticker, say

    show = cfg.train.progress
    _check_capture(capture)
    idx = _train_indices(capture)
    t0 = time.perf_counter()
    say(show, f"poses of {len(idx)} training frames (trajectory.pose_source {cfg.trajectory.pose_source})")
    wanted, all_names = idx, capture.frame_names()
    c2w, points, point_colors, pose_src, idx, registered = _poses(capture, cfg, idx)
    say(show, f"poses: {pose_src}, {len(idx)} frames ({time.perf_counter() - t0:.1f} s)")
    kept = set(idx)
    unregistered = [all_names[i] for i in wanted if i not in kept] or None
    if unregistered:
        log.warning(
            "SfM did not register %d of %d training frames; they are left out of training and of the deblurred "
            "frames (rather than started from poses interpolated in time): %s",
            len(unregistered),
            len(wanted),
            ", ".join(unregistered),
        )
    if len(idx) < MIN_TRAIN_FRAMES:
        raise UserError(
            f"the capture has {len(idx)} training frame(s) with a pose; a 3D scene needs at least "
            f"{MIN_TRAIN_FRAMES} (for one frame, 'ebad deblur' gives its sharp image)"
        )
    frames_np = np.asarray(capture.frames, dtype=np.float32)[idx]
    exposures = np.asarray(capture.exposures, dtype=np.float64)[idx]
    events = capture.events
    has_events = events is not None and len(events) > 0
    lc, tc = cfg.loss, cfg.trajectory
    wants_events = lc.w_event > 0 or lc.w_edi > 0 or lc.target == "edi"
    use_events = wants_events and has_events
    names = [all_names[i] for i in idx]
    no_events: list[str] | None = None
    if has_events:
        no_events = frames_without_events(events, exposures, names)
        if no_events:
            log.warning(
                "capture: %d of %d training frames hold no event in their exposure window and train as sharp "
                "frames: %s",
                len(no_events),
                len(idx),
                ", ".join(no_events),
            )

    c: tuple[float, float] | None = None
    c_source: ContrastSource | None = None
    if use_events:
        if lc.contrast is not None:
            c, c_source = (float(lc.contrast[0]), float(lc.contrast[1])), "config"
        else:
            import edi

            t0 = time.perf_counter()
            say(show, f"estimating the contrast threshold from {len(idx)} frames and {len(events)} events")
            est = edi.estimate_c(frames_np, exposures, events, pair=True, cfa=capture.cfa)
            c, c_source = (float(est[0]), float(est[1])), "edi.estimate_c"
            say(show, f"c = ({c[0]:.3f}, {c[1]:.3f}) ({time.perf_counter() - t0:.1f} s)")

    t0 = time.perf_counter()
    V, structured, sharp_why = sharp_views(
        exposures, events, tc.num_views, tc.adaptive_views, tc.sharp_events_per_pixel
    )
    if tc.kind == "fixed":  # no motion model: one render per frame whatever the blur
        V[:] = 1
        sharp_why = f"{len(V)} of {len(V)} frames sharp: trajectory.kind is 'fixed' (one render per frame)"
    say(show, f"{sharp_why} ({time.perf_counter() - t0:.1f} s)")
    report = PrepareReport(
        pose_source=pose_src,
        pose_trust=_pose_trust(capture.effective_pose_trust)
        if pose_src == "capture"
        else ("exact" if pose_src == "static" else "approximate"),
        train_frames=len(idx),
        channels=3 if capture.cfa is not None else int(frames_np.shape[-1]),
        views=V.tolist(),
        renders_per_pass=int(V.sum()),
        renders_without_skip=int(tc.num_views * len(V)),
        c=c,
        c_source=c_source,
        skipped="no events: L_ev and L_EDI off, EDI target = frames" if wants_events and not has_events else None,
        events_per_pixel=([round(float(v), 4) for v in events_per_pixel(events, exposures)] if has_events else None),
        frames_without_events=no_events,
        structured_events_per_pixel=structured,
        sharp_frames=int((V == 1).sum()),
        sharp_reason=sharp_why,
        unregistered_frames=unregistered,
    )

    latents: Tensor | None = None
    views: list[Tensor | None] | None = None
    tables: EdiTables | None = None
    if use_events and (lc.w_edi > 0 or lc.target == "edi"):
        import edi

        assert c is not None  # set above whenever use_events

        if lc.edi_prior == "medi":  # all training frames jointly, at their exposure centres
            say(show, f"mEDI latents of {len(idx)} frames")
            medi_lat = edi.medi(frames_np, exposures, events, c=c, cfa=capture.cfa)
            lat = np.asarray(medi_lat, dtype=np.float32).reshape(frames_np.shape)
        else:  # per frame, one EDI pass for the mid-exposure latent and (loss.edi_instants views) the views'
            lat, views = [], ([] if lc.w_edi > 0 and lc.edi_instants == "views" else None)
            tick = Ticker(show, "EDI latents", len(idx))
            for f in range(len(idx)):
                t0, t1 = exposures[f]
                extra = _view_times(exposures[f], int(V[f])) if views is not None and V[f] > 1 else []
                out = _edi_at(frames_np[f], exposures[f], events, c, [0.5 * (t0 + t1)] + extra, capture.cfa)
                lat.append(out[0])
                if views is not None:
                    views.append(torch.from_numpy(out[1:]) if extra else None)
                tick(f + 1)
        latents = torch.from_numpy(np.clip(np.stack(lat), 0, 1))  # mEDI's are not clipped yet
        if cfg.model.response != "linear" and lc.w_edi > 0 and lc.edi_prior == "edi":
            tables = edi_tables(
                exposures,
                events,
                c,
                [
                    _target_instants(exposures[f], views is not None and views[f] is not None, int(V[f]))
                    for f in range(len(idx))
                ],
                EDI_SCALES if c_source == "edi.estimate_c" else (1.0,),
            )
    frames_t = torch.from_numpy(frames_np)
    targets = latents if (lc.target == "edi" and latents is not None) else frames_t
    ev = [
        event_counts(events, exposures[f], int(V[f])) if (use_events and lc.w_event > 0 and V[f] > 1) else None
        for f in range(len(idx))
    ]
    d_range = depth_range(cfg, c2w, points)
    return _with_cfa(
        capture,
        cfg,
        TrainingData(
            frames=frames_t,
            targets=targets,
            latents=latents if lc.w_edi > 0 else None,
            exposures=exposures,
            names=names,
            c2w=torch.from_numpy(c2w).float(),
            K=torch.from_numpy(np.asarray(capture.K, dtype=np.float32)),
            V=V,
            ev_counts=ev,
            c=c,
            scale=scene_scale(c2w, d_range),
            depth_range=d_range,
            report=report,
            points=points,
            point_colors=point_colors,
            test_views=[v for v in capture.test_views if v.image is not None],
            test_c2w=test_poses(capture, pose_src, idx, c2w, registered),
            events=events if use_events and (lc.w_event > 0 or views is not None) else None,
            view_latents=views,
            edi_tables=tables,
        ),
    )


def _with_cfa(capture: Capture, cfg: Config, data: TrainingData) -> TrainingData:
    """``data`` of a colour DAVIS capture (``capture.cfa``): its pattern and the losses' cfa weights
    (None with ``loss.cfa_events luminance`` and RGB frames: today's events of the channel mean);
    with ``loss.cfa_frames mosaic`` RGB frames, targets and latents become their mosaics (each
    pixel's own channel, exact for a camera's demosaic that keeps it, as bilinear does)."""
    if capture.cfa is None:
        return data
    from edi.cfa import mosaic

    from .losses import cfa_weights

    lc = cfg.loss
    pattern = data.cfa = capture.cfa
    raw = data.frames.shape[-1] == 1
    if lc.cfa_frames == "mosaic" and not raw:

        def m(x: Tensor) -> Tensor:
            return mosaic(x, pattern)[..., None].contiguous()

        data.frames, data.targets = m(data.frames), m(data.targets)
        data.latents = None if data.latents is None else m(data.latents)
        data.view_latents = (
            None if data.view_latents is None else [None if v is None else m(v) for v in data.view_latents]
        )
        raw = True
    if raw or lc.cfa_events == "filter":
        data.cfa_weights = cfa_weights(pattern, data.height, data.width)
    return data
