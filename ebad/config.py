"""Reconstruction settings as dataclasses, the preset registry and JSON round trips.

Every field carries a docstring (the string under it), which is also its command-line help:
the command line is generated from these dataclasses by tyro (``ebad.cli.reconstruct``), so
every field is an option (``--train.iters 300``, ``--model.init_depth 0.5 2.0``). ``Config`` nests one dataclass
per concern; each section's ``check()`` refuses values that cannot work, naming the option.
Presets are named functions in ``PRESETS`` returning a full ``Config``; a run saves the
resolved config as JSON beside its outputs, and ``config_from_dict`` reads it back (unknown
keys and values of the wrong type are errors that name the key; nothing is ``eval``-ed).
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from .errors import ConfigError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

__all__ = [
    "ModelConfig",
    "TrajectoryConfig",
    "LossConfig",
    "StrategyConfig",
    "TrainConfig",
    "Config",
    "PRESETS",
    "preset",
    "config_to_dict",
    "config_from_dict",
    "save_config",
    "load_config",
    "config_diff",
    "RESUMABLE_FIELDS",
]

Target = Literal["blurry", "edi"]
PoseSource = Literal["auto", "capture", "colmap", "static"]
TrajectoryKind = Literal["linear", "cubic", "fixed"]
StrategyKind = Literal["default", "none"]
EventWindows = Literal["consecutive", "random"]
EventNorm = Literal["l1", "l2"]
EdiPrior = Literal["edi", "medi"]
EdiInstants = Literal["mid", "views"]
CfaEvents = Literal["filter", "luminance"]
CfaFrames = Literal["rgb", "mosaic"]


def _require(ok: bool, option: str, problem: str) -> None:
    if not ok:
        raise ConfigError(f"--{option}: {problem}")


def _finite(section: DataclassInstance, prefix: str) -> None:
    """Every float field of ``section`` is finite (``--train.lr_means nan`` names the option)."""
    for f in dataclasses.fields(section):
        v = getattr(section, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"--{prefix}.{f.name}: must be a finite number, got {v}")
        if isinstance(v, tuple) and any(isinstance(x, float) and not math.isfinite(x) for x in v):
            raise ConfigError(f"--{prefix}.{f.name}: must be finite numbers, got {v}")


@dataclass
class ModelConfig:
    """The Gaussians and how they start."""

    init: Literal["stereo", "random"] = "stereo"
    """fallback without SfM points: plane-sweep stereo between the posed frames (gaussians.plane_sweep_points) or random
    depths along pixel rays"""
    init_points: int = 3000
    """Gaussians of the fallback initialisation (no SfM points)"""
    init_depth: tuple[float, float] | None = None
    """fallback depth range (near, far) in world units; None: from the focus point of the cameras' optical axes
    (FOCUS_DEPTH_RANGE x its depth), else SPREAD_DEPTH_RANGE x the camera-spread scale; cameras that did not move
    (spread < ebad.data.STATIC_SPREAD = 0.1, a tripod or pose_source static): STATIC_DEPTH_RANGE = (0.5, 2.0), scene
    scale 1"""
    init_opacity: float = 0.3
    """activated opacity of every initial Gaussian"""
    init_scale_px: float = 1.5
    """initial Gaussian radius in pixels at its depth (fallback init)"""
    min_sfm_points: int = 16
    """SfM point clouds with fewer points than this are ignored (fallback init instead)"""
    stereo_depths: int = 32
    """plane-sweep initialisation: depth planes, uniform in inverse depth"""
    stereo_neighbours: int = 2
    """plane-sweep initialisation: nearest frames each frame is compared with"""
    stereo_patch: int = 5
    """plane-sweep initialisation: side of the cost-averaging patch in pixels (odd)"""
    max_gaussians: int = 0
    """densification stops growing N beyond this; 0: AUTO_CAP_PER_PIXEL x pixels, clamped to AUTO_CAP_RANGE (2 x pixels
    in [4000, 60000])"""
    background: float = 0.0
    """background intensity (every channel), in [0, 1]"""
    response: Literal["linear", "gamma"] = "linear"
    """camera response from rendered irradiance to recorded values (ebad.response): linear, or black level + gain +
    gamma learnt with the scene"""
    lr_response: float = 1e-3
    """Adam learning rate of the response curve's parameters"""
    sh_degree: int = 0
    """view-dependent colour: spherical harmonics up to this degree (0..3, the INRIA / gsplat convention); 0: one
    colour per Gaussian. The higher coefficients start at 0 and learn at train.lr_colors / 20 (INRIA's ratio)"""
    sh_degree_interval: int = 1000
    """the SH degree used rises by one every this many steps (gsplat's sh_degree_interval), or every this fraction
    of 30000 steps (gsplat's default run) of the budget when that comes sooner: a run of 3000 steps raises it every
    100 (ebad.schedule)"""

    def check(self) -> None:
        _finite(self, "model")
        _require(self.init_points >= 1, "model.init_points", f"must be >= 1, got {self.init_points}")
        _require(0 < self.init_opacity < 1, "model.init_opacity", f"must be in (0, 1), got {self.init_opacity}")
        _require(self.init_scale_px > 0, "model.init_scale_px", f"must be > 0, got {self.init_scale_px}")
        if self.init_depth is not None:
            _require(
                len(self.init_depth) == 2 and 0 < self.init_depth[0] < self.init_depth[1],
                "model.init_depth",
                f"must be two depths 0 < near < far, got {self.init_depth}",
            )
        _require(self.min_sfm_points >= 1, "model.min_sfm_points", f"must be >= 1, got {self.min_sfm_points}")
        _require(self.stereo_depths >= 2, "model.stereo_depths", f"must be >= 2, got {self.stereo_depths}")
        _require(self.stereo_neighbours >= 1, "model.stereo_neighbours", f"must be >= 1, got {self.stereo_neighbours}")
        _require(
            self.stereo_patch >= 1 and self.stereo_patch % 2 == 1,
            "model.stereo_patch",
            f"must be an odd number >= 1, got {self.stereo_patch}",
        )
        _require(
            self.max_gaussians >= 0, "model.max_gaussians", f"must be >= 0 (0: automatic), got {self.max_gaussians}"
        )
        _require(0 <= self.background <= 1, "model.background", f"must be in [0, 1], got {self.background}")
        _require(self.lr_response >= 0, "model.lr_response", f"must be >= 0, got {self.lr_response}")
        _require(0 <= self.sh_degree <= 3, "model.sh_degree", f"must be in 0..3, got {self.sh_degree}")
        _require(
            self.sh_degree_interval >= 1, "model.sh_degree_interval", f"must be >= 1, got {self.sh_degree_interval}"
        )


@dataclass
class TrajectoryConfig:
    """Camera motion inside each exposure."""

    kind: TrajectoryKind = "cubic"
    """motion model (ebad.trajectory.TRAJECTORIES): linear | cubic | fixed (untrusted poses: a correction per frame)"""
    num_views: int = 5
    """V, virtual views per blurry exposure (uniform instants)"""
    adaptive_views: bool = True
    """V from event activity: a frame with few events renders V = 1"""
    sharp_events_per_pixel: float = 0.05
    """below this many events per pixel an exposure is sharp"""
    view_spacing: float = 0.0
    """> 0: at fraction train.coarse_until of the run (where the coarse phase ends), each blurry frame's V becomes its
    learnt image path length / view_spacing pixels, within [2, max_views] (ebad.virtual_views); 0: num_views throughout
    """
    max_views: int = 9
    """the most virtual views view_spacing gives a frame"""
    init_noise: float = 1e-3
    """std of the initial start/end perturbation (radians; x scene scale for translation) that breaks the zero-motion
    symmetry of the blur loss"""
    lr: float = 5e-4
    """Adam learning rate of the knots (radians; translations in scene-scale units); 2e-3 before, whose jitter kept
    noisy poses 4 dB (deblurred) from the truth (benchmarks/results/pose_lr_*.json)"""
    lr_final: float = 1.0
    """the knots' learning rate decays exponentially to this fraction of lr over the run (1: constant)"""
    average_from: float = 0.7
    """from this fraction of the run on, the knots' running mean is kept, and the run's trajectories (deblurred frames,
    exports) are that mean: it removes Adam's step-to-step jitter from the final poses (1: the last step's knots)"""
    anchor_mid: Literal["auto", "yes", "no"] = "auto"
    """keep the mid-exposure poses fixed and learn only the motion; auto: yes when the capture states its poses are
    exact (pose_trust), no for approximate poses and after SfM, which then optimise every frame's whole trajectory (a
    sharp frame's pose too)"""
    pose_source: PoseSource = "auto"
    """auto: capture poses when present and not marked pose_trust none, else static when the frames do not change
    beyond their noise (ebad.data.STILL_CHANGED), else pycolmap SfM; colmap: SfM regardless; static: a camera on a
    tripod (every frame at the identity pose)"""

    def check(self) -> None:
        _finite(self, "trajectory")
        _require(self.num_views >= 1, "trajectory.num_views", f"must be >= 1, got {self.num_views}")
        _require(
            self.sharp_events_per_pixel >= 0,
            "trajectory.sharp_events_per_pixel",
            f"must be >= 0, got {self.sharp_events_per_pixel}",
        )
        _require(
            self.view_spacing >= 0, "trajectory.view_spacing", f"must be >= 0 pixels (0: off), got {self.view_spacing}"
        )
        _require(self.max_views >= 2, "trajectory.max_views", f"must be >= 2, got {self.max_views}")
        _require(self.init_noise >= 0, "trajectory.init_noise", f"must be >= 0, got {self.init_noise}")
        _require(self.lr >= 0, "trajectory.lr", f"must be >= 0, got {self.lr}")
        _require(0 < self.lr_final <= 1, "trajectory.lr_final", f"must be in (0, 1], got {self.lr_final}")
        _require(
            0 <= self.average_from <= 1,
            "trajectory.average_from",
            f"must be in [0, 1] (1: off), got {self.average_from}",
        )


@dataclass
class LossConfig:
    """Which losses, against what, and their weights (the paper's: 1, 0.1, 1)."""

    target: Target = "blurry"
    """what L_blur compares to: the blurry frames or their EDI latents"""
    w_blur: float = 1.0
    """weight of L_blur (0.8 L1 + 0.2 (1 - SSIM) of the mean of V renders)"""
    w_event: float = 0.1
    """weight of L_ev (log-render differences vs c x events); 0 disables"""
    w_edi: float = 1.0
    """weight of L_EDI (renders vs EDI latents at their instants, loss.edi_instants); 0 disables"""
    ssim_weight: float = 0.2
    """the 0.2 in 0.8 L1 + 0.2 (1 - SSIM)"""
    ssim_window: int = 7
    """SSIM window (odd; small images need a small one)"""
    contrast: tuple[float, float] | None = None
    """event contrast thresholds (c_pos, c_neg) in natural-log units; None: estimated from the data (edi.estimate_c, one
    per polarity)"""
    learn_contrast: bool = False
    """refine (c_pos, c_neg) (as logs) jointly through L_ev. Off by default: c -> 0 with flat renders is a degenerate
    minimum of L_ev, and c drifts towards it while novel-view PSNR stays within run-to-run noise
    (benchmarks/learn_contrast.py)"""
    lr_contrast: float = 1e-2
    """Adam learning rate of log c_pos and log c_neg"""
    event_windows: EventWindows = "consecutive"
    """L_ev windows: every pair of consecutive virtual instants, or one random pair of them per step (the paper samples
    its window start t_s at random)"""
    event_norm: EventNorm = "l1"
    """L_ev residual norm: l1 (mean |r|, robust to noise events) or l2 (mean r^2, the paper's)"""
    edi_prior: EdiPrior = "edi"
    """the latents of L_EDI: per-frame EDI, or mEDI (all training frames jointly, linked by the events between their
    centres)"""
    edi_instants: EdiInstants = "views"
    """where L_EDI compares: every virtual view with the EDI latent at its own instant (mean over the views), or only
    the mid-exposure render with the latent at mid-exposure (views needs edi_prior edi;
    benchmarks/results/edi_views.json)"""
    cfa_events: CfaEvents = "filter"
    """a colour DAVIS capture (capture.json "cfa"): its events fire on each pixel's own channel of the render (filter),
    or are taken as events of the luminance, the channel mean (luminance: what ebad did before; raw mosaic frames:
    always filter)"""
    cfa_frames: CfaFrames = "rgb"
    """a colour DAVIS capture with RGB (demosaiced) frames: L_blur and L_EDI compare RGB, or each pixel's own channel
    of the frame and of the render (mosaic); raw mosaic frames always compare the render's mosaic. The ebad preset
    sets mosaic: on the ablation's colour DAVIS (500 steps, refined test poses) mosaic led rgb by 1.06-1.40 dB (seeds
    0-2) and events-as-luminance by 1.2-1.6 dB per seed (docs/results.md); the default stays rgb for the baselines"""

    def check(self) -> None:
        _finite(self, "loss")
        for name, kind in (
            ("cfa_events", CfaEvents),
            ("cfa_frames", CfaFrames),
            ("event_windows", EventWindows),
            ("event_norm", EventNorm),
            ("edi_prior", EdiPrior),
            ("edi_instants", EdiInstants),
        ):
            _require(
                getattr(self, name) in typing.get_args(kind),
                f"loss.{name}",
                f"must be one of {', '.join(typing.get_args(kind))}, got {getattr(self, name)!r}",
            )
        for name in ("w_blur", "w_event", "w_edi"):
            _require(getattr(self, name) >= 0, f"loss.{name}", f"must be >= 0, got {getattr(self, name)}")
        _require(0 <= self.ssim_weight <= 1, "loss.ssim_weight", f"must be in [0, 1], got {self.ssim_weight}")
        _require(
            self.ssim_window >= 1 and self.ssim_window % 2 == 1,
            "loss.ssim_window",
            f"must be an odd number >= 1, got {self.ssim_window}",
        )
        _require(
            self.contrast is None or (len(self.contrast) == 2 and min(self.contrast) > 0),
            "loss.contrast",
            f"must be two thresholds > 0 (c_pos c_neg), got {self.contrast}",
        )
        _require(self.lr_contrast >= 0, "loss.lr_contrast", f"must be >= 0, got {self.lr_contrast}")
        _require(
            self.edi_instants == "mid" or self.edi_prior == "edi",
            "loss.edi_instants",
            "views needs loss.edi_prior edi (mEDI gives latents at the exposure centres only): "
            "with edi_prior medi give --loss.edi_instants mid",
        )


@dataclass
class StrategyConfig:
    """Densification and pruning (gsplat's default strategy)."""

    kind: StrategyKind = "default"
    """densification strategy (ebad.strategy.STRATEGIES): default | none"""
    grad_threshold: float = 2e-4
    """mean screen-space gradient norm (NDC units) that triggers clone/split"""
    split_scale: float = 0.01
    """Gaussians larger than this x scene scale split, smaller ones clone"""
    split_shrink: float = 1.6
    """a split Gaussian becomes two, each this many times smaller (3DGS: 0.8 x 2)"""
    prune_opacity: float = 0.01
    """Gaussians below this activated opacity are removed"""
    prune_scale: float = 0.2
    """Gaussians larger than this x scene scale are removed (after a reset)"""
    refine_start: int = 50
    """first step that refines"""
    refine_stop: int = 10_000
    """last step that refines"""
    refine_every: int = 50
    """steps between refinements"""
    reset_every: int = 600
    """steps between opacity resets (0: never)"""
    reset_opacity: float = 0.05
    """opacities are clamped to at most this at a reset"""
    reset_until: float = 0.5
    """no opacity reset after this fraction of the run (steps over iters, or time over max_seconds): the scene needs
    steps to recover from one (gsplat resets until half its iterations)"""

    def check(self) -> None:
        _finite(self, "strategy")
        _require(self.grad_threshold > 0, "strategy.grad_threshold", f"must be > 0, got {self.grad_threshold}")
        _require(self.split_shrink > 1, "strategy.split_shrink", f"must be > 1, got {self.split_shrink}")
        _require(0 <= self.prune_opacity < 1, "strategy.prune_opacity", f"must be in [0, 1), got {self.prune_opacity}")
        _require(self.refine_every >= 1, "strategy.refine_every", f"must be >= 1, got {self.refine_every}")
        _require(self.reset_every >= 0, "strategy.reset_every", f"must be >= 0, got {self.reset_every}")
        _require(0 < self.reset_opacity < 1, "strategy.reset_opacity", f"must be in (0, 1), got {self.reset_opacity}")
        _require(0 <= self.reset_until <= 1, "strategy.reset_until", f"must be in [0, 1], got {self.reset_until}")


@dataclass
class TrainConfig:
    """The optimisation loop."""

    iters: int = 0
    """optimisation steps (one frame per step); 0: automatic, 60 a training frame and at least 600 (600 up to 10
    frames), or no step limit when max_seconds is given (the clock is the budget; ebad.state.step_budget)"""
    max_seconds: float | None = None
    """wall-time budget; the loop stops when it is spent. The schedule then follows max(steps / iters, seconds /
    max_seconds), so a run with a budget depends on the machine's speed and load and is not repeatable; a run
    budgeted by iters alone is bit-identical for one seed (any PYTHONHASHSEED or NUMBA_NUM_THREADS) as long as
    numba's compiled kernels are the same. ``ebad reconstruct`` on a cold numba cache compiles them in child
    processes and loads them, as later runs do; ``ebad.run.reconstruct`` called alone compiles them in its own
    process and differs in the last bits from later runs (numba compiles a parallel loop's body twice, alone and
    inside its kernel: the compiling process runs the first copy, the cache keeps the second, and the tile
    compositing kernels' fast-math reassociation rounds the two differently; see tests/splat_cpu/test_cold_cache.py
    and the README)"""
    plateau_patience: int = 0
    """stop after this many loss windows without improvement (0: never)"""
    plateau_every: int = 50
    """steps between plateau checks (mean loss over the window)"""
    plateau_tol: float = 1e-3
    """relative improvement that counts as progress"""
    empty_render_steps: int = 50
    """stop with an error when every render of the first this many steps is empty (alpha below 1/255 at every
    pixel: no Gaussian in front of the cameras); 0: never check"""
    lr_means: float = 1.6e-3
    """Adam lr of means, times the scene scale (decays to lr_means_final x itself over the run)"""
    lr_means_final: float = 0.1
    """the means' learning rate decays exponentially to this fraction of lr_means (3DGS: 0.01)"""
    lr_scales: float = 1e-2
    """Adam lr of log-scales"""
    lr_quats: float = 2e-3
    """Adam lr of quaternions"""
    lr_opacities: float = 5e-2
    """Adam lr of opacity logits"""
    lr_colors: float = 1e-2
    """Adam lr of colours (SH DC coefficients)"""
    pose_warmup: int = 0
    """steps before the trajectories start moving"""
    coarse_scale: int = 2
    """the first ``coarse_until`` of the run trains at 1/coarse_scale of the resolution (ebad.data.downscale); 1: never
    """
    coarse_until: float = 0.3
    """fraction of the run (steps over iters, or time over max_seconds when further) at the coarse resolution"""
    eval_every: int = 100
    """steps between test-view PSNR evaluations (when test images exist; 0: never)"""
    checkpoint_every: int = 200
    """steps between checkpoints of a run folder (0: only at the end)"""
    seed: int = 0
    """torch / numpy seed of the run"""
    progress: bool = True
    """tqdm progress bar"""

    def check(self) -> None:
        _finite(self, "train")
        _require(self.iters >= 0, "train.iters", f"must be >= 0 (0: automatic), got {self.iters}")
        _require(
            self.max_seconds is None or self.max_seconds > 0,
            "train.max_seconds",
            f"must be > 0, got {self.max_seconds}",
        )
        _require(self.plateau_patience >= 0, "train.plateau_patience", f"must be >= 0, got {self.plateau_patience}")
        _require(self.plateau_every >= 1, "train.plateau_every", f"must be >= 1, got {self.plateau_every}")
        _require(self.plateau_tol >= 0, "train.plateau_tol", f"must be >= 0, got {self.plateau_tol}")
        _require(
            self.empty_render_steps >= 0, "train.empty_render_steps", f"must be >= 0, got {self.empty_render_steps}"
        )
        for name in ("lr_means", "lr_scales", "lr_quats", "lr_opacities", "lr_colors"):
            _require(getattr(self, name) >= 0, f"train.{name}", f"must be >= 0, got {getattr(self, name)}")
        _require(0 < self.lr_means_final <= 1, "train.lr_means_final", f"must be in (0, 1], got {self.lr_means_final}")
        _require(self.pose_warmup >= 0, "train.pose_warmup", f"must be >= 0, got {self.pose_warmup}")
        _require(
            self.coarse_scale >= 1, "train.coarse_scale", f"must be >= 1 (1: no coarse phase), got {self.coarse_scale}"
        )
        _require(0 <= self.coarse_until <= 1, "train.coarse_until", f"must be in [0, 1], got {self.coarse_until}")
        _require(self.eval_every >= 0, "train.eval_every", f"must be >= 0 (0: never), got {self.eval_every}")
        _require(
            self.checkpoint_every >= 0,
            "train.checkpoint_every",
            f"must be >= 0 (0: only at the end), got {self.checkpoint_every}",
        )


@dataclass
class Config:
    """A full reconstruction configuration."""

    name: str = "ebad"
    """the preset it came from (informational)"""
    model: ModelConfig = field(default_factory=ModelConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    strategy: StrategyConfig = field(default_factory=StrategyConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def check(self) -> Config:
        """Raise ``ConfigError`` naming the first option whose value cannot work; return self."""
        for section in (self.model, self.trajectory, self.loss, self.strategy, self.train):
            section.check()
        _require(
            self.trajectory.view_spacing == 0 or self.train.coarse_until > 0,
            "trajectory.view_spacing",
            "needs train.coarse_until > 0: V is chosen from the trajectories learnt by then",
        )
        return self


# --------------------------------------------------------------------------- presets


def _ebad() -> Config:
    c = Config(name="ebad")
    # a colour DAVIS's demosaiced frames compared through the mosaic (each pixel's own channel, no demosaic
    # error): +1.23 dB novel over RGB at 500 steps, seeds 0-2 (docs/results.md, "Colour DAVIS on an equal step
    # budget"); the baselines fit the RGB frames as given
    c.loss.cfa_frames = "mosaic"
    return c


def _bad() -> Config:
    c = Config(name="bad")
    c.loss.w_event = 0.0
    c.loss.w_edi = 0.0
    c.trajectory.adaptive_views = False
    # BAD-Gaussians' default; with the blur alone cubic measured lower (benchmarks/results/ablation_noisy.json)
    c.trajectory.kind = "linear"
    return c


def _3dgs() -> Config:
    c = Config(name="3dgs")
    c.loss.w_event = 0.0
    c.loss.w_edi = 0.0
    c.trajectory.kind = "fixed"
    c.trajectory.num_views = 1
    c.trajectory.adaptive_views = False
    return c


def _edi_3dgs() -> Config:
    c = _3dgs()
    c.name = "edi-3dgs"
    c.loss.target = "edi"
    return c


def _3dgs_sharp() -> Config:
    # Plain 3DGS fed a capture whose frames are the sharp mid-exposure ground truth, one view per
    # frame, at the poses the capture gives (ebad.evaluate.sharp_capture). A reference of what
    # sharp input gives the same trainer, not a ceiling: ebad can beat it (it also sees the events).
    c = _3dgs()
    c.name = "3dgs-sharp"
    return c


PRESETS: dict[str, Callable[[], Config]] = {
    "3dgs": _3dgs,
    "bad": _bad,
    "edi-3dgs": _edi_3dgs,
    "ebad": _ebad,
    "3dgs-sharp": _3dgs_sharp,
}


def preset(name: str) -> Config:
    """A fresh ``Config`` for the preset ``name`` (one of ``PRESETS``)."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset '{name}'; choose one of {sorted(PRESETS)}")
    return PRESETS[name]()


# --------------------------------------------------------------------------- JSON


def config_to_dict(cfg: Config) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def _value(v: Any, t: Any, where: str) -> Any:
    """``v`` read from JSON as the field type ``t``, or ``ConfigError`` naming ``where``."""
    origin, args = typing.get_origin(t), typing.get_args(t)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if v is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _value(v, inner[0], where)
    if origin is Literal:
        if v not in args:
            raise ConfigError(f"{where}: must be one of {list(args)}, got {v!r}")
        return v
    if origin is tuple:
        if not isinstance(v, (list, tuple)) or len(v) != len(args):
            raise ConfigError(f"{where}: must be a list of {len(args)} values, got {v!r}")
        return tuple(_value(x, a, where) for x, a in zip(v, args))
    if t is bool:
        if not isinstance(v, bool):
            raise ConfigError(f"{where}: must be true or false, got {v!r}")
        return v
    if t is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise ConfigError(f"{where}: must be an integer, got {v!r}")
        return v
    if t is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{where}: must be a number, got {v!r}")
        return float(v)
    if t is str:
        if not isinstance(v, str):
            raise ConfigError(f"{where}: must be a string, got {v!r}")
        return v
    raise TypeError(f"config field {where} has a type the JSON reader does not handle: {t}")  # a bug


def _from_dict(cls, data: dict[str, Any], where: str):
    if not isinstance(data, dict):
        raise ConfigError(f"config section '{where}' must be an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"config section '{where or 'top level'}' has unknown key(s) {sorted(unknown)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        key = f"{where}.{f.name}" if where else f.name
        t = hints[f.name]
        if dataclasses.is_dataclass(t):
            kwargs[f.name] = _from_dict(t, data[f.name], key)
        else:
            kwargs[f.name] = _value(data[f.name], t, key)
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any]) -> Config:
    """Inverse of ``config_to_dict``; unknown keys and mistyped values raise ``ConfigError`` naming them."""
    return _from_dict(Config, data, "")


def save_config(cfg: Config, path: str | Path) -> None:
    """Write ``cfg`` as JSON, atomically (a temporary file renamed into place)."""
    from scenes._atomic import write_text_atomic  # here: importing ``scenes`` loads scipy, this module nothing heavy

    write_text_atomic(Path(path), json.dumps(config_to_dict(cfg), indent=2) + "\n")


def load_config(path: str | Path) -> Config:
    """The ``Config`` of a JSON file (``save_config``); ConfigError naming the file and the field otherwise."""
    from scenes.jsonio import read_json_object

    path = Path(path)
    data = read_json_object(path, ConfigError)
    try:
        return config_from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc


# --------------------------------------------------------------------------- resume

# What ``--resume`` may change: how long to go on and how to watch it, nothing that changes
# what is being optimised.
RESUMABLE_FIELDS = frozenset(
    {
        "train.iters",
        "train.max_seconds",
        "train.progress",
        "train.eval_every",
        "train.checkpoint_every",
        "train.plateau_patience",
    }
)


def config_diff(a: Config, b: Config) -> dict[str, tuple[Any, Any]]:
    """``{"section.field": (value in a, value in b)}`` for every field that differs."""
    da, db = config_to_dict(a), config_to_dict(b)
    out: dict[str, tuple[Any, Any]] = {}
    for key in da:
        if isinstance(da[key], dict):
            for sub in da[key]:
                if da[key][sub] != db[key][sub]:
                    out[f"{key}.{sub}"] = (da[key][sub], db[key][sub])
        elif da[key] != db[key]:
            out[key] = (da[key], db[key])
    return out
