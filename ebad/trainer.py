"""The reconstruction: prepare a capture, optimise Gaussians and trajectories, return a Run.

Composed of small functions: ``prepare`` (poses, V per frame, c, event sums, EDI latents:
every "skip" decision is made and recorded here), ``init_gaussians``, ``make_optimizers``,
``train_step`` (one frame: V renders in ONE rasteriser call, the three losses), ``should_stop``
(time budget, plateau), ``evaluate_views``; ``reconstruct`` strings them together with a
progress bar and checkpoints. ``Run`` holds the result and renders novel views.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from .config import Config, preset
from .errors import UserError
from .gaussians import (init_params, num_gaussians, plane_sweep_points, points_from_frames, render,
                        scene_scale)
from .losses import blur_loss, edi_loss, event_loss
from .metrics import psnr, ssim
from .strategy import make_strategy
from .trajectory import ExposureTrajectories, virtual_instants
from .views import choose_num_views, event_sums, events_per_pixel

__all__ = ["Problem", "Run", "prepare", "init_gaussians", "make_optimizers", "train_step",
           "reconstruct", "evaluate_views"]


# --------------------------------------------------------------------------- problem

@dataclass
class Problem:
    """Everything the loop needs, precomputed from a capture (train frames only)."""

    frames: Tensor  # [F, H, W, D] blurry training frames
    targets: Tensor  # [F, H, W, D] what L_blur compares to (frames or EDI latents)
    latents: Tensor | None  # [F, H, W, D] EDI latents at mid-exposure, or None (no L_EDI)
    exposures: np.ndarray  # [F, 2] seconds
    names: list[str]
    c2w: Tensor  # [F, 4, 4] initial mid-exposure poses
    K: Tensor  # [3, 3]
    V: np.ndarray  # [F] virtual views per frame
    ev_sums: list[Tensor | None]  # per frame [V - 1, H, W] or None (no L_ev)
    c: float | None  # contrast threshold in use (None: no events used)
    scale: float  # scene scale (world units)
    depth_range: tuple[float, float]
    points: Tensor | None = None  # [P, 3] SfM points, when any
    point_colors: Tensor | None = None  # [P, D]
    test_views: list = field(default_factory=list)
    report: dict[str, Any] = field(default_factory=dict)

    @property
    def height(self) -> int:
        return int(self.frames.shape[1])

    @property
    def width(self) -> int:
        return int(self.frames.shape[2])


def _train_indices(capture) -> list[int]:
    if not capture.split:
        return list(range(capture.num_frames))
    idx = [i for i, s in enumerate(capture.split) if s == "train"]
    if not idx:
        raise UserError("capture has no frame with split 'train'")
    return idx


def _check_capture(capture) -> None:
    fr = capture.frames
    if not isinstance(fr, np.ndarray) or fr.ndim != 4 or fr.shape[-1] not in (1, 3):
        raise UserError(f"capture.frames must be [F, H, W, 1|3], got {getattr(fr, 'shape', type(fr))}")
    if not np.isfinite(fr).all():
        raise UserError("capture.frames has non-finite values")
    ex = np.asarray(capture.exposures)
    if ex.shape != (fr.shape[0], 2):
        raise UserError(f"capture.exposures must be [F, 2] = {(fr.shape[0], 2)}, got {ex.shape}")
    if np.asarray(capture.K).shape != (3, 3):
        raise UserError(f"capture.K must be [3, 3], got {np.asarray(capture.K).shape}")


def _poses(capture, cfg: Config, idx: list[int]):
    """Mid-exposure poses of the training frames, and SfM points when SfM ran."""
    src = cfg.trajectory.pose_source
    if src in ("auto", "capture") and capture.c2w is not None:
        return np.asarray(capture.c2w, dtype=np.float64)[idx], None, None, "capture", idx
    if src == "capture":
        raise UserError("trajectory.pose_source is 'capture' but the capture has no poses (c2w)")
    if src == "static":
        return np.repeat(np.eye(4)[None], len(idx), axis=0), None, None, "static", idx
    try:
        from scenes.colmap import estimate_poses
    except ImportError as exc:  # pragma: no cover - depends on the scenes package
        raise UserError(f"the capture has no poses and scenes.colmap is unavailable: {exc}") from exc
    try:
        est = estimate_poses(capture)
    except ValueError as exc:  # scenes.colmap.SfMError: too few frames registered
        raise UserError(f"{exc} (for a camera that did not move, use --trajectory.pose_source static)") from exc
    reg = np.asarray(getattr(est, "registered", np.ones(capture.num_frames, bool)), dtype=bool)
    keep = [i for i in idx if reg[i]]
    if len(keep) < 2:
        raise UserError(f"pycolmap registered only {len(keep)} training frame(s); cannot reconstruct "
                        "(for a camera that did not move, use --trajectory.pose_source static)")
    pts = torch.from_numpy(np.asarray(est.points, dtype=np.float32)) if len(est.points) else None
    cols = None
    if pts is not None:
        cols = np.asarray(est.colors, dtype=np.float32)
        if cols.max() > 1.0:
            cols = cols / 255.0
        if capture.channels == 1 and cols.shape[1] == 3:
            cols = cols.mean(1, keepdims=True)
        cols = torch.from_numpy(cols)
    return np.asarray(est.c2w, dtype=np.float64)[keep], pts, cols, "colmap", keep


def _depth_range(capture, cfg: Config, c2w: np.ndarray, points: Tensor | None) -> tuple[float, float]:
    if cfg.model.init_depth is not None:
        return tuple(float(v) for v in cfg.model.init_depth)
    if "depth_range" in capture.meta:
        lo, hi = capture.meta["depth_range"]
        return float(lo), float(hi)
    if points is not None and len(points) > 0:
        R, t = c2w[:, :3, :3], c2w[:, :3, 3]
        z = np.einsum("fji,fnj->fni", R, points.numpy()[None] - t[:, None])[..., 2]
        z = z[z > 0]
        if z.size:
            return float(np.percentile(z, 5)), float(np.percentile(z, 95))
    d0 = focus_depth(c2w)
    if d0 is not None:
        return 0.4 * d0, 2.5 * d0
    s = scene_scale(c2w)
    return 0.5 * s, 2.0 * s


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


def prepare(capture, cfg: Config) -> Problem:
    """Validate the capture and make every "skip what is not needed" decision (recorded in ``report``)."""
    _check_capture(capture)
    idx = _train_indices(capture)
    c2w, points, point_colors, pose_src, idx = _poses(capture, cfg, idx)
    frames_np = np.asarray(capture.frames, dtype=np.float32)[idx]
    exposures = np.asarray(capture.exposures, dtype=np.float64)[idx]
    events = capture.events
    has_events = events is not None and len(events) > 0
    lc = cfg.loss
    wants_events = lc.w_event > 0 or lc.w_edi > 0 or lc.target == "edi"
    use_events = wants_events and has_events
    report: dict[str, Any] = {"pose_source": pose_src, "train_frames": len(idx),
                              "channels": int(frames_np.shape[-1])}
    if wants_events and not has_events:
        report["skipped"] = "no events: L_ev and L_EDI off, EDI target = frames"

    c = None
    if use_events:
        if lc.contrast is not None:
            c = float(lc.contrast)
            report["c_source"] = "config"
        else:
            import edi

            c = float(edi.estimate_c(frames_np, exposures, events))
            report["c_source"] = "edi.estimate_c"
        report["c"] = c

    tc = cfg.trajectory
    V = choose_num_views(exposures, events if tc.adaptive_views else None, tc.num_views,
                         tc.adaptive_views, tc.sharp_events_per_pixel)
    if tc.kind == "fixed":  # no motion model: one render per frame whatever the blur
        V[:] = 1
    report["views"] = V.tolist()
    report["renders_per_pass"] = int(V.sum())
    report["renders_without_skip"] = int(tc.num_views * len(V))
    if has_events:
        report["events_per_pixel"] = [round(float(v), 4) for v in events_per_pixel(events, exposures)]

    latents = None
    if use_events and (lc.w_edi > 0 or lc.target == "edi"):
        import edi

        lat = []
        for f in range(len(idx)):
            t0, t1 = exposures[f]
            lat.append(np.asarray(edi.deblur(frames_np[f], (t0, t1), events, times=0.5 * (t0 + t1), c=c),
                                  dtype=np.float32).reshape(frames_np.shape[1:]))
        latents = torch.from_numpy(np.clip(np.stack(lat), 0, 1))
    frames_t = torch.from_numpy(frames_np)
    targets = latents if (lc.target == "edi" and latents is not None) else frames_t
    if lc.target == "edi" and latents is None:
        targets = frames_t
    ev = [event_sums(events, exposures[f], int(V[f])) if (use_events and lc.w_event > 0 and V[f] > 1) else None
          for f in range(len(idx))]
    depth_range = _depth_range(capture, cfg, c2w, points)
    return Problem(
        frames=frames_t, targets=targets, latents=latents if lc.w_edi > 0 else None,
        exposures=exposures, names=[(capture.names[i] if capture.names else f"{i:04d}") for i in idx],
        c2w=torch.from_numpy(c2w).float(), K=torch.from_numpy(np.asarray(capture.K, dtype=np.float32)),
        V=V, ev_sums=ev, c=c, scale=scene_scale(c2w, depth_range), depth_range=depth_range,
        points=points, point_colors=point_colors, test_views=list(capture.test_views), report=report,
    )


# --------------------------------------------------------------------------- setup

def init_gaussians(problem: Problem, cfg: Config) -> dict[str, nn.Parameter]:
    """From SfM points when there are any, else back-projected pixels (``points_from_frames``)."""
    mc = cfg.model
    if problem.points is not None and len(problem.points) >= 16:
        cols = problem.point_colors
        if cols is None or cols.shape[1] != problem.frames.shape[-1]:
            cols = torch.full((len(problem.points), problem.frames.shape[-1]), 0.5)
        return init_params(problem.points, cols, opacity=mc.init_opacity)
    src = problem.latents if problem.latents is not None else problem.targets
    args = (src.numpy(), problem.c2w.double().numpy(), problem.K.double().numpy(), mc.init_points,
            problem.depth_range)
    if mc.init == "stereo":
        pts, cols, scales = plane_sweep_points(*args, scale_px=mc.init_scale_px, seed=cfg.train.seed)
    else:
        pts, cols, scales = points_from_frames(*args, scale_px=mc.init_scale_px, seed=cfg.train.seed)
    return init_params(pts, cols, scales, opacity=mc.init_opacity)


def max_gaussians(cfg: Config, problem: Problem) -> int:
    """The configured cap, or 2 x pixels clamped to [4000, 60000] when it is 0 (auto)."""
    if cfg.model.max_gaussians > 0:
        return int(cfg.model.max_gaussians)
    return int(min(60000, max(4000, 2 * problem.width * problem.height)))


def make_optimizers(params: dict[str, nn.Parameter], traj: ExposureTrajectories, cfg: Config,
                    scale: float, log_c: nn.Parameter | None = None) -> dict[str, torch.optim.Optimizer]:
    """One Adam per Gaussian parameter (so densification can edit its moments) and one for poses."""
    tc = cfg.train
    lrs = {"means": tc.lr_means * scale, "scales": tc.lr_scales, "quats": tc.lr_quats,
           "opacities": tc.lr_opacities, "colors": tc.lr_colors}
    opts = {k: torch.optim.Adam([params[k]], lr=lrs[k], eps=1e-15) for k in lrs}
    if traj.knots.numel() > 0 and bool(traj.moving.any()):
        opts["poses"] = torch.optim.Adam([traj.knots], lr=cfg.trajectory.lr)
    if log_c is not None and log_c.requires_grad:
        opts["contrast"] = torch.optim.Adam([log_c], lr=cfg.loss.lr_contrast)
    return opts


# --------------------------------------------------------------------------- one step

def frame_losses(problem: Problem, params, traj: ExposureTrajectories, f: int, cfg: Config,
                 log_c: Tensor | None = None):
    """Losses of frame ``f``: its V virtual views (plus the mid view when V is even and L_EDI
    is on) rendered in one batched call. Returns (total, parts dict, info for the strategy)."""
    lc = cfg.loss
    V = int(problem.V[f])
    u = virtual_instants(V)
    need_mid = problem.latents is not None and V % 2 == 0
    if need_mid:
        u = torch.cat([u, torch.tensor([0.5])])
    poses = traj(torch.tensor([f]), u)[0]  # [V', 4, 4]
    images, _, meta = render(params, poses, problem.K, problem.width, problem.height, cfg.model.background)
    renders = images[:V]
    parts = {"blur": blur_loss(renders, problem.targets[f], lc.ssim_weight, lc.ssim_window)}
    total = lc.w_blur * parts["blur"]
    if lc.w_event > 0 and problem.ev_sums[f] is not None:
        c = torch.exp(log_c) if log_c is not None else problem.c
        parts["ev"] = event_loss(renders, problem.ev_sums[f], c)
        total = total + lc.w_event * parts["ev"]
    if problem.latents is not None and lc.w_edi > 0:
        mid = images[V] if need_mid else images[V // 2]
        parts["edi"] = edi_loss(mid, problem.latents[f], lc.ssim_weight, lc.ssim_window)
        total = total + lc.w_edi * parts["edi"]
    info = {"means2d": meta.get("means2d"), "radii": meta.get("radii"),
            "width": problem.width, "height": problem.height, "mean_render": renders.detach().mean(0)}
    return total, parts, info


def train_step(problem: Problem, params, traj, optimizers, strategy, sstate, step: int, f: int,
               cfg: Config, log_c: Tensor | None = None, started: float | None = None) -> dict:
    """Forward, backward, Adam steps, densification; returns the step's scalar losses."""
    for opt in optimizers.values():
        opt.zero_grad(set_to_none=True)
    total, parts, info = frame_losses(problem, params, traj, f, cfg, log_c)
    if not torch.isfinite(total):
        raise FloatingPointError(f"non-finite loss at step {step} (frame {problem.names[f]})")
    strategy.step_pre_backward(params, optimizers, sstate, step, info)
    total.backward()
    frac = step / max(cfg.train.iters, 1)
    if cfg.train.max_seconds and started is not None:  # a time budget: decay over the budget too
        frac = max(frac, (time.perf_counter() - started) / cfg.train.max_seconds)
    lr_decay = 0.1 ** min(frac, 1.0)
    optimizers["means"].param_groups[0]["lr"] = cfg.train.lr_means * problem.scale * lr_decay
    for name, opt in optimizers.items():
        if name == "poses" and step < cfg.train.pose_warmup:
            continue
        opt.step()
    with torch.no_grad():
        params["quats"].data = params["quats"].data / params["quats"].data.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    rep = strategy.step_post_backward(params, optimizers, sstate, step, info)
    out = {"loss": float(total.detach()), **{k: float(v.detach()) for k, v in parts.items()},
           "train_psnr": psnr(info["mean_render"], problem.targets[f])}
    out.update({k: v for k, v in rep.items() if v})
    if log_c is not None:
        out["c"] = float(torch.exp(log_c.detach()))
    return out


# --------------------------------------------------------------------------- run

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
    history: list[dict] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    report: dict[str, Any] = field(default_factory=dict)
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
        K_t = torch.as_tensor(np.asarray(self.K if K is None else K), dtype=torch.float32)
        W = int(self.width if width is None else width)
        H = int(self.height if height is None else height)
        if W <= 0 or H <= 0:
            raise ValueError(f"width and height must be positive, got {W} x {H}")
        out = []
        for i in range(0, c2w_t.shape[0], batch):
            img, _, _ = render(self.params, c2w_t[i:i + batch], K_t, W, H, self.config.model.background)
            out.append(img.clamp(0, 1))
        res = torch.cat(out).numpy()
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


def evaluate_views(run: Run, views) -> dict[str, float] | None:
    """Mean PSNR / SSIM of the views that carry an image (None when none does)."""
    views = [v for v in views if getattr(v, "image", None) is not None]
    if not views:
        return None
    imgs = run.render(np.stack([v.c2w for v in views]))
    ps = [psnr(imgs[i], v.image) for i, v in enumerate(views)]
    ss = [ssim(imgs[i], v.image) for i, v in enumerate(views)]
    return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "n": len(views),
            "per_view": {v.name: {"psnr": p, "ssim": s} for v, p, s in zip(views, ps, ss)}}


def should_stop(history: list[dict], step: int, started: float, cfg: Config) -> str | None:
    """'time' when the wall-time budget is spent, 'plateau' when the windowed loss stalled."""
    tc = cfg.train
    if tc.max_seconds is not None and time.perf_counter() - started >= tc.max_seconds:
        return "time"
    if tc.plateau_patience > 0 and step > 0 and step % tc.plateau_every == 0:
        w = tc.plateau_every
        losses = [h["loss"] for h in history]
        windows = [np.mean(losses[i:i + w]) for i in range(0, len(losses) - w + 1, w)]
        if len(windows) > tc.plateau_patience:
            best_before = min(windows[:-tc.plateau_patience])
            recent = min(windows[-tc.plateau_patience:])
            if recent > best_before * (1 - tc.plateau_tol):
                return "plateau"
    return None


def _checkpoint(path: Path, run: Run, optimizers, sstate, order_rng: np.random.Generator,
                log_c: Tensor | None = None) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save({
        "log_c": None if log_c is None else log_c.detach().clone(),
        "step": run.step,
        "params": {k: v.detach() for k, v in run.params.items()},
        "knots": run.trajectories.knots.detach(),
        "optimizers": {k: o.state_dict() for k, o in optimizers.items()},
        "strategy": sstate,
        "history": run.history,
        "rng": order_rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
    }, tmp)
    tmp.replace(path)


def validate_config(cfg: Config) -> Config:
    """Raise ``UserError`` naming the field for settings that cannot work."""
    from .strategy import STRATEGIES
    from .trajectory import TRAJECTORIES

    if not isinstance(cfg, Config):
        raise UserError(f"config must be an ebad.Config or a preset name, got {type(cfg).__name__}")
    checks = [
        (cfg.trajectory.kind in TRAJECTORIES, f"trajectory.kind must be one of {sorted(TRAJECTORIES)}, got '{cfg.trajectory.kind}'"),
        (cfg.strategy.kind in STRATEGIES, f"strategy.kind must be one of {sorted(STRATEGIES)}, got '{cfg.strategy.kind}'"),
        (cfg.trajectory.num_views >= 1, f"trajectory.num_views must be >= 1, got {cfg.trajectory.num_views}"),
        (cfg.train.iters >= 1, f"train.iters must be >= 1, got {cfg.train.iters}"),
        (min(cfg.loss.w_blur, cfg.loss.w_event, cfg.loss.w_edi) >= 0, "loss weights must be >= 0"),
        (cfg.loss.target in ("blurry", "edi"), f"loss.target must be 'blurry' or 'edi', got '{cfg.loss.target}'"),
        (cfg.loss.contrast is None or cfg.loss.contrast > 0, f"loss.contrast must be > 0, got {cfg.loss.contrast}"),
        (cfg.train.max_seconds is None or cfg.train.max_seconds > 0, f"train.max_seconds must be > 0, got {cfg.train.max_seconds}"),
        (0 < cfg.model.init_opacity < 1, f"model.init_opacity must be in (0, 1), got {cfg.model.init_opacity}"),
        (cfg.model.init_points >= 1, f"model.init_points must be >= 1, got {cfg.model.init_points}"),
    ]
    for ok, msg in checks:
        if not ok:
            raise UserError(msg)
    return cfg


def reconstruct(capture, config: Config | str | None = None, out_dir: str | Path | None = None,
                resume: bool = False, gt_views=None, on_step=None) -> Run:
    """Recover Gaussians and per-exposure trajectories from ``capture``.

    Args:
        capture: a ``scenes.Capture``.
        config: a ``Config``, a preset name, or None (the ``ebad`` preset).
        out_dir: when given, checkpoints go to ``out_dir/checkpoints/last.pt`` every
            ``train.checkpoint_every`` steps (the rest of the run folder is written by
            ``ebad.runfolder.write_run``).
        resume: continue from ``out_dir``'s checkpoint when there is one.
        gt_views: test views with images to report PSNR on (default: the capture's).
        on_step: optional callback(step, stats) after every step.
    """
    cfg = preset("ebad") if config is None else (preset(config) if isinstance(config, str) else config)
    validate_config(cfg)
    torch.manual_seed(cfg.train.seed)
    gen = torch.Generator().manual_seed(cfg.train.seed)
    t_prep = time.perf_counter()
    problem = prepare(capture, cfg)
    prep_s = time.perf_counter() - t_prep
    params = init_gaussians(problem, cfg)
    moving = torch.from_numpy(problem.V > 1)
    am = cfg.trajectory.anchor_mid
    anchored = am == "yes" or (am == "auto" and problem.report["pose_source"] == "capture")
    traj = ExposureTrajectories(problem.c2w, cfg.trajectory.kind if moving.any() else "fixed", moving,
                                scale=problem.scale, init_noise=cfg.trajectory.init_noise, generator=gen,
                                anchored=anchored)
    problem.report["anchored_mid_poses"] = anchored
    log_c = None
    if problem.c is not None and any(e is not None for e in problem.ev_sums):
        log_c = nn.Parameter(torch.tensor(math.log(problem.c)), requires_grad=cfg.loss.learn_contrast)
    optimizers = make_optimizers(params, traj, cfg, problem.scale, log_c)
    strategy = make_strategy(cfg.strategy, problem.scale, max_gaussians(cfg, problem), gen)
    sstate = strategy.initialize_state(num_gaussians(params))
    order_rng = np.random.default_rng(cfg.train.seed)
    run = Run(params=params, trajectories=traj, config=cfg, K=problem.K.double().numpy(),
              width=problem.width, height=problem.height, names=problem.names,
              exposures=problem.exposures, V=problem.V, report=dict(problem.report))
    views = problem.test_views if gt_views is None else gt_views
    ckpt = Path(out_dir) / "checkpoints" / "last.pt" if out_dir is not None else None
    if resume and ckpt is not None and ckpt.exists():
        state = torch.load(ckpt, weights_only=False)
        for k, v in state["params"].items():
            params[k] = nn.Parameter(v.clone())
        with torch.no_grad():
            traj.knots.data = state["knots"].clone()
        if log_c is not None and state.get("log_c") is not None:
            with torch.no_grad():
                log_c.data = state["log_c"].clone()
        optimizers = make_optimizers(params, traj, cfg, problem.scale, log_c)
        for k, sd in state["optimizers"].items():
            if k in optimizers:
                optimizers[k].load_state_dict(sd)
        sstate = state["strategy"]
        run.params = params
        run.history = list(state["history"])
        run.step = int(state["step"])
        order_rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        run.report["resumed_from"] = run.step
    init_eval = evaluate_views(run, views) if run.step == 0 else None
    F = len(problem.names)
    order: list[int] = []
    started = time.perf_counter() - (run.history[-1]["time"] if run.history else 0.0)
    stop_reason = "iters"
    last_eval = None
    bar = None
    if cfg.train.progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.train.iters, initial=run.step, desc=f"ebad[{cfg.name}]", dynamic_ncols=True,
                   leave=False)
    try:
        while run.step < cfg.train.iters:
            if not order:
                order = list(order_rng.permutation(F))
            f = int(order.pop())
            stats = train_step(problem, params, traj, optimizers, strategy, sstate, run.step, f, cfg, log_c, started)
            run.step += 1
            stats["step"] = run.step
            stats["n"] = num_gaussians(params)
            stats["time"] = time.perf_counter() - started
            ev_every = cfg.train.eval_every
            if ev_every and (run.step % ev_every == 0 or run.step == cfg.train.iters):
                last_eval = evaluate_views(run, views)
                if last_eval is not None:
                    stats["test_psnr"] = last_eval["psnr"]
            run.history.append(stats)
            if bar is not None:
                post = {"loss": f"{stats['loss']:.4f}", "blur": f"{stats['blur']:.4f}"}
                for k in ("ev", "edi"):
                    if k in stats:
                        post[k] = f"{stats[k]:.4f}"
                post["N"] = stats["n"]
                post["psnr"] = f"{(last_eval or {}).get('psnr', stats['train_psnr']):.2f}"
                bar.set_postfix(post, refresh=False)
                bar.update(1)
            if on_step is not None:
                on_step(run.step, stats)
            if ckpt is not None and cfg.train.checkpoint_every and run.step % cfg.train.checkpoint_every == 0:
                ckpt.parent.mkdir(parents=True, exist_ok=True)
                _checkpoint(ckpt, run, optimizers, sstate, order_rng, log_c)
            reason = should_stop(run.history, run.step, started, cfg)
            if reason:
                stop_reason = reason
                break
    finally:
        if bar is not None:
            bar.close()
    run.params = params
    if ckpt is not None:
        ckpt.parent.mkdir(parents=True, exist_ok=True)
        _checkpoint(ckpt, run, optimizers, sstate, order_rng, log_c)
    final = evaluate_views(run, views)
    run.metrics = {
        "preset": cfg.name, "steps": run.step, "stop_reason": stop_reason,
        "train_seconds": run.history[-1]["time"] if run.history else 0.0, "prepare_seconds": prep_s,
        "gaussians": run.num_gaussians, "final_loss": run.history[-1]["loss"] if run.history else None,
        "test": final, "test_initial": init_eval, **{k: v for k, v in run.report.items()},
        "c_final": None if log_c is None else float(torch.exp(log_c.detach())),
    }
    return run
