"""``ebad reconstruct --view``: the viewer of ``ebad view`` (``ebad.cli.view``) serving a run while it trains.

``LiveView`` is a callback (``ebad.callbacks.Callback``): it starts a viser server when made, draws
the training state after the first step (Gaussians, training cameras, exposure trajectories; the
first view at the first training camera) and redraws it every ``every`` seconds, but never more
often than keeps its own time under ``budget`` (5%) of the training time: after an update that took
``t`` seconds the next waits at least ``t / budget``. The browsers' cameras and controls are kept
across updates. The server stops when training does (``ebad view OUT`` shows the finished run).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from .state import StepStats, TrainState

__all__ = ["LiveView", "DEFAULT_EVERY", "DEFAULT_BUDGET"]

DEFAULT_EVERY = 5.0  # seconds between updates
DEFAULT_BUDGET = 0.05  # the largest fraction of the training time the updates may take


class LiveView:
    """A viser server showing the training state, updated every ``every`` seconds (see the module)."""

    def __init__(
        self,
        K: np.ndarray,
        width: int,
        height: int,
        names: Sequence[str],
        host: str = "127.0.0.1",
        port: int = 8080,
        every: float = DEFAULT_EVERY,
        budget: float = DEFAULT_BUDGET,
        test_views: Sequence[Any] = (),
        say: Callable[[str], None] | None = None,
    ):
        from .cli.view import check_host, disable_share, import_viser
        from .errors import UserError

        if not every > 0:
            raise UserError(f"--view-every must be a positive number of seconds, got {every}")
        if not 0 < budget < 1:
            raise UserError(f"the live view's time budget must be in (0, 1), got {budget}")
        if not 0 <= port < 65536:
            raise UserError(f"--view-port must be in 1..65535, got {port}")  # 0 (any free port) for scripts
        viser = import_viser()
        check_host(host)
        self.K, self.width, self.height, self.names = np.asarray(K, np.float64), int(width), int(height), list(names)
        self.every, self.budget, self.test_views = float(every), float(budget), list(test_views)
        self.server = viser.ViserServer(host=host, port=port, label="ebad (training)", verbose=False)
        disable_share(self.server)
        self.handles: dict | None = None
        self.updates = 0  # scene updates sent so far (the first builds the scene)
        self.seconds = 0.0  # time spent in them
        self.cost = 0.0  # seconds of the latest update
        self.last = -float("inf")  # perf_counter at the end of the latest update
        self.step = -1  # the training step the scene shows
        self.closed = False
        if say is not None:
            say(f"live view: open http://localhost:{self.port} (Ctrl-C stops the run)")

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    def interval(self) -> float:
        """Seconds until the next update may be sent: ``every``, or longer when updates are slow."""
        return max(self.every, self.cost / self.budget)

    def on_step(self, state: TrainState, stats: StepStats) -> None:
        if self.handles is None or time.perf_counter() - self.last >= self.interval():
            self.update(state)

    def update(self, state: TrainState) -> None:
        """Show ``state`` now."""
        from scenes.capture import frame_name

        from .cli.view import build_scene, update_scene

        t0 = time.perf_counter()
        F = state.trajectories.num_frames
        scene = SimpleNamespace(
            params=state.params,
            response=state.response,  # the colours the run will export (recorded domain)
            trajectories=state.trajectories,
            names=self.names if len(self.names) == F else [frame_name(i) for i in range(F)],
            K=self.K,
            width=self.width,
            height=self.height,
        )
        if self.handles is None:
            self.handles = build_scene(self.server, scene, self.test_views)
        else:
            update_scene(self.server, self.handles, scene)
        self.last = time.perf_counter()
        self.cost = self.last - t0
        self.seconds += self.cost
        self.updates += 1
        self.step = state.step

    def on_end(self, state: TrainState, reason: str) -> None:
        self.close()

    def close(self) -> None:
        """Stop the server (again: nothing)."""
        if not self.closed:
            self.closed = True
            self.server.stop()
