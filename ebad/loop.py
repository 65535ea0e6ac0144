"""The training loop: one step, and the loop that repeats it.

``frame_losses`` renders one frame's V virtual views in ONE rasteriser call and computes the
three losses; ``train_step`` adds the backward, Adam and densification and returns its
``StepStats``; ``train`` repeats it until ``should_stop`` says so, calling each ``Callback``
(``ebad.callbacks``) after every step. The data it trains on is prepared before
(``ebad.data.prepare``), the state started before (``ebad.state.TrainState``), and
``ebad.run.reconstruct`` strings them together.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from .callbacks import Callback, Checkpointer
from .config import Config
from .data import MIN_DOWNSCALED_SIDE, TrainingData, downscale
from .errors import UserError
from .gaussians import normalise_quats_, num_gaussians, render
from .losses import cfa_project, event_loss, exposure_losses, l1_ssim_each
from .metrics import psnr
from .response import Response
from .schedule import Phase, Schedule
from .state import StepStats, TrainState
from .strategy import RenderInfo, Strategy
from .threads import torch_single_threaded
from .trajectory import virtual_instants
from .virtual_views import path_lengths_px, random_window, views_from_blur, window_counts

__all__ = [
    "StopReason",
    "DivergedError",
    "LR_OPTIONS",
    "FrameLosses",
    "frame_losses",
    "train_step",
    "train",
    "should_stop",
    "check_not_empty",
    "step_profile",
    "coarse_data",
    "views_from_trajectories",
    "RASTER_FORWARD",
    "RASTER_BACKWARD",
]


class DivergedError(UserError):
    """Training diverged: the loss or a parameter became non-finite (a learning rate too high)."""


# the option that sets each optimizer's learning rate (``state.make_optimizers``), named when it diverges
LR_OPTIONS = {
    "means": "--train.lr_means",
    "scales": "--train.lr_scales",
    "quats": "--train.lr_quats",
    "opacities": "--train.lr_opacities",
    "colors": "--train.lr_colors",
    "sh_rest": "--train.lr_colors",
    "poses": "--trajectory.lr",
    "contrast": "--loss.lr_contrast",
    "response": "--model.lr_response",
}
DIVERGED_HINT = "the last checkpoint saved before it, if any, is kept"


def _diverged(step: int, what: str, options: Sequence[str]) -> DivergedError:
    opts = ", ".join(options) if options else "the learning rates (--train.lr_*)"
    return DivergedError(f"training diverged at step {step}: {what} became non-finite; lower {opts}; {DIVERGED_HINT}")


def check_finite(state: TrainState, step: int) -> None:
    """Every optimised parameter is finite, else ``DivergedError`` naming the learning-rate option(s) to lower."""
    bad = [
        name
        for name, opt in state.optimizers.items()
        if any(not bool(torch.isfinite(p).all()) for g in opt.param_groups for p in g["params"])
    ]
    if bad:
        raise _diverged(step, f"the {', '.join(bad)} parameters", [LR_OPTIONS.get(b, b) for b in bad])


log = logging.getLogger(__name__)

# A run whose loss over its last steps is this many times its first step's (the initial scene's)
# has diverged while staying finite (a learning rate far too high: --train.lr_means 1e3 ends at 4x)
DIVERGED_LOSS_FACTOR = 2.0
DIVERGED_LOSS_WINDOW = 20  # the last steps averaged (at most a quarter of the run)


def _end_window(history: Sequence[StepStats]) -> int:
    """The steps at a run's end that its divergence checks average: ``DIVERGED_LOSS_WINDOW``, at most a quarter
    of the run (0: too short to judge)."""
    return min(DIVERGED_LOSS_WINDOW, len(history) // 4)


def loss_rose(history: Sequence[StepStats]) -> str | None:
    """A warning when the loss of the last steps is ``DIVERGED_LOSS_FACTOR`` x the first step's, else None."""
    w = _end_window(history)
    if w < 1:
        return None
    first, last = history[0].loss, float(np.mean([h.loss for h in history[-w:]]))
    if not last > DIVERGED_LOSS_FACTOR * first:
        return None
    return (
        f"training diverged: the loss rose from {first:.4g} at step {history[0].step} to {last:.4g} over the "
        f"last {w} steps; the result is worse than the start: lower the learning rates (--train.lr_means first)"
    )


COLLAPSED_PSNR_DROP = 10.0  # dB: the last steps' training PSNR this far below the run's best window


def psnr_collapsed(history: Sequence[StepStats]) -> str | None:
    """A warning when the mean training PSNR of the last steps lies ``COLLAPSED_PSNR_DROP`` dB below the
    best mean over any window of as many steps, else None: a run that learnt the scene and then lost it
    (the loss can end below its first step's, so ``loss_rose`` stays silent: an SfM start with 26 points
    on a tiny colour capture rose to 20.8 dB, fell to 4 at step 700 and ended there, with exit 0)."""
    w = _end_window(history)
    if w < 1:
        return None
    ps = np.clip(np.nan_to_num(np.array([h.train_psnr for h in history], float), nan=0.0), 0.0, 100.0)
    means = np.convolve(ps, np.ones(w) / w, mode="valid")
    best = int(np.argmax(means))
    if not means[best] - means[-1] > COLLAPSED_PSNR_DROP:
        return None
    return (
        f"training collapsed: the training PSNR fell from {means[best]:.1f} dB (steps {history[best].step}-"
        f"{history[best + w - 1].step}) to {means[-1]:.1f} dB over the last {w} steps; the result is far worse "
        "than the run's best: lower the learning rates (--train.lr_means, --trajectory.lr) or check the poses"
    )


StopReason = Literal["iters", "time", "plateau", "interrupted (SIGINT)", "interrupted (SIGTERM)"]  # why train() stopped


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
    alpha: float | None = None  # largest alpha of the renders (in the first train.empty_render_steps steps only)


def frame_losses(data: TrainingData, state: TrainState, f: int, cfg: Config, sh_degree: int = 0) -> FrameLosses:
    """Losses of frame ``f``: its V virtual views (plus the mid view when V is even and L_EDI
    compares at mid-exposure only) rendered in one batched call, with the SH degree ``sh_degree``
    (the schedule's, ``Phase.sh_degree``; 0: view-independent colours)."""
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
    images, alphas, meta = render(
        state.params, poses, data.K, data.width, data.height, cfg.model.background, sh_degree=sh_degree
    )
    t2 = time.perf_counter()
    mid = V if need_mid else V // 2  # the render L_EDI compares with a mid-exposure latent
    edi_target = None
    if lc.w_edi > 0:
        edi_target = views if views is not None else data.latents[f] if data.latents is not None else None
        if edi_target is not None and data.edi_tables is not None and state.response.learnable:  # in irradiance
            tab = data.edi_tables.targets(f, data.frames[f], state.response, data.c_recorded)
            edi_target = tab if views is not None else tab[0]
    counts: Tensor | None = None
    event_views: tuple[int, ...] = ()
    c = None
    frame_counts = data.ev_counts[f]
    if lc.w_event > 0 and frame_counts is not None:
        c = torch.exp(state.log_c) if state.log_c is not None else data.c
        if lc.event_windows == "random":  # one random pair of virtual instants (virtual_views docstring)
            i, j = random_window(V, state.generator)
            counts, event_views = window_counts(frame_counts, i, j), (i, j)
        else:
            counts, event_views = frame_counts, tuple(range(V))
    if state.response.learnable:
        blur, edi, ev, mean_render = _losses_through_response(
            images,
            V,
            data.targets[f],
            edi_target,
            mid,
            counts,
            event_views,
            c,
            state.response,
            cfg,
            data.cfa_weights,
            data.c_recorded,
        )
    else:  # the three losses in one autograd node (``losses.exposure_losses``)
        blur, edi, ev, mean_render = exposure_losses(
            images,
            V,
            data.targets[f],
            edi_target,
            mid,
            counts,
            event_views,
            0.0 if c is None else c,
            lc.ssim_weight,
            lc.ssim_window,
            norm=lc.event_norm,
            cfa=data.cfa_weights,
        )
    total = lc.w_blur * blur
    if ev is not None:
        total = total + lc.w_event * ev
    if edi is not None:
        total = total + lc.w_edi * edi
    info = RenderInfo(means2d=meta.get("means2d"), radii=meta.get("radii"), width=data.width, height=data.height)
    return FrameLosses(
        total=total,
        blur=blur,
        ev=ev,
        edi=edi,
        info=info,
        mean_render=mean_render,
        raster_timings=meta.get("timings", {}),
        timings={"poses": 1e3 * (t1 - t0), "losses": 1e3 * (time.perf_counter() - t2)},
        alpha=float(alphas.detach().max()) if state.step < cfg.train.empty_render_steps else None,
    )


def _losses_through_response(
    images: Tensor,
    V: int,
    blurry: Tensor,
    edi_target: Tensor | None,
    mid: int,
    counts: Tensor | None,
    event_views: tuple[int, ...],
    c,
    response: Response,
    cfg: Config,
    cfa: Tensor | None = None,
    c_recorded: bool = False,
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
    """``losses.exposure_losses`` with a learnt camera response, composed from torch operations:
    L_blur and L_EDI compare the response of the renders (``images`` [V', H, W, D], irradiance)
    with the recorded frame and latents. L_ev compares in the units of ``c``: the log of the
    renders themselves for a c in log irradiance (the events' units), the log of their response
    when ``c_recorded`` (c estimated from the recorded frames: ``TrainingData.c_recorded``,
    ``ebad.response``). With ``cfa`` weights and one-channel (raw mosaic) frames, the renders'
    ``cfa_project`` is what the response maps for L_blur and L_EDI. -> L_blur, L_EDI, L_ev and
    the recorded mean render [H, W, D] (detached)."""
    lc = cfg.loss
    compared = cfa_project(images, cfa) if cfa is not None and blurry.shape[-1] == 1 else images
    renders = compared[:V]
    recorded_blur = response(renders.mean(0, keepdim=True))  # what the APS records of the exposure
    pairs = [(recorded_blur, blurry)]  # L_blur and L_EDI (each l1_ssim) from one kernel call
    if edi_target is not None:
        pairs.append((response(renders if edi_target.ndim == 4 else compared[mid]), edi_target))
    blur, *edi = l1_ssim_each(pairs, lc.ssim_weight, lc.ssim_window)
    ev = None
    if event_views:
        assert counts is not None  # given with event_views (frame_losses)
        seen = images[list(event_views)]
        ev = event_loss(response(seen) if c_recorded else seen, counts, c, norm=lc.event_norm, cfa=cfa)
    return blur, (edi[0] if edi else None), ev, recorded_blur.detach()[0]


def train_step(
    data: TrainingData,
    state: TrainState,
    strategy: Strategy,
    f: int,
    cfg: Config,
    elapsed: float = 0.0,
    phase: Phase | None = None,
) -> StepStats:
    """Forward, backward, Adam steps, densification of frame ``f``; advances ``state.step``.
    ``phase``: where the step stands in the run's ``Schedule`` (learning rates, whether opacity
    resets may fire); by default the config's schedule at ``state.step`` and ``elapsed`` seconds.
    ``StepStats.profile`` says where the step's time went (``step_profile``)."""
    if phase is None:
        phase = Schedule.from_config(cfg, data.scale).at(state.step, elapsed)
    t0 = time.perf_counter()
    for opt in state.optimizers.values():  # zero_grad(set_to_none=True), without its per-optimizer hooks
        for group in opt.param_groups:
            for p in group["params"]:
                p.grad = None
    out = frame_losses(data, state, f, cfg, sh_degree=phase.sh_degree)
    if not torch.isfinite(out.total):
        raise _diverged(state.step, f"the loss (frame {data.names[f]})", [LR_OPTIONS["means"], "--train.lr_*"])
    out.info.progress, out.info.resets = phase.fraction, phase.resets
    t1 = time.perf_counter()
    strategy.step_pre_backward(state.params, state.optimizers, state.strategy_state, state.step, out.info)
    t2 = time.perf_counter()
    out.total.backward()
    t3 = time.perf_counter()
    state.optimizers["means"].param_groups[0]["lr"] = phase.lr_means
    if "poses" in state.optimizers:
        state.optimizers["poses"].param_groups[0]["lr"] = phase.lr_poses
    for name, opt in state.optimizers.items():
        if name == "poses" and state.step < cfg.train.pose_warmup:
            continue
        opt.step()
    normalise_quats_(state.params["quats"])
    check_finite(state, state.step)
    t4 = time.perf_counter()
    refine = strategy.step_post_backward(state.params, state.optimizers, state.strategy_state, state.step, out.info)
    state.step += 1
    t5 = time.perf_counter()
    rt = out.raster_timings
    return StepStats(
        step=state.step,
        frame=data.names[f],
        loss=float(out.total.detach()),
        blur=float(out.blur.detach()),
        train_psnr=psnr(out.mean_render, data.targets[f]),
        gaussians=num_gaussians(state.params),
        time=elapsed,
        ev=None if out.ev is None else float(out.ev.detach()),
        edi=None if out.edi is None else float(out.edi.detach()),
        c=None if state.log_c is None or not state.log_c.requires_grad else torch.exp(state.log_c.detach()).tolist(),
        refine=refine,
        width=data.width,
        alpha=out.alpha,
        profile={
            "forward": 1e3 * (t1 - t0),
            "raster_forward": sum(rt.get(k, 0.0) for k in RASTER_FORWARD),
            "poses": out.timings["poses"],
            "losses": out.timings["losses"],
            "backward": 1e3 * (t3 - t2),
            "raster_backward": sum(rt.get(k, 0.0) for k in RASTER_BACKWARD),
            "adam": 1e3 * (t4 - t3),
            "densify": 1e3 * ((t2 - t1) + (t5 - t4)),
            "step": 1e3 * (time.perf_counter() - t0),
        },
    )


RASTER_FORWARD = ("sh_ms", "project_ms", "bin_ms", "composite_ms")  # splat_cpu's meta["timings"] of its forward
RASTER_BACKWARD = ("backward_sh_ms", "backward_project_ms", "backward_composite_ms")  # and of its backward


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


EMPTY_ALPHA = 1.0 / 255.0  # a render whose alpha stays below this at every pixel shows nothing (splat_cpu ALPHA_MIN)


def check_not_empty(history: Sequence[StepStats], cfg: Config) -> None:
    """Raise ``UserError`` when the run has done its first ``train.empty_render_steps`` steps (or all
    its steps, when fewer) and every render of them was empty: nothing is in front of the cameras
    and no gradient can bring it there; the run would otherwise finish with a black scene."""
    n = min(cfg.train.empty_render_steps, cfg.train.iters)
    if n <= 0 or len(history) < n or history[-1].step != n:
        return
    alphas = [h.alpha for h in history[-n:]]
    if any(a is None or a >= EMPTY_ALPHA for a in alphas):
        return
    raise UserError(
        f"every render of the first {n} steps is empty (largest alpha {max(a or 0.0 for a in alphas):.2g}): no "
        "Gaussian is in front of the cameras; check the capture's poses and intrinsics, or set the initial depth "
        "range with --model.init_depth NEAR FAR (--train.empty_render_steps 0 turns this check off)"
    )


def should_stop(history: Sequence[StepStats], elapsed: float, cfg: Config) -> Literal["time", "plateau"] | None:
    """'time' when the wall-time budget is spent, 'plateau' when the windowed loss stalled."""
    tc = cfg.train
    if tc.max_seconds is not None and elapsed >= tc.max_seconds:
        return "time"
    step = history[-1].step if history else 0
    if tc.plateau_patience > 0 and step > 0 and step % tc.plateau_every == 0:
        w = tc.plateau_every
        losses = [h.loss for h in history]
        windows = [np.mean(losses[i : i + w]) for i in range(0, len(losses) - w + 1, w)]
        if len(windows) > tc.plateau_patience:
            best_before = min(windows[: -tc.plateau_patience])
            recent = min(windows[-tc.plateau_patience :])
            if recent > best_before * (1 - tc.plateau_tol):
                return "plateau"
    return None


class _Interrupts:
    """SIGINT / SIGTERM set a flag the loop checks after each step (so the state stays whole and
    is checkpointed); a second Ctrl-C raises KeyboardInterrupt at once."""

    def __init__(self) -> None:
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


def train(
    data: TrainingData, state: TrainState, strategy: Strategy, cfg: Config, callbacks: Sequence[Callback] = ()
) -> StopReason:
    """Steps until ``train.iters``, a stop rule or a signal; returns why it stopped:
    'iters', 'time', 'plateau' or 'interrupted (SIGINT)' / 'interrupted (SIGTERM)'.

    What happens when is the run's ``Schedule`` (``ebad.schedule``), made here once: the coarse
    phase trains on ``coarse_data``; where it ends, ``trajectory.view_spacing`` > 0 gives each
    frame its V from the trajectories learnt so far (``views_from_trajectories``,
    ``data.set_views``: ``data`` changes in place; a resumed run past that point chooses again at
    its first step); from ``trajectory.average_from`` on, every step's knots are added to
    ``state.knots_sum`` (``reconstruct`` gives the run their mean)."""
    started = time.perf_counter() - state.elapsed
    reason: StopReason = "iters"
    coarse = coarse_data(data, cfg)
    schedule = Schedule.from_config(
        cfg,
        data.scale,
        coarse=coarse is not None,
        choose_views=bool((data.V > 1).any()),
        averaging="poses" in state.optimizers,
    )
    views_pending = schedule.views_at is not None
    diverged = False
    with _Interrupts() as interrupts, torch_single_threaded():
        try:
            while state.step < cfg.train.iters:
                f = state.next_frame()
                elapsed = time.perf_counter() - started
                phase = schedule.at(state.step, elapsed)
                if views_pending and phase.views_due:
                    data.set_views(views_from_trajectories(data, state, cfg))
                    views_pending = False
                level = coarse if phase.coarse and coarse is not None else data
                try:
                    stats = train_step(level, state, strategy, f, cfg, elapsed, phase)
                except DivergedError:
                    diverged = True
                    raise
                except ValueError as exc:  # the rasteriser's check of its inputs (non-finite poses or Gaussians)
                    if "non-finite" not in str(exc):
                        raise
                    diverged = True
                    raise _diverged(state.step, f"the rasteriser's input ({exc})", []) from None
                state.elapsed = stats.time = time.perf_counter() - started
                if schedule.at(state.step, state.elapsed).averaging:  # judged where the step ended
                    state.accumulate_knots()
                state.history.append(stats)
                check_not_empty(state.history, cfg)
                for cb in callbacks:
                    cb.on_step(state, stats)
                if interrupts.received:
                    reason = "interrupted (SIGINT)" if interrupts.received == "SIGINT" else "interrupted (SIGTERM)"
                    break
                stop = should_stop(state.history, state.elapsed, cfg)
                if stop:
                    reason = stop
                    break
            warning = loss_rose(state.history) or psnr_collapsed(state.history)
            if warning:
                log.warning("%s", warning)
        finally:
            for cb in callbacks:
                if diverged and isinstance(cb, Checkpointer):
                    continue  # a diverged state is not saved over the last good checkpoint
                cb.on_end(state, reason)
    return reason
