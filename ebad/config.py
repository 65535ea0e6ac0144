"""Reconstruction settings as dataclasses, the preset registry, JSON and argparse helpers.

Every field carries a comment; ``Config`` nests one dataclass per concern. Presets are named
functions in ``PRESETS`` returning a full ``Config``; a run saves the resolved config as JSON
beside its outputs, and ``config_from_dict`` reads it back (unknown keys are errors that name
the key; nothing is ``eval``-ed).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

from .errors import UserError

__all__ = [
    "ModelConfig", "TrajectoryConfig", "LossConfig", "StrategyConfig", "TrainConfig", "Config",
    "PRESETS", "preset", "config_to_dict", "config_from_dict", "save_config", "load_config",
    "add_dataclass_arguments", "apply_dataclass_arguments",
]

Target = Literal["blurry", "edi"]
PoseSource = Literal["auto", "capture", "colmap", "static"]


@dataclass
class ModelConfig:
    """The Gaussians and how they start."""

    init: Literal["stereo", "random"] = "stereo"  # fallback without SfM points: plane-sweep stereo
    #   between the posed frames (gaussians.plane_sweep_points) or random depths along pixel rays
    init_points: int = 3000  # Gaussians of the fallback initialisation (no SfM points)
    init_depth: tuple[float, float] | None = None  # fallback depth range (near, far) in world units;
    #   None: from capture.meta["depth_range"] when present, else (0.5, 2.0) x the camera-spread scale
    init_opacity: float = 0.3  # activated opacity of every initial Gaussian
    init_scale_px: float = 1.5  # initial Gaussian radius in pixels at its depth (fallback init)
    max_gaussians: int = 0  # densification stops growing N beyond this; 0: 2 x pixels, in [4000, 60000]
    background: float = 0.0  # background intensity (every channel)


@dataclass
class TrajectoryConfig:
    """Camera motion inside each exposure."""

    kind: str = "linear"  # registered trajectory model: linear | cubic | fixed
    num_views: int = 5  # V, virtual views per blurry exposure (uniform instants)
    adaptive_views: bool = True  # V from event activity: a frame with few events renders V = 1
    sharp_events_per_pixel: float = 0.05  # below this many events per pixel an exposure is sharp
    init_noise: float = 1e-3  # std of the initial start/end perturbation (radians; x scene scale for
    #   translation) that breaks the zero-motion symmetry of the blur loss
    lr: float = 2e-3  # Adam learning rate of the knots (radians; translations in scene-scale units)
    anchor_mid: Literal["auto", "yes", "no"] = "auto"  # keep the mid-exposure pose fixed (learn only
    #   the motion); auto: yes when the poses come with the capture (trusted), no after SfM
    pose_source: PoseSource = "auto"  # auto: capture poses when present, else pycolmap SfM; static: a camera on a tripod (every frame at the identity pose)


@dataclass
class LossConfig:
    """Which losses, against what, and their weights (the paper's: 1, 0.1, 1)."""

    target: Target = "blurry"  # what L_blur compares to: the blurry frames or their EDI latents
    w_blur: float = 1.0  # weight of L_blur (0.8 L1 + 0.2 (1 - SSIM) of the mean of V renders)
    w_event: float = 0.1  # weight of L_ev (log-render differences vs c x events); 0 disables
    w_edi: float = 1.0  # weight of L_EDI (mid-exposure render vs EDI latent); 0 disables
    ssim_weight: float = 0.2  # the 0.2 in 0.8 L1 + 0.2 (1 - SSIM)
    ssim_window: int = 7  # SSIM window (odd; small images need a small one)
    contrast: float | None = None  # event contrast threshold c; None: edi.estimate_c from the data
    # refine c (as log c) jointly, through L_ev. Off by default: c -> 0 with flat renders is a
    # degenerate minimum of L_ev and c drifts towards it (benchmarks/learn_contrast.py, small
    # grey scene, true c 0.2, 60 s: c 0.187 -> 0.07 in two runs), while novel-view PSNR is
    # equal within run-to-run noise (learnt minus fixed: -0.24 dB in one run, +0.26 dB in another)
    learn_contrast: bool = False
    lr_contrast: float = 1e-2  # Adam learning rate of log c


@dataclass
class StrategyConfig:
    """Densification and pruning (gsplat's default strategy)."""

    kind: str = "default"  # registered strategy: default | none
    grad_threshold: float = 2e-4  # mean screen-space gradient norm (NDC units) that triggers clone/split
    split_scale: float = 0.01  # Gaussians larger than this x scene scale split, smaller ones clone
    prune_opacity: float = 0.01  # Gaussians below this activated opacity are removed
    prune_scale: float = 0.2  # Gaussians larger than this x scene scale are removed (after a reset)
    refine_start: int = 50  # first step that refines
    refine_stop: int = 10_000  # last step that refines
    refine_every: int = 50  # steps between refinements
    reset_every: int = 600  # steps between opacity resets (0: never)
    reset_opacity: float = 0.05  # opacities are clamped to at most this at a reset


@dataclass
class TrainConfig:
    """The optimisation loop."""

    iters: int = 600  # optimisation steps (one frame per step)
    max_seconds: float | None = None  # wall-time budget; the loop stops when it is spent
    plateau_patience: int = 0  # stop after this many evaluations without improvement (0: never)
    plateau_every: int = 50  # steps between plateau checks (mean loss over the window)
    plateau_tol: float = 1e-3  # relative improvement that counts as progress
    lr_means: float = 1.6e-3  # Adam lr of means, times the scene scale (decays x0.1 over the run)
    lr_scales: float = 1e-2  # Adam lr of log-scales
    lr_quats: float = 2e-3  # Adam lr of quaternions
    lr_opacities: float = 5e-2  # Adam lr of opacity logits
    lr_colors: float = 1e-2  # Adam lr of colours (SH DC coefficients)
    pose_warmup: int = 0  # steps before the trajectories start moving
    eval_every: int = 100  # steps between test-view PSNR evaluations (when test images exist; 0: never)
    checkpoint_every: int = 200  # steps between checkpoints of a run folder (0: only at the end)
    seed: int = 0  # torch / numpy seed of the run
    progress: bool = True  # tqdm progress bar


@dataclass
class Config:
    """A full reconstruction configuration."""

    name: str = "ebad"  # the preset it came from (informational)
    model: ModelConfig = field(default_factory=ModelConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    strategy: StrategyConfig = field(default_factory=StrategyConfig)
    train: TrainConfig = field(default_factory=TrainConfig)


# --------------------------------------------------------------------------- presets

def _ebad() -> Config:
    return Config(name="ebad")


def _bad() -> Config:
    c = Config(name="bad")
    c.loss.w_event = 0.0
    c.loss.w_edi = 0.0
    c.trajectory.adaptive_views = False
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


def _oracle() -> Config:
    # Fed a capture whose frames are the sharp mid-exposure ground truth (see
    # ebad.synthetic.oracle_capture): plain 3DGS with trusted poses.
    c = _3dgs()
    c.name = "oracle"
    return c


PRESETS: dict[str, Callable[[], Config]] = {
    "3dgs": _3dgs,
    "bad": _bad,
    "edi-3dgs": _edi_3dgs,
    "ebad": _ebad,
    "oracle": _oracle,
}


def preset(name: str) -> Config:
    """A fresh ``Config`` for the preset ``name`` (one of ``PRESETS``)."""
    if name not in PRESETS:
        raise UserError(f"unknown preset '{name}'; choose one of {sorted(PRESETS)}")
    return PRESETS[name]()


# --------------------------------------------------------------------------- JSON

def config_to_dict(cfg: Config) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def _from_dict(cls, data: dict[str, Any], where: str):
    if not isinstance(data, dict):
        raise UserError(f"config section '{where}' must be an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise UserError(f"config section '{where}' has unknown key(s) {sorted(unknown)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        v = data[f.name]
        t = hints[f.name]
        if dataclasses.is_dataclass(t):
            v = _from_dict(t, v, f"{where}.{f.name}" if where else f.name)
        elif isinstance(v, list):
            v = tuple(v)
        kwargs[f.name] = v
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any]) -> Config:
    """Inverse of ``config_to_dict``; unknown keys raise ``UserError`` naming them."""
    return _from_dict(Config, data, "")


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(json.dumps(config_to_dict(cfg), indent=2) + "\n")


def load_config(path: str | Path) -> Config:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON: {exc}") from exc
    return config_from_dict(data)


# --------------------------------------------------------------------------- argparse

def _scalar_type(t):
    origin = typing.get_origin(t)
    args = typing.get_args(t)
    if origin is Literal:
        return str, list(args)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return _scalar_type(inner[0])
        return None, None
    if t in (int, float, str):
        return t, None
    return None, None


def field_comments(cls) -> dict[str, str]:
    """The comment documenting each field of a dataclass: its inline ``# ...`` comment, or the
    comment lines just above it. Used as the command-line help of the field."""
    import inspect
    import re

    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):  # no source (frozen app): no help text
        return {}
    out: dict[str, str] = {}
    above: list[str] = []
    last = None  # the field whose inline comment a "#   ..." line continues
    for line in lines[1:]:
        stripped = line.strip()
        if stripped.startswith("#"):
            text = stripped.lstrip("#").strip()
            if last is not None and stripped.startswith("#  "):
                out[last] = f"{out[last]} {text}"
            else:
                above.append(text)
                last = None
            continue
        m = re.match(r"\s+(\w+)\s*:[^#]*(?:#\s*(.*))?$", line)
        last = None
        if m and not stripped.startswith(("def ", "@")) and m.group(1) not in out:
            out[m.group(1)] = m.group(2) or " ".join(above)
            last = m.group(1) if m.group(2) else None
        above = []
    return {k: v for k, v in out.items() if v}


def add_dataclass_arguments(parser: argparse.ArgumentParser, cls=Config, prefix: str = "") -> None:
    """Add one ``--section.field`` option per scalar field of ``cls`` (nested dataclasses recurse).

    Options default to ``None`` (meaning "keep the preset's value"); bools take true/false.
    Tuple-valued fields are left to JSON configs.
    """
    hints = typing.get_type_hints(cls)
    docs = field_comments(cls)
    group = parser.add_argument_group(prefix.rstrip(".") or "config") if not prefix else parser
    for f in dataclasses.fields(cls):
        t = hints[f.name]
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(t):
            add_dataclass_arguments(parser, t, prefix=f"{name}.")
            continue
        if name == "name":
            continue
        if t is bool:
            group.add_argument(f"--{name}", dest=name, default=None, metavar="BOOL",
                               type=_parse_bool, help=f"(true/false) {docs.get(f.name, '')}".rstrip())
            continue
        conv, choices = _scalar_type(t)
        if conv is None:
            continue
        group.add_argument(f"--{name}", dest=name, default=None, type=conv, choices=choices,
                           help=docs.get(f.name, f"{cls.__name__}.{f.name}"))


def _parse_bool(s: str) -> bool:
    low = s.lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true/false, got '{s}'")


def apply_dataclass_arguments(cfg: Config, args: argparse.Namespace) -> Config:
    """Overwrite the fields of ``cfg`` whose ``--section.field`` option was given."""
    for key, value in vars(args).items():
        if value is None or "." not in key:
            continue
        section, fname = key.split(".", 1)
        obj = getattr(cfg, section, None)
        if obj is None or not hasattr(obj, fname):
            continue
        setattr(obj, fname, value)
    return cfg
