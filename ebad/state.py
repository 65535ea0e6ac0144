"""The loop's state as one typed object, with ``save`` / ``load`` that are each other's inverse.

``TrainState`` holds everything a step changes: the Gaussian parameters and their optimisers,
the exposure trajectories, the contrast threshold, the densification statistics, every random
generator, the step, the frame order of the current pass and the history. ``TrainState.create``
starts a run from ``TrainingData``; ``save(path)`` writes a checkpoint atomically and
``TrainState.load(path, data, cfg)`` restores it so that the next step is the step the saved
run would have taken (tested: save, load, one step equals one step without the round trip).
"""

from __future__ import annotations

import copy
import dataclasses
import errno
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor, nn

from scenes._atomic import atomic_path

from .config import Config
from .data import TrainingData
from .errors import UserError
from .gaussians import (
    SH_REST_LR_RATIO,
    init_params,
    num_gaussians,
    plane_sweep_points,
    points_from_frames,
    resize_sh,
    sh_degree_of,
)
from .response import Response
from .strategy import OPTIONAL_PARAM_NAMES, PARAM_NAMES, RefineReport, StrategyState
from .trajectory import ExposureTrajectories

if TYPE_CHECKING:
    from scenes import Capture

__all__ = [
    "StepStats",
    "TrainState",
    "init_gaussians",
    "make_optimizers",
    "max_gaussians",
    "step_budget",
    "with_step_budget",
    "capture_fingerprint",
    "read_checkpoint",
    "fingerprint_diff",
    "AUTO_CAP_PER_PIXEL",
    "AUTO_CAP_RANGE",
    "AUTO_STEPS_PER_FRAME",
    "AUTO_MIN_STEPS",
    "NO_STEP_LIMIT",
    "CHECKPOINT_FORMAT",
]

# ModelConfig.max_gaussians = 0: the cap is this many Gaussians per pixel, clamped to the range
# (the small scenes need room to grow; at DAVIS size 2 x 346 x 260 = 180k would be too slow).
AUTO_CAP_PER_PIXEL = 2
AUTO_CAP_RANGE = (4000, 60000)
# TrainConfig.iters = 0: each training frame gets as many steps as a frame of a 10-frame capture got under the fixed
# default of 600 that every 10-frame run had (so 600 up to 10 frames); a 30-frame capture gets 1800, not 20 a frame.
# With train.max_seconds the clock is the budget: NO_STEP_LIMIT steps.
AUTO_STEPS_PER_FRAME = 60
AUTO_MIN_STEPS = 600
NO_STEP_LIMIT = 1 << 40
CHECKPOINT_FORMAT = "ebad-checkpoint/1"


@dataclass
class StepStats:
    """What one step reports (one entry of the run's history)."""

    step: int  # 1-based: steps done after this one
    frame: str  # the training frame of the step
    loss: float  # the weighted total
    blur: float  # L_blur
    train_psnr: float  # PSNR of the mean render against the step's L_blur target
    gaussians: int  # N after the step's densification
    time: float  # training seconds since the run started (resumes included)
    ev: float | None = None  # L_ev, when on for this frame
    edi: float | None = None  # L_EDI, when on
    c: list[float] | None = None  # (c_pos, c_neg), when learnt
    test_psnr: float | None = None  # mean test-view PSNR, on evaluation steps
    width: int | None = None  # width of the frames the step trained on (smaller in the coarse phase)
    refine: RefineReport = field(default_factory=RefineReport)  # what densification did
    profile: dict[str, float] | None = None  # ms of each part of the step (ebad.loop.train_step, step_profile)
    alpha: float | None = None  # largest alpha of the step's renders (train.empty_render_steps' first steps only)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StepStats:
        d = dict(d)
        d["refine"] = RefineReport(**d.get("refine", {}))
        return cls(**d)


def max_gaussians(cfg: Config, data: TrainingData) -> int:
    """The configured cap, or ``AUTO_CAP_PER_PIXEL`` x pixels clamped to ``AUTO_CAP_RANGE`` when it is 0."""
    if cfg.model.max_gaussians > 0:
        return int(cfg.model.max_gaussians)
    lo, hi = AUTO_CAP_RANGE
    return int(min(hi, max(lo, AUTO_CAP_PER_PIXEL * data.width * data.height)))


def step_budget(cfg: Config, frames: int) -> int:
    """The configured ``train.iters``, or when it is 0, ``AUTO_STEPS_PER_FRAME`` steps a training frame and at least
    ``AUTO_MIN_STEPS``; with ``train.max_seconds`` given, ``NO_STEP_LIMIT`` (the time budget decides)."""
    if cfg.train.iters > 0:
        return int(cfg.train.iters)
    if cfg.train.max_seconds is not None:
        return NO_STEP_LIMIT
    return max(AUTO_MIN_STEPS, AUTO_STEPS_PER_FRAME * frames)


def with_step_budget(cfg: Config, frames: int) -> Config:
    """A copy of ``cfg`` whose ``train.iters`` is ``step_budget``'s (``cfg`` itself is left as given)."""
    out = copy.deepcopy(cfg)
    out.train.iters = step_budget(cfg, frames)
    return out


def init_gaussians(data: TrainingData, cfg: Config) -> dict[str, nn.Parameter]:
    """From SfM points when there are at least ``model.min_sfm_points``, else from the frames
    (plane-sweep stereo or random depths, ``model.init``); with zero SH coefficients of degrees
    1..``model.sh_degree`` (``gaussians.resize_sh``)."""
    params = _init_gaussians(data, cfg)
    resize_sh(params, cfg.model.sh_degree)
    return params


def _init_gaussians(data: TrainingData, cfg: Config) -> dict[str, nn.Parameter]:
    mc = cfg.model
    if data.points is not None and len(data.points) >= mc.min_sfm_points:
        cols = data.point_colors
        if cols is None or cols.shape[1] != data.channels:
            cols = torch.full((len(data.points), data.channels), 0.5)
        return init_params(data.points, cols, opacity=mc.init_opacity)
    src = data.init_images  # latents, else targets; demosaiced raw mosaics (the model renders RGB)
    args = (src.numpy(), data.c2w.double().numpy(), data.K.double().numpy(), mc.init_points, data.depth_range)
    if mc.init == "stereo":
        pts, cols, scales = plane_sweep_points(
            *args,
            n_depths=mc.stereo_depths,
            neighbours=mc.stereo_neighbours,
            patch=mc.stereo_patch,
            scale_px=mc.init_scale_px,
            seed=cfg.train.seed,
        )
    else:
        pts, cols, scales = points_from_frames(*args, scale_px=mc.init_scale_px, seed=cfg.train.seed)
    return init_params(pts, cols, scales, opacity=mc.init_opacity)


def _adam(params: list[Tensor], **kw) -> torch.optim.Adam:
    """Adam, fused where torch has it for the CPU (torch >= 2.4): one pass per parameter instead of
    a dozen torch operations (measured faster at every N we run); the same update either way."""
    try:
        return torch.optim.Adam(params, fused=True, **kw)
    except RuntimeError:  # torch < 2.4: fused Adam only on GPUs
        return torch.optim.Adam(params, **kw)


def make_optimizers(
    params: dict[str, nn.Parameter],
    traj: ExposureTrajectories,
    cfg: Config,
    scale: float,
    log_c: nn.Parameter | None = None,
    response: Response | None = None,
) -> dict[str, torch.optim.Optimizer]:
    """One Adam per Gaussian parameter (so densification can edit its moments), one for poses,
    and one each for the contrast threshold and the response curve when they are learnt. The SH
    coefficients above the DC (``sh_rest``, when the model has them) learn at ``train.lr_colors /
    gaussians.SH_REST_LR_RATIO``."""
    tc = cfg.train
    lrs = {
        "means": tc.lr_means * scale,
        "scales": tc.lr_scales,
        "quats": tc.lr_quats,
        "opacities": tc.lr_opacities,
        "colors": tc.lr_colors,
    }
    if "sh_rest" in params:
        lrs["sh_rest"] = tc.lr_colors / SH_REST_LR_RATIO
    opts: dict[str, torch.optim.Optimizer] = {k: _adam([params[k]], lr=lrs[k], eps=1e-15) for k in lrs}
    if traj.knots.numel() > 0 and bool(traj.moving.any()):
        opts["poses"] = _adam([traj.knots], lr=cfg.trajectory.lr)
    if log_c is not None and log_c.requires_grad:
        opts["contrast"] = torch.optim.Adam([log_c], lr=cfg.loss.lr_contrast)
    if response is not None and response.learnable:
        opts["response"] = torch.optim.Adam(response.parameters(), lr=cfg.model.lr_response)
    return opts


def anchored(data: TrainingData, cfg: Config) -> bool:
    """Keep the mid-exposure poses (``trajectory.anchor_mid``; auto: when the capture says they are exact)."""
    am = cfg.trajectory.anchor_mid
    return am == "yes" or (am == "auto" and data.report.pose_source == "capture" and data.report.pose_trust == "exact")


def _trajectories(
    data: TrainingData, cfg: Config, generator: torch.Generator | None, init_noise: float
) -> ExposureTrajectories:
    """Anchored (trusted poses): only blurry frames move, around their given mid pose. Free: every
    frame's pose is optimised, the whole trajectory of a blurry frame and one correction of a sharp
    one (``fixed`` becomes ``offset``), as BAD-Gaussians and gsplat's pose_opt do."""
    anchor = anchored(data, cfg)
    moving = torch.from_numpy(data.V > 1) if anchor else torch.ones(data.num_frames, dtype=torch.bool)
    kind: str = cfg.trajectory.kind if bool((torch.from_numpy(data.V > 1)).any()) else "fixed"
    if not anchor and data.report.pose_source != "static" and kind == "fixed":
        kind = "offset"
    if kind == "fixed" or data.report.pose_source == "static":
        moving = torch.from_numpy(data.V > 1)
    return ExposureTrajectories(
        data.c2w, kind, moving, scale=data.scale, init_noise=init_noise, generator=generator, anchored=anchor
    )


def _log_c(data: TrainingData, cfg: Config) -> nn.Parameter | None:
    if data.c is None or all(e is None for e in data.ev_counts):
        return None
    return nn.Parameter(torch.log(torch.tensor(data.c, dtype=torch.float32)), requires_grad=cfg.loss.learn_contrast)


@dataclass
class TrainState:
    """Everything one training step reads and changes."""

    params: dict[str, nn.Parameter]  # PARAM_NAMES -> [N, ...]
    optimizers: dict[str, torch.optim.Optimizer]  # one per parameter, "poses", "contrast"
    trajectories: ExposureTrajectories
    log_c: nn.Parameter | None  # [2] logs of (c_pos, c_neg) (None: no L_ev)
    response: Response  # rendered irradiance -> recorded values
    strategy_state: StrategyState
    order_rng: np.random.Generator  # the order frames are visited in
    generator: torch.Generator  # initial trajectory noise and densification splits
    step: int = 0
    order: list[int] = field(default_factory=list)  # frames still to visit in the current pass
    history: list[StepStats] = field(default_factory=list)
    elapsed: float = 0.0  # training seconds so far (over every resume)
    knots_sum: Tensor | None = None  # running sum of the knots since trajectory.average_from (None: not started)
    knots_count: int = 0  # steps in knots_sum

    @property
    def num_gaussians(self) -> int:
        return num_gaussians(self.params)

    @classmethod
    def create(cls, data: TrainingData, cfg: Config, strategy_state: StrategyState | None = None) -> TrainState:
        """A fresh run: initial Gaussians, trajectories, optimisers and generators seeded by ``train.seed``."""
        seed = cfg.train.seed
        generator = torch.Generator().manual_seed(seed)
        params = init_gaussians(data, cfg)
        traj = _trajectories(data, cfg, generator, cfg.trajectory.init_noise)
        log_c = _log_c(data, cfg)
        response = Response(cfg.model.response)
        return cls(
            params=params,
            optimizers=make_optimizers(params, traj, cfg, data.scale, log_c, response),
            trajectories=traj,
            log_c=log_c,
            response=response,
            strategy_state=strategy_state
            or StrategyState(torch.zeros(num_gaussians(params)), torch.zeros(num_gaussians(params))),
            order_rng=np.random.default_rng(seed),
            generator=generator,
        )

    def accumulate_knots(self) -> None:
        """Add the knots of this step to their running sum (``trajectory.average_from``)."""
        k = self.trajectories.knots.detach()
        self.knots_sum = k.clone() if self.knots_sum is None else self.knots_sum + k
        self.knots_count += 1

    def knots_mean(self) -> Tensor | None:
        """The mean of the accumulated knots (None before any)."""
        return None if self.knots_sum is None else self.knots_sum / self.knots_count

    def next_frame(self) -> int:
        """The next training frame: a fresh random permutation of the frames every pass."""
        if not self.order:
            self.order = [int(i) for i in self.order_rng.permutation(self.trajectories.num_frames)]
        return self.order.pop()

    def save(self, path: str | Path, fingerprint: dict[str, Any] | None = None) -> None:
        """Write the state to ``path`` atomically (a file unique to this process, renamed into place)."""
        path = Path(path)
        doc = {
            "format": CHECKPOINT_FORMAT,
            "fingerprint": fingerprint,
            "step": self.step,
            "elapsed": self.elapsed,
            "params": {k: v.detach().clone() for k, v in self.params.items()},
            "trajectories": {k: v.detach().clone() for k, v in self.trajectories.state_dict().items()},
            "log_c": None if self.log_c is None else self.log_c.detach().clone(),
            "response": {k: v.detach().clone() for k, v in self.response.state_dict().items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "strategy_state": self.strategy_state.to_dict(),
            "order": list(self.order),
            "order_rng": self.order_rng.bit_generator.state,
            "generator": self.generator.get_state(),
            "history": [h.to_dict() for h in self.history],
            "knots_sum": None if self.knots_sum is None else self.knots_sum.clone(),
            "knots_count": self.knots_count,
        }
        with atomic_path(path) as tmp:
            try:
                torch.save(doc, tmp)
            except RuntimeError as exc:  # torch's zip writer reports a failed write (a full disk) this way
                if "write" not in str(exc).lower() and "inline_container" not in str(exc):
                    raise
                raise OSError(
                    errno.EIO, f"could not write the checkpoint ({exc}); nothing was replaced", str(path)
                ) from exc

    @classmethod
    def load(
        cls, path: str | Path, data: TrainingData, cfg: Config, fingerprint: dict[str, Any] | None = None
    ) -> TrainState:
        """The state ``save`` wrote, for the same training data and config.

        Raises ``UserError`` naming the file when it is not a readable checkpoint, and naming
        the difference when it was made from another capture (``fingerprint``)."""
        doc = read_checkpoint(path, fingerprint)
        saved = doc["params"]
        params = {k: nn.Parameter(saved[k].clone()) for k in PARAM_NAMES + OPTIONAL_PARAM_NAMES if k in saved}
        missing = [k for k in PARAM_NAMES if k not in params]
        if missing:
            raise UserError(f"{path}: the checkpoint has no Gaussian parameters {missing}; delete it to start over")
        saved_degree = sh_degree_of(params)
        if saved_degree != cfg.model.sh_degree:  # an older checkpoint (no SH) or another --model.sh_degree
            resize_sh(params, cfg.model.sh_degree)
        generator = torch.Generator()
        traj = _trajectories(data, cfg, None, 0.0)
        traj.load_state_dict(doc["trajectories"])
        log_c = _log_c(data, cfg)
        if log_c is not None and doc["log_c"] is not None:
            with torch.no_grad():
                log_c.data = doc["log_c"].clone()
        response = Response(cfg.model.response)
        response.load_state_dict(doc["response"])
        optimizers = make_optimizers(params, traj, cfg, data.scale, log_c, response)
        for k, sd in doc["optimizers"].items():
            if k in optimizers and not (k == "sh_rest" and saved_degree != cfg.model.sh_degree):
                optimizers[k].load_state_dict(sd)
        order_rng = np.random.default_rng()
        order_rng.bit_generator.state = doc["order_rng"]
        generator.set_state(doc["generator"])  # an older checkpoint's "torch_rng" (the global RNG: unused) is ignored
        return cls(
            params=params,
            optimizers=optimizers,
            trajectories=traj,
            log_c=log_c,
            response=response,
            strategy_state=StrategyState.from_dict(doc["strategy_state"]),
            order_rng=order_rng,
            generator=generator,
            step=int(doc["step"]),
            order=[int(i) for i in doc["order"]],
            history=[StepStats.from_dict(h) for h in doc["history"]],
            elapsed=float(doc["elapsed"]),
            knots_sum=doc.get("knots_sum"),
            knots_count=int(doc.get("knots_count", 0)),
        )


def read_checkpoint(path: str | Path, fingerprint: dict[str, Any] | None = None) -> dict[str, Any]:
    """The checkpoint's contents, or ``UserError`` naming the file when it is not a readable
    checkpoint, and naming the difference when it was made from another capture than the one
    ``fingerprint`` describes."""
    path = Path(path)
    try:
        doc = torch.load(path, weights_only=True)
    except Exception as exc:  # torch raises many types for a damaged file; all mean the same here
        raise UserError(
            f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc}); delete it to start the run over"
        ) from exc
    if not isinstance(doc, dict) or doc.get("format") != CHECKPOINT_FORMAT:
        raise UserError(f"{path}: not an {CHECKPOINT_FORMAT} checkpoint; delete it to start the run over")
    if fingerprint is not None and doc.get("fingerprint") is not None:
        diff = fingerprint_diff(doc["fingerprint"], fingerprint)
        if diff:
            raise UserError(
                f"{path} was made from another capture ({diff}); resume with the capture it "
                "was made from, or choose another --out"
            )
    return doc


FINGERPRINT_EVENT_SAMPLES = 1 << 20  # events hashed for the content fingerprint (evenly spaced, ends included)


def _digest(*arrays: np.ndarray) -> str:
    import hashlib

    h = hashlib.blake2b(digest_size=12)
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _content_fingerprint(capture: Capture) -> dict[str, str]:
    """Hashes of what a run learns from: every frame's pixels, the poses given (and the filter), and the
    events (at most ``FINGERPRINT_EVENT_SAMPLES`` of them, evenly spaced: a stream edited anywhere
    but between samples, or shifted in time, changes it). A few ms for 10 frames at 346x260."""
    ev = capture.events
    out = {"pixels": _digest(np.asarray(capture.frames, dtype=np.float32))}
    poses = [] if capture.c2w is None else [np.round(np.asarray(capture.c2w, dtype=np.float64), 9)]
    out["poses"] = _digest(*poses, np.frombuffer(str(capture.cfa).encode(), np.uint8))
    if ev is not None and len(ev):
        idx = np.unique(np.linspace(0, len(ev) - 1, min(len(ev), FINGERPRINT_EVENT_SAMPLES)).astype(np.int64))
        out["event_content"] = _digest(*(np.asarray(getattr(ev, k))[idx].astype(np.int64) for k in "txyp"))
    return out


def capture_fingerprint(capture: Capture) -> dict[str, Any]:
    """What identifies the capture a run was made from: frame names, size, exposures, events, K, and
    hashes of the content (``_content_fingerprint``)."""
    ev = capture.events
    return {
        "frames": [str(n) for n in (capture.names or range(capture.num_frames))],
        "size": [int(capture.frames.shape[2]), int(capture.frames.shape[1]), int(capture.frames.shape[3])],
        "exposures": np.round(np.asarray(capture.exposures, dtype=np.float64), 9).tolist(),
        "events": 0 if ev is None else int(len(ev)),
        "K": np.round(np.asarray(capture.K, dtype=np.float64), 6).tolist(),
        **_content_fingerprint(capture),
    }


def fingerprint_diff(saved: dict[str, Any], now: dict[str, Any]) -> str:
    """A short description of how two fingerprints differ ('' when they match). The content hashes
    are compared when the checkpoint has them (checkpoints written before them still resume)."""
    out = []
    for key in ("frames", "size", "exposures", "events", "K", "pixels", "poses", "event_content"):
        a, b = saved.get(key), now.get(key)
        if a == b or (key in ("pixels", "poses", "event_content") and key not in saved):
            continue
        if key == "frames":
            # a fingerprint without frames (None) reads as other frame names, not a TypeError
            if a is not None and b is not None and len(a) != len(b):
                out.append(f"{len(a)} frames then, {len(b)} now")
            else:
                out.append("other frame names")
        elif key in ("size", "events"):
            out.append(f"{key} {a} then, {b} now")
        elif key == "pixels":
            out.append("other frame pixels")
        elif key == "event_content":
            out.append("other event content")
        else:
            out.append(f"other {key}")
    return "; ".join(out)
