"""Densification and pruning behind gsplat's small strategy interface.

A strategy implements the ``Strategy`` protocol: ``check_sanity(params, optimizers)`` once
before training, ``initialize_state(n) -> StrategyState``, ``step_pre_backward(params,
optimizers, state, step, info)`` and ``step_post_backward(...) -> RefineReport``, where
``info`` is the ``RenderInfo`` of the step's rasteriser call. ``DefaultStrategy``
follows gsplat's default: screen-space gradients of the projected means are accumulated over
EVERY camera of each rasteriser call (all V virtual views of an exposure, not only the last),
and every ``refine_every`` steps Gaussians with a high mean gradient are cloned (small) or
split in two (large); transparent ones are pruned (and, after the first opacity reset, huge
ones); every ``reset_every`` steps opacities are clamped down so that floaters can die, while
the run's schedule allows it (``RenderInfo.resets``: before ``strategy.reset_until``, ``ebad.schedule``).

The parameter surgery functions (``duplicate``, ``split``, ``remove``, ``reset_opacity``)
keep each Adam optimizer's moments aligned with its parameter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import torch
from numba import njit
from torch import Tensor, nn

from .config import StrategyConfig
from .lie import quat_to_rotmat

__all__ = [
    "Strategy",
    "StrategyState",
    "RenderInfo",
    "RefineReport",
    "DefaultStrategy",
    "NoStrategy",
    "STRATEGIES",
    "make_strategy",
    "duplicate",
    "split",
    "remove",
    "reset_opacity",
    "screen_grads",
    "PARAM_NAMES",
    "OPTIONAL_PARAM_NAMES",
]

Params = dict[str, nn.Parameter]
Optims = dict[str, torch.optim.Optimizer]
PARAM_NAMES = ("means", "scales", "quats", "opacities", "colors")  # a Gaussian's parameters, each [N, ...]
OPTIONAL_PARAM_NAMES = ("sh_rest",)  # and those a model may have (view-dependent colour: ebad.gaussians)


@dataclass
class RenderInfo:
    """What one step's rasteriser call hands the strategy (gsplat's ``info``)."""

    means2d: Tensor | None  # [C, N, 2] projected means; the backward fills ``.grad``
    radii: Tensor | None  # [C, N] or [C, N, 2] screen radii (0: not visible)
    width: int
    height: int
    progress: float = 0.0  # fraction of the run's budget done (``ebad.schedule.Schedule.fraction``)
    resets: bool = True  # opacity resets may fire at this step (the run's schedule: before strategy.reset_until)


@dataclass
class StrategyState:
    """Accumulated screen-space statistics between refinements."""

    grad2d: Tensor = field(default_factory=lambda: torch.zeros(0))  # [N] summed gradient norms
    count: Tensor = field(default_factory=lambda: torch.zeros(0))  # [N] cameras that saw each Gaussian

    def to_dict(self) -> dict[str, Tensor]:
        return {"grad2d": self.grad2d, "count": self.count}

    @classmethod
    def from_dict(cls, d: dict[str, Tensor]) -> StrategyState:
        return cls(grad2d=d["grad2d"], count=d["count"])


@dataclass
class RefineReport:
    """What one ``step_post_backward`` did."""

    cloned: int = 0
    split: int = 0
    pruned: int = 0
    reset: bool = False


class Strategy(Protocol):
    """gsplat's strategy interface."""

    def check_sanity(self, params: Params, optimizers: Optims) -> None: ...

    def initialize_state(self, n: int) -> StrategyState: ...

    def step_pre_backward(
        self, params: Params, optimizers: Optims, state: StrategyState, step: int, info: RenderInfo
    ) -> None: ...

    def step_post_backward(
        self, params: Params, optimizers: Optims, state: StrategyState, step: int, info: RenderInfo
    ) -> RefineReport: ...


def _check_params(params: Params, optimizers: Optims) -> None:
    """Every Gaussian parameter is present with one row per Gaussian, and has its own optimizer."""
    missing = [k for k in PARAM_NAMES if k not in params]
    if missing:
        raise ValueError(f"strategy: Gaussian parameters {missing} are missing")
    n = params["means"].shape[0]
    for k in PARAM_NAMES + tuple(k for k in OPTIONAL_PARAM_NAMES if k in params):
        if params[k].shape[0] != n:
            raise ValueError(f"strategy: params['{k}'] has {params[k].shape[0]} rows, means has {n}")
        opt = optimizers.get(k)
        group = opt.param_groups[0]["params"] if opt is not None and len(opt.param_groups) == 1 else []
        if len(group) != 1 or group[0] is not params[k]:
            raise ValueError(f"strategy: optimizers['{k}'] must hold exactly params['{k}']")


def _surgery(
    params: Params,
    optimizers: Optims,
    param_fn: Callable[[str, Tensor], Tensor],
    state_fn: Callable[[str, Tensor], Tensor],
    names=None,
) -> None:
    """Replace params[name] by param_fn(name, p) and each Adam moment by state_fn(name, moment)."""
    for name in list(params) if names is None else names:
        old = params[name]
        new = nn.Parameter(param_fn(name, old.data), requires_grad=old.requires_grad)
        opt = optimizers.get(name)
        if opt is not None:
            st = opt.state.pop(old, None)
            for group in opt.param_groups:
                group["params"] = [new if p is old else p for p in group["params"]]
            if st:
                st = {k: (state_fn(k, v) if isinstance(v, Tensor) and v.ndim > 0 else v) for k, v in st.items()}
                opt.state[new] = st
        params[name] = new


def duplicate(params: Params, optimizers: Optims, mask: Tensor) -> None:  # mask [N] bool
    """Append a copy of every selected Gaussian (fresh zero Adam moments for the copies)."""
    idx = torch.nonzero(mask).squeeze(1)
    _surgery(
        params, optimizers, lambda n, p: torch.cat([p, p[idx]]), lambda k, v: torch.cat([v, torch.zeros_like(v[idx])])
    )


def split(
    params: Params, optimizers: Optims, mask: Tensor, generator: torch.Generator | None = None, shrink: float = 1.6
) -> None:  # mask [N] bool; shrink: StrategyConfig.split_shrink
    """Replace every selected Gaussian by two, sampled from it, each ``shrink`` times smaller."""
    idx = torch.nonzero(mask).squeeze(1)
    keep = ~mask
    with torch.no_grad():
        s = torch.exp(params["scales"][idx])  # [S, 3]
        R = quat_to_rotmat(params["quats"][idx])  # [S, 3, 3]
        noise = torch.randn(2, idx.shape[0], 3, generator=generator)
        offsets = torch.einsum("sij,ksj->ksi", R, noise * s[None])  # [2, S, 3]
        new_means = (params["means"][idx][None] + offsets).reshape(-1, 3)

    def pfn(name, p):
        if name == "means":
            extra = new_means
        elif name == "scales":
            extra = (p[idx] - math.log(shrink)).repeat(2, 1)
        else:
            extra = p[idx].repeat(2, *([1] * (p.ndim - 1)))
        return torch.cat([p[keep], extra])

    _surgery(
        params,
        optimizers,
        pfn,
        lambda k, v: torch.cat([v[keep], torch.zeros_like(v[idx]).repeat(2, *([1] * (v.ndim - 1)))]),
    )


def remove(params: Params, optimizers: Optims, mask: Tensor) -> None:  # mask [N] bool
    """Delete the selected Gaussians."""
    keep = ~mask
    _surgery(params, optimizers, lambda n, p: p[keep], lambda k, v: v[keep])


def reset_opacity(params: Params, optimizers: Optims, value: float) -> None:
    """Clamp every opacity to at most ``value`` and zero the opacity moments."""
    cap = math.log(value / (1 - value))
    _surgery(params, optimizers, lambda n, p: p.clamp_max(cap), lambda k, v: torch.zeros_like(v), names=["opacities"])


def screen_grads(info: RenderInfo) -> tuple[Tensor, Tensor] | None:
    """Per-camera screen-space gradient norms [C, N] (NDC units, as gsplat) and visibility [C, N].

    ``info.means2d`` [C, N, 2] carries the ``.grad`` the backward filled. Returns None when
    there is no gradient.
    """
    m2d = info.means2d
    if m2d is None or m2d.grad is None:
        return None
    g = m2d.grad.detach().clone()
    g[..., 0] *= info.width / 2.0
    g[..., 1] *= info.height / 2.0
    radii = _radii(info)
    visible = (radii > 0).all(-1) if radii.ndim == 3 else radii > 0
    return g.norm(dim=-1) * visible, visible


def _radii(info: RenderInfo) -> Tensor:
    """``info.radii``, which a rasteriser hands with the means2d whose gradient is accumulated."""
    if info.radii is None:
        raise ValueError("RenderInfo.radii is None: the screen radii are needed with the means2d gradient")
    return info.radii


@njit(cache=True)
def _add_screen_grads(grad, radii, sx, sy, grad2d, count):  # pragma: no cover - jit
    """``screen_grads`` summed over the cameras into ``grad2d`` and ``count`` [N], in one pass:
    grad [C, N, 2] of the projected means, radii [C, N, R] (visible: every radius > 0); the x and
    y components scaled by sx, sy."""
    C, N, R = radii.shape
    for c in range(C):
        for n in range(N):
            visible = True
            for k in range(R):
                visible = visible and radii[c, n, k] > 0
            if visible:
                gx = grad[c, n, 0] * sx
                gy = grad[c, n, 1] * sy
                grad2d[n] += math.sqrt(gx * gx + gy * gy)
                count[n] += 1.0


@dataclass
class DefaultStrategy:
    """gsplat's default strategy; see the module docstring. ``scene_scale`` in world units."""

    cfg: StrategyConfig
    scene_scale: float = 1.0
    max_gaussians: int = 1_000_000
    generator: torch.Generator | None = None

    def check_sanity(self, params: Params, optimizers: Optims) -> None:
        _check_params(params, optimizers)

    def initialize_state(self, n: int) -> StrategyState:
        return StrategyState(grad2d=torch.zeros(n), count=torch.zeros(n))

    def step_pre_backward(
        self, params: Params, optimizers: Optims, state: StrategyState, step: int, info: RenderInfo
    ) -> None:
        m2d = info.means2d
        if m2d is not None and m2d.requires_grad:
            m2d.retain_grad()

    def accumulate(self, state: StrategyState, info: RenderInfo) -> None:
        """Add this step's per-camera gradient norms (every camera of the batch) to the state:
        ``screen_grads`` summed over the cameras, in one numba pass on CPU float32 statistics
        (much cheaper than the dozen torch operations it replaces, ``screen_grads``, its reference)."""
        m2d = info.means2d
        fast = (
            m2d is not None
            and m2d.grad is not None
            and m2d.device.type == "cpu"
            and state.grad2d.dtype == torch.float32 == state.count.dtype
            and state.grad2d.is_contiguous()
            and state.count.is_contiguous()
        )
        if not fast:
            out = screen_grads(info)
            if out is None:
                return
            norms, visible = out  # [C, N]
            state.grad2d += norms.sum(0)
            state.count += visible.sum(0).float()
            return
        assert m2d is not None and m2d.grad is not None  # fast
        radii = _radii(info).numpy()
        _add_screen_grads(
            m2d.grad.detach().numpy(),
            radii if radii.ndim == 3 else radii[..., None],
            info.width / 2.0,
            info.height / 2.0,
            state.grad2d.numpy(),
            state.count.numpy(),
        )

    def step_post_backward(
        self, params: Params, optimizers: Optims, state: StrategyState, step: int, info: RenderInfo
    ) -> RefineReport:
        cfg = self.cfg
        report = RefineReport()
        if step >= cfg.refine_stop:
            return report
        self.accumulate(state, info)
        if step > cfg.refine_start and step % cfg.refine_every == 0:
            report = self.refine(params, optimizers, state, step)
        if cfg.reset_every > 0 and step > 0 and step % cfg.reset_every == 0 and info.resets:
            reset_opacity(params, optimizers, cfg.reset_opacity)
            report.reset = True
        return report

    def refine(self, params: Params, optimizers: Optims, state: StrategyState, step: int) -> RefineReport:
        cfg = self.cfg
        n0 = params["means"].shape[0]
        avg = state.grad2d / state.count.clamp_min(1)
        high = avg > cfg.grad_threshold
        big = torch.exp(params["scales"].detach()).max(-1).values > cfg.split_scale * self.scene_scale
        clone_mask = high & ~big
        split_mask = high & big
        room = self.max_gaussians - n0
        if room <= 0:
            clone_mask[:] = False
            split_mask[:] = False
        elif int(clone_mask.sum() + split_mask.sum()) > room:  # keep the strongest gradients
            order = torch.argsort(avg, descending=True)
            allowed = torch.zeros_like(high)
            allowed[order[:room]] = True
            clone_mask &= allowed
            split_mask &= allowed
        n_clone, n_split = int(clone_mask.sum()), int(split_mask.sum())
        if n_clone:
            duplicate(params, optimizers, clone_mask)
        if n_split:
            split_mask = torch.cat([split_mask, torch.zeros(n_clone, dtype=torch.bool)])
            split(params, optimizers, split_mask, generator=self.generator, shrink=cfg.split_shrink)
        with torch.no_grad():
            prune = torch.sigmoid(params["opacities"]) < cfg.prune_opacity
            if cfg.reset_every > 0 and step > cfg.reset_every:
                prune |= torch.exp(params["scales"]).max(-1).values > cfg.prune_scale * self.scene_scale
        n_prune = int(prune.sum())
        if n_prune and n_prune < prune.shape[0]:
            remove(params, optimizers, prune)
        else:
            n_prune = 0
        n = params["means"].shape[0]
        state.grad2d = torch.zeros(n)
        state.count = torch.zeros(n)
        return RefineReport(cloned=n_clone, split=n_split, pruned=n_prune)


@dataclass
class NoStrategy:
    """Keeps the initial Gaussians as they are."""

    cfg: StrategyConfig | None = None
    scene_scale: float = 1.0
    max_gaussians: int = 0
    generator: torch.Generator | None = None

    def check_sanity(self, params: Params, optimizers: Optims) -> None:
        _check_params(params, optimizers)

    def initialize_state(self, n: int) -> StrategyState:
        return StrategyState()

    def step_pre_backward(self, params, optimizers, state, step, info) -> None:
        return None

    def step_post_backward(self, params, optimizers, state, step, info) -> RefineReport:
        return RefineReport()


STRATEGIES: dict[str, Callable[..., Strategy]] = {"default": DefaultStrategy, "none": NoStrategy}


def make_strategy(
    cfg: StrategyConfig, scene_scale: float, max_gaussians: int, generator: torch.Generator | None = None
) -> Strategy:
    """The registered strategy ``cfg.kind`` (a ``Literal`` checked by the config)."""
    return STRATEGIES[cfg.kind](cfg=cfg, scene_scale=scene_scale, max_gaussians=max_gaussians, generator=generator)
