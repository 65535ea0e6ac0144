"""The reconstruction loop: one step, a small loop with callbacks, and ``reconstruct``.

``prepare`` (ebad.data) turns a capture into ``TrainingData``; ``TrainState.create`` (ebad.state)
starts the Gaussians, trajectories and optimisers; ``train_step`` does one frame (V renders in
ONE rasteriser call, the three losses, Adam, densification) and returns its ``StepStats``;
``train`` repeats it until ``should_stop`` says so, calling each ``Callback`` after every step
(evaluation, progress bar, checkpoints are callbacks); ``reconstruct`` strings them together
and returns a ``Run``, which renders novel views.
"""
from __future__ import annotations

import dataclasses
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import numpy as np
import torch
from torch import Tensor

from .config import Config, preset
from .data import MIN_DOWNSCALED_SIDE, PrepareReport, TrainingData, downscale, prepare
from .errors import ConfigError
from .gaussians import normalise_quats_, num_gaussians, render
from .losses import event_loss, exposure_losses, l1_ssim_each
from .metrics import psnr, ssim
from .response import Response
from .state import StepStats, TrainState, capture_fingerprint, max_gaussians
from .strategy import RenderInfo, Strategy, make_strategy
from .trajectory import ExposureTrajectories, virtual_instants
from .virtual_views import path_lengths_px, random_window, views_from_blur, window_counts

__all__ = ["Run", "RunMetrics", "ViewScores", "with_poses", "frame_losses", "train_step", "train", "should_stop",
           "reconstruct", "evaluate_views", "coarse_data", "views_from_trajectories", "step_profile", "render_images",
           "Callback", "Evaluator", "ProgressBar", "Checkpointer", "StepHook", "warm_up"]


# --------------------------------------------------------------------------- one step

@dataclass
class FrameLosses:
    """The losses of one frame's renders, and what the strategy needs from the render."""

    total: Tensor  # scalar, weighted
    blur: Tensor
    ev: Tensor | None
    edi: Tensor | None
    info: RenderInfo
    mean_render: Tensor  # [H, W, D] detached: what the camera would record of the exposure (response of the mean)
    raster_timings: dict = field(default_factory=dict)  # the rasteriser's ms per stage (its backward's once it ran)
    timings: dict = field(default_factory=dict)  # ms of the forward's parts outside the rasteriser: "poses", "losses"


def frame_losses(data: TrainingData, state: TrainState, f: int, cfg: Config) -> FrameLosses:
    """Losses of frame ``f``: its V virtual views (plus the mid view when V is even and L_EDI
    compares at mid-exposure only) rendered in one batched call."""
    lc = cfg.loss
    V = int(data.V[f])
    u = virtual_instants(V)
    views = data.view_latents[f] if data.view_latents is not None else None  # latents at the V instants
    need_mid = data.latents is not None and V % 2 == 0 and views is None
    if need_mid:
        u = torch.cat([u, torch.tensor([0.5])])
    t0 = time.perf_counter()
    poses = state.trajectories(torch.tensor([f]), u)[0]  # [V', 4, 4]
    t1 = time.perf_counter()
    images, _, meta = render(state.params, poses, data.K, data.width, data.height, cfg.model.background)
    t2 = time.perf_counter()
    mid = V if need_mid else V // 2  # the render L_EDI compares with a mid-exposure latent
    edi_target = None
    if lc.w_edi > 0:
        edi_target = views if views is not None else data.latents[f] if data.latents is not None else None
    counts, event_views, c = None, (), None
    if lc.w_event > 0 and data.ev_counts[f] is not None:
        c = torch.exp(state.log_c) if state.log_c is not None else data.c
        if lc.event_windows == "random":  # one random pair of virtual instants (virtual_views docstring)
            i, j = random_window(V, state.generator)
            counts, event_views = window_counts(data.ev_counts[f], i, j), (i, j)
        else:
            counts, event_views = data.ev_counts[f], tuple(range(V))
    if state.response.learnable:
        blur, edi, ev, mean_render = _losses_through_response(images, V, data.targets[f], edi_target, mid, counts,
                                                              event_views, c, state.response, cfg)
    else:  # the three losses in one autograd node (``losses.exposure_losses``)
        blur, edi, ev, mean_render = exposure_losses(images, V, data.targets[f], edi_target, mid, counts, event_views,
                                                     0.0 if c is None else c, lc.ssim_weight, lc.ssim_window,
                                                     norm=lc.event_norm)
    total = lc.w_blur * blur
    if ev is not None:
        total = total + lc.w_event * ev
    if edi is not None:
        total = total + lc.w_edi * edi
    info = RenderInfo(means2d=meta.get("means2d"), radii=meta.get("radii"), width=data.width, height=data.height)
    return FrameLosses(total=total, blur=blur, ev=ev, edi=edi, info=info, mean_render=mean_render,
                       raster_timings=meta.get("timings", {}),
                       timings={"poses": 1e3 * (t1 - t0), "losses": 1e3 * (time.perf_counter() - t2)})


def _losses_through_response(images: Tensor, V: int, blurry: Tensor, edi_target: Tensor | None, mid: int,
                             counts: Tensor | None, event_views: tuple[int, ...], c, response: Response,
                             cfg: Config) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
    """``losses.exposure_losses`` with a learnt camera response, composed from torch operations:
    L_blur and L_EDI compare the response of the renders (``images`` [V', H, W, D], irradiance)
    with the recorded frame and latents, L_ev the renders themselves. -> L_blur, L_EDI, L_ev and
    the recorded mean render [H, W, D] (detached)."""
    lc = cfg.loss
    renders = images[:V]
    recorded_blur = response(renders.mean(0, keepdim=True))  # what the APS records of the exposure
    pairs = [(recorded_blur, blurry)]  # L_blur and L_EDI (each l1_ssim) from one kernel call
    if edi_target is not None:
        pairs.append((response(renders if edi_target.ndim == 4 else images[mid]), edi_target))
    blur, *edi = l1_ssim_each(pairs, lc.ssim_weight, lc.ssim_window)
    ev = event_loss(images[list(event_views)], counts, c, norm=lc.event_norm) if event_views else None
    return blur, (edi[0] if edi else None), ev, recorded_blur.detach()[0]


def _budget_fraction(state: TrainState, cfg: Config, elapsed: float) -> float:
    """How far through the run: steps over iterations, or time over the budget when that is further."""
    frac = state.step / max(cfg.train.iters, 1)
    if cfg.train.max_seconds:
        frac = max(frac, elapsed / cfg.train.max_seconds)
    return min(frac, 1.0)


def train_step(data: TrainingData, state: TrainState, strategy: Strategy, f: int, cfg: Config,
               elapsed: float = 0.0) -> StepStats:
    """Forward, backward, Adam steps, densification of frame ``f``; advances ``state.step``.
    ``StepStats.profile`` says where the step's time went (``step_profile``)."""
    t0 = time.perf_counter()
    for opt in state.optimizers.values():  # zero_grad(set_to_none=True), without its per-optimizer hooks
        for group in opt.param_groups:
            for p in group["params"]:
                p.grad = None
    out = frame_losses(data, state, f, cfg)
    if not torch.isfinite(out.total):
        raise FloatingPointError(f"non-finite loss at step {state.step} (frame {data.names[f]})")
    frac = _budget_fraction(state, cfg, elapsed)
    out.info.progress = frac
    t1 = time.perf_counter()
    strategy.step_pre_backward(state.params, state.optimizers, state.strategy_state, state.step, out.info)
    t2 = time.perf_counter()
    out.total.backward()
    t3 = time.perf_counter()
    state.optimizers["means"].param_groups[0]["lr"] = cfg.train.lr_means * data.scale * cfg.train.lr_means_final ** frac
    if "poses" in state.optimizers:
        state.optimizers["poses"].param_groups[0]["lr"] = cfg.trajectory.lr * cfg.trajectory.lr_final ** frac
    for name, opt in state.optimizers.items():
        if name == "poses" and state.step < cfg.train.pose_warmup:
            continue
        opt.step()
    normalise_quats_(state.params["quats"])
    t4 = time.perf_counter()
    refine = strategy.step_post_backward(state.params, state.optimizers, state.strategy_state, state.step, out.info)
    state.step += 1
    t5 = time.perf_counter()
    rt = out.raster_timings
    return StepStats(
        step=state.step, frame=data.names[f], loss=float(out.total.detach()), blur=float(out.blur.detach()),
        train_psnr=psnr(out.mean_render, data.targets[f]), gaussians=num_gaussians(state.params), time=elapsed,
        ev=None if out.ev is None else float(out.ev.detach()), edi=None if out.edi is None else float(out.edi.detach()),
        c=None if state.log_c is None or not state.log_c.requires_grad else torch.exp(state.log_c.detach()).tolist(),
        refine=refine, width=data.width,
        profile={"forward": 1e3 * (t1 - t0), "raster_forward": sum(rt.get(k, 0.0) for k in RASTER_FORWARD),
                 "poses": out.timings["poses"], "losses": out.timings["losses"],
                 "backward": 1e3 * (t3 - t2), "raster_backward": sum(rt.get(k, 0.0) for k in RASTER_BACKWARD),
                 "adam": 1e3 * (t4 - t3), "densify": 1e3 * ((t2 - t1) + (t5 - t4)),
                 "step": 1e3 * (time.perf_counter() - t0)},
    )


RASTER_FORWARD = ("project_ms", "bin_ms", "composite_ms")  # splat_cpu's meta["timings"] of its forward
RASTER_BACKWARD = ("backward_project_ms", "backward_composite_ms")  # and of its backward


def step_profile(history: Sequence[StepStats]) -> dict[str, float] | None:
    """Mean ms per step of each part of ``StepStats.profile`` over ``history``, and ``outside_share``:
    the fraction of the steps' time spent outside the rasteriser (the losses and SSIM, the
    trajectory poses, the autograd of both, Adam, densification). None when no step has a profile.

    The parts: ``forward`` (its own parts ``poses``, the trajectories' poses; ``raster_forward``;
    ``losses``, from the renders to the weighted total: the response, L1 + SSIM, L_ev), ``backward``
    (``raster_backward`` inside it), ``adam``, ``densify`` and the whole ``step``."""
    profiles = [h.profile for h in history if h.profile]
    if not profiles:
        return None
    keys = [k for k in profiles[-1] if all(k in p for p in profiles)]  # a resumed run's history may predate a part
    mean = {k: float(np.mean([p[k] for p in profiles])) for k in keys}
    mean["outside_share"] = 1.0 - (mean["raster_forward"] + mean["raster_backward"]) / max(mean["step"], 1e-9)
    mean["steps"] = len(profiles)
    return mean


# --------------------------------------------------------------------------- evaluation

@dataclass
class ViewScores:
    """Mean PSNR / SSIM over some views, and each view's."""

    psnr: float
    ssim: float
    n: int
    per_view: dict[str, dict[str, float]] = field(default_factory=dict)


def render_images(params: dict[str, Tensor], c2w, K, width: int, height: int, background: float = 0.0,
                  batch: int = 8, response: Callable[[Tensor], Tensor] | None = None) -> np.ndarray:
    """Render ``C`` views [C, 4, 4] in batches, without gradients, through the camera ``response``
    when given, clamped to [0, 1] -> [C, H, W, D] numpy float32."""
    c2w_t = torch.as_tensor(np.asarray(c2w), dtype=torch.float32)
    K_t = torch.as_tensor(np.asarray(K), dtype=torch.float32)
    out = []
    with torch.no_grad():
        for i in range(0, c2w_t.shape[0], batch):
            img, _, _ = render(params, c2w_t[i:i + batch], K_t, width, height, background)
            out.append((img if response is None else response(img)).clamp(0, 1))
    return torch.cat(out).numpy()


def score_views(images: np.ndarray, views) -> ViewScores:  # [C, H, W, D], C views with .image and .name
    """PSNR / SSIM of rendered images against the views' images."""
    per = {v.name: {"psnr": psnr(images[i], v.image), "ssim": ssim(images[i], v.image)} for i, v in enumerate(views)}
    return ViewScores(psnr=float(np.mean([p["psnr"] for p in per.values()])),
                      ssim=float(np.mean([p["ssim"] for p in per.values()])), n=len(views), per_view=per)


def with_poses(views, poses: dict[str, np.ndarray]) -> list:
    """The views with their pose replaced by ``poses[name]`` where given (poses in the run's frame)."""
    return [dataclasses.replace(v, c2w=poses[v.name]) if v.name in poses else v for v in views]


def _scorable(views) -> list:
    return [v for v in views if getattr(v, "image", None) is not None and getattr(v, "c2w", None) is not None]


def evaluate_views(render_fn: Callable[[np.ndarray], np.ndarray], views) -> ViewScores | None:
    """Mean PSNR / SSIM of the views that carry an image and a pose (None when none does);
    ``render_fn(c2w [C, 4, 4]) -> [C, H, W, D]``."""
    views = _scorable(views)
    if not views:
        return None
    return score_views(render_fn(np.stack([v.c2w for v in views])), views)


# --------------------------------------------------------------------------- the loop

class Callback(Protocol):
    """Called after every step, in order; ``on_end`` once when the loop stops."""

    def on_step(self, state: TrainState, stats: StepStats) -> None: ...

    def on_end(self, state: TrainState, reason: str) -> None: ...


class Evaluator:
    """Every ``every`` steps (and at ``last``), the test-view PSNR into ``stats.test_psnr``."""

    def __init__(self, data: TrainingData, cfg: Config, views, every: int, last: int):
        self.data, self.cfg, self.every, self.last = data, cfg, every, last
        self.views = _scorable(with_poses(views, data.test_c2w))
        self.latest: ViewScores | None = None
        self.latest_step = -1  # the step ``latest`` was scored at

    def scores(self, state: TrainState) -> ViewScores | None:
        d = self.data
        return evaluate_views(lambda c2w: render_images(state.params, c2w, d.K, d.width, d.height,
                                                        self.cfg.model.background, response=state.response),
                              self.views)

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        if self.views and self.every and (state.step % self.every == 0 or state.step == self.last):
            self.latest, self.latest_step = self.scores(state), state.step
            stats.test_psnr = self.latest.psnr

    def final(self, state: TrainState) -> ViewScores | None:
        """The scores at the state's step: the last evaluation's when it was made there."""
        return self.latest if self.latest_step == state.step else self.scores(state)

    def on_end(self, state: TrainState, reason: str) -> None:
        return None


class ProgressBar:
    """A tqdm bar with the losses, N and the latest (test, else train) PSNR."""

    def __init__(self, cfg: Config, initial: int):
        from tqdm import tqdm

        self.bar = tqdm(total=cfg.train.iters, initial=initial, desc=f"ebad[{cfg.name}]", dynamic_ncols=True,
                        leave=False)
        self.psnr: float | None = None

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        post = {"loss": f"{stats.loss:.4f}", "blur": f"{stats.blur:.4f}"}
        for k in ("ev", "edi"):
            if getattr(stats, k) is not None:
                post[k] = f"{getattr(stats, k):.4f}"
        post["N"] = stats.gaussians
        if stats.test_psnr is not None:
            self.psnr = stats.test_psnr
        post["psnr"] = f"{self.psnr if self.psnr is not None else stats.train_psnr:.2f}"
        self.bar.set_postfix(post, refresh=False)
        self.bar.update(1)

    def on_end(self, state: TrainState, reason: str) -> None:
        self.bar.close()


class Checkpointer:
    """Every ``every`` steps (0: never during the loop) and at the end, ``state.save(path)``."""

    def __init__(self, path: Path, every: int, fingerprint: dict[str, Any] | None):
        self.path, self.every, self.fingerprint = path, every, fingerprint

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        if self.every and state.step % self.every == 0:
            state.save(self.path, self.fingerprint)

    def on_end(self, state: TrainState, reason: str) -> None:
        state.save(self.path, self.fingerprint)


class StepHook:
    """A user function ``fn(step, stats)`` after every step."""

    def __init__(self, fn: Callable[[int, StepStats], None]):
        self.fn = fn

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        self.fn(state.step, stats)

    def on_end(self, state: TrainState, reason: str) -> None:
        return None


def should_stop(history: Sequence[StepStats], elapsed: float, cfg: Config) -> str | None:
    """'time' when the wall-time budget is spent, 'plateau' when the windowed loss stalled."""
    tc = cfg.train
    if tc.max_seconds is not None and elapsed >= tc.max_seconds:
        return "time"
    step = history[-1].step if history else 0
    if tc.plateau_patience > 0 and step > 0 and step % tc.plateau_every == 0:
        w = tc.plateau_every
        losses = [h.loss for h in history]
        windows = [np.mean(losses[i:i + w]) for i in range(0, len(losses) - w + 1, w)]
        if len(windows) > tc.plateau_patience:
            best_before = min(windows[:-tc.plateau_patience])
            recent = min(windows[-tc.plateau_patience:])
            if recent > best_before * (1 - tc.plateau_tol):
                return "plateau"
    return None


class _Interrupts:
    """SIGINT / SIGTERM set a flag the loop checks after each step (so the state stays whole and
    is checkpointed); a second Ctrl-C raises KeyboardInterrupt at once."""

    def __init__(self):
        self.received: str | None = None
        self._old: dict[int, Any] = {}

    def _handle(self, signum, frame):
        if self.received is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


@contextmanager
def _torch_single_threaded():
    """torch single-threaded for the duration, its thread count restored after. A step's torch
    operations are small: on one thread they neither spin between parallel regions (when
    ``ebad.OMP_PASSIVE`` is False, see the ``ebad`` package docstring) nor wait for sleeping
    threads to wake, and the parallel work is numba's (rasteriser, SSIM), whose threads are
    its own. On the numba omp layer (``splat_cpu._numba_impl``) a step at 346x260 took 14.2
    against 15.7 ms at half resolution and 30.2 against 33.1 ms at full resolution with torch on
    one thread rather than two (realistic capture, seed 0, one 70-step run each)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def coarse_data(data: TrainingData, cfg: Config) -> TrainingData | None:
    """The coarse phase's problem (``train.coarse_scale``), or None when there is none: no coarse
    phase configured, or frames too small for it (``data.MIN_DOWNSCALED_SIDE``)."""
    s = cfg.train.coarse_scale
    if s <= 1 or cfg.train.coarse_until <= 0 or min(data.height, data.width) < MIN_DOWNSCALED_SIDE * s:
        return None
    return downscale(data, s)


PATH_SAMPLES = 9  # instants over an exposure at which views_from_trajectories follows the scene's points
PATH_POINTS = 4096  # at most this many Gaussian centres (evenly strided) stand for the scene there


@torch.no_grad()
def views_from_trajectories(data: TrainingData, state: TrainState, cfg: Config) -> np.ndarray:  # [F]
    """V per frame from the learnt trajectories (``trajectory.view_spacing``): each blurry
    frame's image path length at full resolution (``virtual_views.path_lengths_px``, over the
    Gaussians' centres) over the spacing, within [2, max_views]."""
    means = state.params["means"].detach()
    points = means[:: max(1, len(means) // PATH_POINTS)]
    poses = state.trajectories(torch.arange(data.num_frames), torch.linspace(0, 1, PATH_SAMPLES))
    lengths = path_lengths_px(poses, points, data.K, data.width, data.height)
    return views_from_blur(lengths, data.V, cfg.trajectory.view_spacing, cfg.trajectory.max_views)


def train(data: TrainingData, state: TrainState, strategy: Strategy, cfg: Config,
          callbacks: Sequence[Callback] = ()) -> str:
    """Steps until ``train.iters``, a stop rule or a signal; returns why it stopped:
    'iters', 'time', 'plateau' or 'interrupted (SIGINT)' / 'interrupted (SIGTERM)'.

    The first ``train.coarse_until`` of the run trains on ``coarse_data``; where that phase ends,
    ``trajectory.view_spacing`` > 0 gives each frame its V from the trajectories learnt so far
    (``views_from_trajectories``, ``data.set_views``: ``data`` changes in place; a resumed run
    past that point chooses again at its first step). From ``trajectory.average_from`` on, every
    step's knots are added to ``state.knots_sum`` (``reconstruct`` gives the run their mean)."""
    started = time.perf_counter() - state.elapsed
    reason = "iters"
    coarse = coarse_data(data, cfg)
    views_due = cfg.trajectory.view_spacing > 0 and bool((data.V > 1).any())
    averaging = cfg.trajectory.average_from < 1 and "poses" in state.optimizers
    with _Interrupts() as interrupts, _torch_single_threaded():
        try:
            while state.step < cfg.train.iters:
                f = state.next_frame()
                elapsed = time.perf_counter() - started
                fine = _budget_fraction(state, cfg, elapsed) >= cfg.train.coarse_until
                if views_due and fine:
                    data.set_views(views_from_trajectories(data, state, cfg))
                    views_due = False
                level = data if fine or coarse is None else coarse
                stats = train_step(level, state, strategy, f, cfg, elapsed)
                state.elapsed = stats.time = time.perf_counter() - started
                if averaging and _budget_fraction(state, cfg, state.elapsed) >= cfg.trajectory.average_from:
                    state.accumulate_knots()
                state.history.append(stats)
                for cb in callbacks:
                    cb.on_step(state, stats)
                if interrupts.received:
                    reason = f"interrupted ({interrupts.received})"
                    break
                stop = should_stop(state.history, state.elapsed, cfg)
                if stop:
                    reason = stop
                    break
        finally:
            for cb in callbacks:
                cb.on_end(state, reason)
    return reason


def warm_up() -> float:
    """Compile every numba kernel a reconstruction runs (or load it from numba's cache): three
    steps of the ``ebad`` preset on a tiny synthetic capture, which reach the rasteriser, SSIM
    and L_ev kernels that every preset uses. Timed comparisons call it first so that no
    method's budget pays for compilation: on a cold cache the first step of a run took 15 s
    (the rasteriser's backward and SSIM) and 1.7 s more for L_ev. Returns its seconds (about
    1 s on a warm cache)."""
    import scenes

    t0 = time.perf_counter()
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 3, False, 0
    reconstruct(scenes.make_scene("boxes", size="tiny", n_frames=3, n_test=1).capture, cfg)
    return time.perf_counter() - t0


# --------------------------------------------------------------------------- run

@dataclass
class RunMetrics:
    """What a reconstruction reports (``metrics.json``)."""

    preset: str
    steps: int
    stop_reason: str  # iters | time | plateau | interrupted (...)
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
    def from_dict(cls, d: dict[str, Any]) -> "RunMetrics":
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
    pose_source: str = "capture"  # where the training poses came from: capture | colmap | static
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
    def render(self, c2w, K=None, width: int | None = None, height: int | None = None,
               batch: int = 8) -> np.ndarray:  # [4, 4] -> [H, W, D]; [C, 4, 4] -> [C, H, W, D]
        """Render novel views (numpy float32 in [0, 1]); K, width, height default to the capture's."""
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
        res = render_images(self.params, c2w_t, self.K if K is None else K, W, H, self.config.model.background, batch,
                            response=self.response)
        return res[0] if single else res

    @torch.no_grad()
    def deblurred_frames(self) -> np.ndarray:  # [F, H, W, D]
        """Every training frame re-rendered sharp at its mid-exposure pose."""
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


def reconstruct(capture, config: Config | str | None = None, out_dir: str | Path | None = None,
                resume: bool = False, gt_views=None, on_step: Callable[[int, StepStats], None] | None = None,
                callbacks: Sequence[Callback] = ()) -> Run:
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
    """
    cfg = _resolve(config)
    torch.manual_seed(cfg.train.seed)
    t_prep = time.perf_counter()
    data = prepare(capture, cfg)
    prep_s = time.perf_counter() - t_prep
    fingerprint = capture_fingerprint(capture)
    ckpt = Path(out_dir) / "checkpoints" / "last.pt" if out_dir is not None else None
    resumed_from = None
    if resume and ckpt is not None and ckpt.exists():
        state = TrainState.load(ckpt, data, cfg, fingerprint)
        resumed_from = state.step
    else:
        state = TrainState.create(data, cfg)
    strategy = make_strategy(cfg.strategy, data.scale, max_gaussians(cfg, data), state.generator)
    strategy.check_sanity(state.params, state.optimizers)
    if resumed_from is None:
        state.strategy_state = strategy.initialize_state(state.num_gaussians)
    views = data.test_views if gt_views is None else gt_views  # poses from data.test_c2w where known
    evaluator = Evaluator(data, cfg, views, cfg.train.eval_every, cfg.train.iters)
    init_eval = evaluator.scores(state) if state.step == 0 else None
    extra = list(callbacks)
    callbacks: list[Callback] = [evaluator]
    if cfg.train.progress:
        callbacks.append(ProgressBar(cfg, state.step))
    if on_step is not None:
        callbacks.append(StepHook(on_step))
    if ckpt is not None:
        callbacks.append(Checkpointer(ckpt, cfg.train.checkpoint_every, fingerprint))
    stop_reason = train(data, state, strategy, cfg, [*callbacks, *extra])
    mean = state.knots_mean()
    if mean is not None:  # the checkpoint keeps the last step's knots and the sum, to resume from
        with torch.no_grad():
            state.trajectories.knots.copy_(mean)
    run = Run(params=state.params, trajectories=state.trajectories, config=cfg, K=data.K.double().numpy(),
              width=data.width, height=data.height, names=data.names, exposures=data.exposures, V=data.V,
              pose_source=data.report.pose_source, test_c2w=data.test_c2w, response=state.response,
              history=state.history, step=state.step)
    data.report.anchored_mid_poses = state.trajectories.anchored
    run.metrics = RunMetrics(
        preset=cfg.name, steps=state.step, stop_reason=stop_reason, complete=not stop_reason.startswith("interrupted"),
        train_seconds=state.elapsed, prepare_seconds=prep_s, gaussians=run.num_gaussians,
        final_loss=state.history[-1].loss if state.history else None, test=evaluator.final(state),
        test_initial=init_eval, prepare=data.report, anchored_mid_poses=state.trajectories.anchored,
        c_final=None if state.log_c is None else torch.exp(state.log_c.detach()).tolist(), resumed_from=resumed_from,
        response=state.response.values() if state.response.learnable else None, averaged_steps=state.knots_count,
    )
    return run
