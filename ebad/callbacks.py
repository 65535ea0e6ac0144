"""What the loop calls after every step: the ``Callback`` protocol and the built-in callbacks.

``ebad.loop.train`` calls ``on_step(state, stats)`` of each callback after every step, in
order, and ``on_end(state, reason)`` once when it stops. ``Evaluator`` scores the test views,
``ProgressBar`` shows the losses, ``Checkpointer`` saves the state, ``StepHook`` hands each
step to a user function, ``TensorBoardLogger`` writes TensorBoard event files (``ebad reconstruct
--tensorboard``; needs the ``tensorboard`` package, the ``ebad[tensorboard]`` extra).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from .config import Config
from .data import TrainingData
from .progress import Ticker, say
from .scoring import ViewScores, evaluate_views, render_images, scorable_views, with_poses
from .state import NO_STEP_LIMIT, StepStats, TrainState

if TYPE_CHECKING:
    from scenes import TestView

__all__ = [
    "Callback",
    "Evaluator",
    "ProgressBar",
    "Checkpointer",
    "StepHook",
    "TensorBoardLogger",
    "require_tensorboard",
    "say",
    "Ticker",
]


class Callback(Protocol):
    """Called after every step, in order; ``on_end`` once when the loop stops."""

    def on_step(self, state: TrainState, stats: StepStats) -> None: ...

    def on_end(self, state: TrainState, reason: str) -> None: ...


class Evaluator:
    """Every ``every`` steps (and at ``last``), the test-view PSNR into ``stats.test_psnr``."""

    def __init__(self, data: TrainingData, cfg: Config, views: Sequence[TestView], every: int, last: int):
        self.data, self.cfg, self.every, self.last = data, cfg, every, last
        self.views = scorable_views(with_poses(views, data.test_c2w))
        self.latest: ViewScores | None = None
        self.latest_step = -1  # the step ``latest`` was scored at

    def scores(self, state: TrainState) -> ViewScores | None:
        d = self.data
        return evaluate_views(
            lambda c2w: render_images(
                state.params, c2w, d.K, d.width, d.height, self.cfg.model.background, response=state.response
            ),
            self.views,
            d.cfa,
        )

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        if self.views and self.every and (state.step % self.every == 0 or state.step == self.last):
            self.latest, self.latest_step = self.scores(state), state.step
            stats.test_psnr = None if self.latest is None else self.latest.psnr  # None: no scorable view

    def final(self, state: TrainState) -> ViewScores | None:
        """The scores at the state's step: the last evaluation's when it was made there."""
        return self.latest if self.latest_step == state.step else self.scores(state)

    def on_end(self, state: TrainState, reason: str) -> None:
        return None


class ProgressBar:
    """A tqdm bar with the losses, N and the latest (test, else train) PSNR. Under a time budget
    (``train.max_seconds``) the bar counts training seconds against it, and the steps are shown
    beside (``step``: done / ``train.iters``, or done alone without a step limit); else it counts steps."""

    def __init__(self, cfg: Config, initial: int, elapsed: float = 0.0):
        from tqdm import tqdm

        self.iters, self.seconds = cfg.train.iters, cfg.train.max_seconds
        desc = f"ebad[{cfg.name}]"
        if self.seconds is None:
            self.bar = tqdm(total=self.iters, initial=initial, desc=desc, dynamic_ncols=True, leave=False)
        else:
            self.bar = tqdm(
                total=float(self.seconds),
                initial=min(float(elapsed), float(self.seconds)),
                desc=desc,
                unit="s",
                dynamic_ncols=True,
                leave=False,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}{postfix}]",
            )
        self.psnr: float | None = None

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        post: dict[str, str | int] = {"loss": f"{stats.loss:.4f}", "blur": f"{stats.blur:.4f}"}
        for k in ("ev", "edi"):
            if getattr(stats, k) is not None:
                post[k] = f"{getattr(stats, k):.4f}"
        post["N"] = stats.gaussians
        if stats.test_psnr is not None:
            self.psnr = stats.test_psnr
        post["psnr"] = f"{self.psnr if self.psnr is not None else stats.train_psnr:.2f}"
        if self.seconds is None:
            self.bar.set_postfix(post, refresh=False)
            self.bar.update(1)
        else:
            post["step"] = str(state.step) if self.iters >= NO_STEP_LIMIT else f"{state.step}/{self.iters}"
            self.bar.set_postfix(post, refresh=False)
            self.bar.update(min(float(state.elapsed), float(self.seconds)) - self.bar.n)

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


def require_tensorboard(option: str = "--tensorboard") -> None:
    """Raise ``UserError`` (one line naming ``option``) when the ``tensorboard`` package is missing."""
    if importlib.util.find_spec("tensorboard") is None:
        from .errors import UserError

        raise UserError(
            f"{option} needs the tensorboard package, which is not installed: pip install 'ebad[tensorboard]' "
            "(or pip install tensorboard)"
        )


class TensorBoardLogger:
    """TensorBoard event files in ``log_dir`` (torch's ``SummaryWriter``; ``tensorboard --logdir``).

    After every step: ``loss/total``, ``loss/blur``, ``loss/ev`` and ``loss/edi`` (when on),
    ``psnr/train``, ``gaussians``, ``time/step_s`` (seconds of the step), ``threshold/c_pos`` and
    ``threshold/c_neg`` (when learnt), and ``psnr/test`` on the steps the ``Evaluator`` scored.
    Every ``every`` steps (0: only at the end) and at the end: the renders, in the capture's own
    recorded values (through the camera response), of the first training frame at its current
    mid-exposure pose (``render/train_NAME``) and of each ``views`` (name, c2w [4, 4]) at its pose
    (``render/NAME``). ``K``, ``width`` and ``height`` are the capture's.
    """

    def __init__(
        self,
        log_dir: str | Path,
        K: np.ndarray,
        width: int,
        height: int,
        background: float = 0.0,
        every: int = 100,
        views: Sequence[tuple[str, np.ndarray]] = (),
        train_name: str = "0",
    ):
        require_tensorboard()
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(log_dir=str(log_dir))
        self.K, self.width, self.height, self.background = np.asarray(K), width, height, background
        self.every, self.views, self.train_name = every, list(views), train_name
        self.last_time: float | None = None
        self.last_render = -1

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        w, step = self.writer, stats.step
        w.add_scalar("loss/total", stats.loss, step)
        w.add_scalar("loss/blur", stats.blur, step)
        for k in ("ev", "edi"):
            if getattr(stats, k) is not None:
                w.add_scalar(f"loss/{k}", getattr(stats, k), step)
        w.add_scalar("psnr/train", stats.train_psnr, step)
        if stats.test_psnr is not None:
            w.add_scalar("psnr/test", stats.test_psnr, step)
        w.add_scalar("gaussians", stats.gaussians, step)
        if self.last_time is not None:
            w.add_scalar("time/step_s", stats.time - self.last_time, step)
        self.last_time = stats.time
        if stats.c is not None:
            w.add_scalar("threshold/c_pos", stats.c[0], step)
            w.add_scalar("threshold/c_neg", stats.c[1], step)
        if self.every and step % self.every == 0:
            self.renders(state, step)

    def renders(self, state: TrainState, step: int) -> None:
        """Write the renders (see the class docstring) at ``step``."""
        from .scoring import render_images

        c2w = [state.trajectories.mid_poses()[0].detach().double().numpy()] + [np.asarray(m) for _, m in self.views]
        names = [f"train_{self.train_name}"] + [n for n, _ in self.views]
        imgs = render_images(
            state.params, np.stack(c2w), self.K, self.width, self.height, self.background, response=state.response
        )
        for name, img in zip(names, imgs):
            self.writer.add_image(f"render/{name}", np.clip(img, 0.0, 1.0), step, dataformats="HWC")
        self.last_render = step

    def on_end(self, state: TrainState, reason: str) -> None:
        if state.step > 0 and self.last_render != state.step:
            self.renders(state, state.step)
        self.writer.flush()
        self.writer.close()
