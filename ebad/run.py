"""A reconstruction: ``reconstruct`` (capture -> ``Run``), the ``Run`` it returns and its ``RunMetrics``.

``reconstruct`` prepares the capture (``ebad.data.prepare``), starts or resumes the state
(``ebad.state.TrainState``), trains (``ebad.loop.train`` with the callbacks of
``ebad.callbacks``) and returns a ``Run``, which renders novel views. ``warm_up`` compiles
numba's kernels before a timed comparison.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import torch
from torch import Tensor

from .callbacks import Callback, Checkpointer, Evaluator, ProgressBar, StepHook
from .config import Config, preset
from .data import PoseSourceUsed, PrepareReport, prepare
from .errors import ConfigError
from .gaussians import num_gaussians
from .loop import StopReason, train
from .progress import say
from .response import Response
from .scoring import ViewScores, render_images
from .state import NO_STEP_LIMIT, StepStats, TrainState, capture_fingerprint, max_gaussians, with_step_budget
from .strategy import make_strategy
from .threads import configure as configure_threads
from .trajectory import ExposureTrajectories

if TYPE_CHECKING:
    from scenes import Capture, TestView

__all__ = ["Run", "RunMetrics", "reconstruct", "warm_up", "capture_kind", "CaptureKind"]


#: the kinds of capture whose kernels ``warm_up`` compiles: grey frames and events, colour frames with
#: luminance events, a colour DAVIS (a Bayer filter over the APS and event pixels: L_ev per channel)
CaptureKind = Literal["grey", "rgb", "cfa"]
_KIND_SCENE: dict[str, dict[str, Any]] = {"grey": {}, "rgb": {"rgb": True}, "cfa": {"rgb": True, "cfa": "RGGB"}}


def capture_kind(capture: Capture) -> CaptureKind:
    """The ``CaptureKind`` of a capture: "cfa" when it records a colour filter, "rgb" with colour
    frames, else "grey"."""
    if capture.cfa is not None:
        return "cfa"
    return "rgb" if capture.channels == 3 else "grey"


def warm_up(kinds: Sequence[CaptureKind] = ("grey",), sh_degree: int = 0) -> float:
    """Compile the numba kernels a reconstruction of each kind of capture in ``kinds`` runs (or load
    them from numba's cache), and no other: per kind, three steps of the ``ebad`` preset (with
    ``sh_degree``: its SH kernels) on a tiny synthetic capture of that kind, which reach the
    rasteriser, SSIM and L_ev kernels that every preset uses. Timed comparisons call it first so
    that no method's budget pays for compilation (on a cold cache, mostly the rasteriser's
    backward, SSIM and L_ev). Returns its seconds.

    Raises:
        ConfigError: a kind that is not a ``CaptureKind``, or no kind.
    """
    import scenes

    bad = [k for k in kinds if k not in _KIND_SCENE]
    if bad or not kinds:
        raise ConfigError(f"warm_up: kinds must be some of {', '.join(_KIND_SCENE)}, got {list(kinds)}")
    t0 = time.perf_counter()
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 3, False, 0
    cfg.model.sh_degree = sh_degree
    cfg.model.sh_degree_interval = 1  # the SH kernels run from the second step (a degree above 0)
    cfg.check()
    for kind in dict.fromkeys(kinds):
        reconstruct(scenes.make_scene("boxes", size="tiny", n_frames=3, n_test=1, **_KIND_SCENE[kind]).capture, cfg)
    return time.perf_counter() - t0


@dataclass
class RunMetrics:
    """What a reconstruction reports (``metrics.json``)."""

    preset: str
    steps: int
    stop_reason: StopReason  # iters | time | plateau | interrupted (SIGINT | SIGTERM)
    complete: bool  # False when interrupted: resume with --resume
    train_seconds: float
    prepare_seconds: float
    gaussians: int
    final_loss: float | None
    test: ViewScores | None  # test views after training
    test_initial: ViewScores | None  # test views at initialisation (None on a resumed run)
    prepare: PrepareReport  # what prepare decided
    anchored_mid_poses: bool
    c_final: list[float] | None = None  # (c_pos, c_neg) at the end (learnt or not)
    response: dict[str, float] | None = None  # the learnt response curve (black, gain, gamma)
    resumed_from: int | None = None  # the step a resumed run continued from
    averaged_steps: int = 0  # steps whose knots the run's trajectories are the mean of (trajectory.average_from)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunMetrics:
        """Inverse of ``to_dict`` (``metrics.json`` read back)."""
        d = dict(d)
        for key in ("test", "test_initial"):
            d[key] = None if d.get(key) is None else ViewScores(**d[key])
        d["prepare"] = PrepareReport(**d["prepare"])
        return cls(**d)


@dataclass
class Run:
    """A finished (or checkpointed) reconstruction."""

    params: dict[str, Tensor]
    trajectories: ExposureTrajectories
    config: Config
    K: np.ndarray  # [3, 3]
    width: int
    height: int
    names: list[str]
    exposures: np.ndarray  # [F, 2]
    V: np.ndarray  # [F]
    pose_source: PoseSourceUsed = "capture"  # where the training poses came from: capture | colmap | static
    test_c2w: dict[str, np.ndarray] = field(default_factory=dict)  # test-view poses in the run's frame, by name
    response: Response = field(default_factory=Response)  # rendered irradiance -> recorded values
    history: list[StepStats] = field(default_factory=list)
    metrics: RunMetrics | None = None
    step: int = 0

    @property
    def num_gaussians(self) -> int:
        return num_gaussians(self.params)

    @property
    def channels(self) -> int:
        return int(self.params["colors"].shape[1])

    @torch.no_grad()
    def render(
        self, c2w, K=None, width: int | None = None, height: int | None = None, batch: int = 8
    ) -> np.ndarray:  # [4, 4] -> [H, W, D]; [C, 4, 4] -> [C, H, W, D]
        """Render novel views (numpy float32 in [0, 1]) in the capture's recorded domain: the rendered
        irradiance through the run's camera ``response`` (the identity for ``linear``), the values every output
        of ebad stores as they are (``ebad.export``); K, width, height default to the capture's."""
        c2w_t = torch.as_tensor(np.asarray(c2w), dtype=torch.float32)
        single = c2w_t.ndim == 2
        if single:
            c2w_t = c2w_t[None]
        if c2w_t.ndim != 3 or c2w_t.shape[1:] != (4, 4):
            raise ValueError(f"c2w must be [4, 4] or [C, 4, 4], got {tuple(c2w_t.shape)}")
        if not torch.isfinite(c2w_t).all():
            raise ValueError("c2w has non-finite values")
        W = int(self.width if width is None else width)
        H = int(self.height if height is None else height)
        if W <= 0 or H <= 0:
            raise ValueError(f"width and height must be positive, got {W} x {H}")
        res = render_images(
            self.params,
            c2w_t,
            self.K if K is None else K,
            W,
            H,
            self.config.model.background,
            batch,
            response=self.response,
        )
        return res[0] if single else res

    @torch.no_grad()
    def deblurred_frames(self) -> np.ndarray:  # [F, H, W, D]
        """Every training frame re-rendered sharp at its mid-exposure pose (recorded domain, like ``render``)."""
        return self.render(self.trajectories.mid_poses().numpy())

    @torch.no_grad()
    def exposure_poses(self, samples: int = 9) -> tuple[np.ndarray, np.ndarray]:  # [F, S, 4, 4], [S]
        u = torch.linspace(0, 1, samples)
        F = self.trajectories.num_frames
        return self.trajectories(torch.arange(F), u).numpy(), u.numpy()


def _resolve(config: Config | str | None) -> Config:
    if config is None:
        config = preset("ebad")
    elif isinstance(config, str):
        config = preset(config)
    elif not isinstance(config, Config):
        raise ConfigError(f"config must be an ebad.Config or a preset name, got {type(config).__name__}")
    return config.check()


def reconstruct(
    capture: Capture,
    config: Config | str | None = None,
    out_dir: str | Path | None = None,
    resume: bool = False,
    gt_views: Sequence[TestView] | None = None,
    on_step: Callable[[int, StepStats], None] | None = None,
    callbacks: Sequence[Callback] = (),
    ready: Callable[[], None] | None = None,
) -> Run:
    """Recover Gaussians and per-exposure trajectories from ``capture``.

    Args:
        capture: a ``scenes.Capture``.
        config: a ``Config``, a preset name, or None (the ``ebad`` preset).
        out_dir: when given, checkpoints go to ``out_dir/checkpoints/last.pt`` every
            ``train.checkpoint_every`` steps and at the end (the rest of the run folder is
            written by ``ebad.runfolder.write_run``).
        resume: continue from ``out_dir``'s checkpoint when there is one (it must have been made
            from the same capture).
        gt_views: test views with images to report PSNR on (default: the capture's).
        on_step: optional callback(step, stats) after every step.
        callbacks: more ``Callback`` objects, called after the built-in ones (they see the state).
        ready: called once after preparing and initialising, before the first render (the initial
            scoring or the first step): ``ebad reconstruct`` waits there for the processes compiling
            the kernels into numba's cache (``ebad.precompile``), so that it loads them as later runs do.

    It first calls ``ebad.threads.configure()``; torch is loaded by then, so a program that wants
    OpenMP's threads to sleep (and numba on its faster "omp" layer) calls it before importing torch.
    """
    configure_threads()
    cfg = _resolve(config)
    show = cfg.train.progress
    t_prep = time.perf_counter()
    say(show, f"preparing the capture ({capture.num_frames} frames, {capture.width}x{capture.height})")
    data = prepare(capture, cfg)
    prep_s = time.perf_counter() - t_prep
    say(show, f"prepared in {prep_s:.1f} s")
    if cfg.train.iters == 0:  # automatic: 60 steps a frame, or the time budget alone
        cfg = with_step_budget(cfg, data.num_frames)
        budget = "no step limit" if cfg.train.iters == NO_STEP_LIMIT else f"{cfg.train.iters} steps"
        say(show, f"budget (train.iters 0, automatic): {budget}")
    fingerprint = capture_fingerprint(capture)
    ckpt = Path(out_dir) / "checkpoints" / "last.pt" if out_dir is not None else None
    resumed_from = None
    if resume and ckpt is not None and ckpt.exists():
        state = TrainState.load(ckpt, data, cfg, fingerprint)
        resumed_from = state.step
    else:
        t_init = time.perf_counter()
        say(show, "initialising the Gaussians and the trajectories")
        state = TrainState.create(data, cfg)
        say(show, f"initialised {state.num_gaussians} Gaussians in {time.perf_counter() - t_init:.1f} s")
    if ready is not None:
        ready()
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    strategy.check_sanity(state.params, state.optimizers)
    if resumed_from is None:
        state.strategy_state = strategy.initialize_state(state.num_gaussians)
    views = data.test_views if gt_views is None else gt_views  # poses from data.test_c2w where known
    evaluator = Evaluator(data, cfg, views, cfg.train.eval_every, cfg.train.iters)
    init_eval = None
    if state.step == 0 and evaluator.views:
        t_eval = time.perf_counter()
        say(show, f"scoring {len(evaluator.views)} test view(s) at initialisation")
        init_eval = evaluator.scores(state)
        say(show, f"scored in {time.perf_counter() - t_eval:.1f} s")
    built: list[Callback] = [evaluator]
    if cfg.train.progress:
        built.append(ProgressBar(cfg, state.step, state.elapsed))
    say(
        show,
        "training; the first step loads numba's compiled kernels (compiles them on a cold cache: a minute or more)",
    )
    if on_step is not None:
        built.append(StepHook(on_step))
    if ckpt is not None:
        built.append(Checkpointer(ckpt, cfg.train.checkpoint_every, fingerprint))
    stop_reason = train(data, state, strategy, cfg, [*built, *callbacks])
    mean = state.knots_mean()
    if mean is not None:  # the checkpoint keeps the last step's knots and the sum, to resume from
        with torch.no_grad():
            state.trajectories.knots.copy_(mean)
    run = Run(
        params=dict(state.params),  # a dict[str, Tensor] of the same Parameters
        trajectories=state.trajectories,
        config=cfg,
        K=data.K.double().numpy(),
        width=data.width,
        height=data.height,
        names=data.names,
        exposures=data.exposures,
        V=data.V,
        pose_source=data.report.pose_source,
        test_c2w=data.test_c2w,
        response=state.response,
        history=state.history,
        step=state.step,
    )
    data.report.anchored_mid_poses = state.trajectories.anchored
    run.metrics = RunMetrics(
        preset=cfg.name,
        steps=state.step,
        stop_reason=stop_reason,
        complete=not stop_reason.startswith("interrupted"),
        train_seconds=state.elapsed,
        prepare_seconds=prep_s,
        gaussians=run.num_gaussians,
        final_loss=state.history[-1].loss if state.history else None,
        test=evaluator.final(state),
        test_initial=init_eval,
        prepare=data.report,
        anchored_mid_poses=state.trajectories.anchored,
        c_final=None if state.log_c is None else torch.exp(state.log_c.detach()).tolist(),
        resumed_from=resumed_from,
        response=state.response.values() if state.response.learnable else None,
        averaged_steps=state.knots_count,
    )
    return run
