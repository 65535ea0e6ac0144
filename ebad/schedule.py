"""What happens at which fraction of the budget: decided once from the config, held as data.

A run's budget is ``train.iters`` steps and, when given, ``train.max_seconds`` of training; how
far through it a step is, is ONE number, ``Schedule.fraction``: steps done over iterations, or
seconds over the time budget when that is further, at most 1. Everything that changes over a
run is a function of that number, read from one ``Schedule``:

- the learning rates of the means and of the trajectories' knots decay exponentially, from
  their start to ``final`` times it at fraction 1 (``train.lr_means_final``, ``trajectory.lr_final``);
- below ``coarse_until`` a step trains on the coarse (downscaled) problem (``train.coarse_until``;
  0 when there is no coarse phase);
- at ``views_at`` each blurry frame's V is chosen again from the learnt trajectories
  (``trajectory.view_spacing``; where the coarse phase ends);
- opacity resets may fire only below ``reset_until`` (``strategy.reset_until``; when they fire
  within that is the strategy's ``reset_every``);
- from ``average_from`` on, the knots are averaged (``trajectory.average_from``), judged at the
  fraction where a step ENDS (after it), every other item where it starts;
- the spherical-harmonic degree used (``model.sh_degree``) rises by one every ``model.sh_degree_interval``
  steps (gsplat's rule), or every ``sh_degree_interval / SH_REFERENCE_ITERS`` of the budget when that comes
  sooner: the rise is spread over a short run as over gsplat's default 30000-step run (there degree 3 is
  reached at step 3000, a tenth of the run; in a 3000-step run at step 300; in a time budget, at a tenth of it).

``Schedule.at(step, elapsed)`` gives the ``Phase`` of one step: all of the above, decided.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config import Config

__all__ = ["Schedule", "Phase", "SH_REFERENCE_ITERS"]

SH_REFERENCE_ITERS = 30000  # gsplat's default run, over which its sh_degree_interval is counted


@dataclass(frozen=True)
class Phase:
    """Where one step stands in the schedule."""

    fraction: float  # of the budget, in [0, 1]
    coarse: bool  # train on the coarse problem
    views_due: bool  # the frames' V are (or were) due to be chosen from the trajectories by now
    resets: bool  # opacity resets may fire
    averaging: bool  # knots are averaged (meaningful at the fraction where a step ends)
    lr_means: float  # the means' learning rate (times the scene scale)
    lr_poses: float  # the knots' learning rate
    sh_degree: int = 0  # the spherical-harmonic degree the renders use


@dataclass(frozen=True)
class Schedule:
    """A run's schedule (see the module docstring); ``None`` for an item that never happens."""

    iters: int
    max_seconds: float | None
    coarse_until: float  # 0: no coarse phase
    views_at: float | None
    reset_until: float
    average_from: float | None
    lr_means: float  # at fraction 0 (already times the scene scale)
    lr_means_final: float  # ratio at fraction 1
    lr_poses: float
    lr_poses_final: float
    sh_degree: int = 0  # the model's (model.sh_degree)
    sh_degree_interval: int = 1000

    @classmethod
    def from_config(
        cls, cfg: Config, scale: float, coarse: bool = True, choose_views: bool = True, averaging: bool = True
    ) -> Schedule:
        """The schedule of ``cfg`` for a scene of ``scale``. ``coarse``: a coarse problem exists
        (frames large enough, ``ebad.loop.coarse_data``); ``choose_views``: some frame is blurry;
        ``averaging``: the knots are optimised."""
        tc, tj = cfg.train, cfg.trajectory
        if tc.iters < 1:  # an internal error: the caller skipped ebad.state.with_step_budget
            raise ValueError(f"train.iters {tc.iters} (automatic) must be resolved first (ebad.state.with_step_budget)")
        return cls(
            iters=tc.iters,
            max_seconds=tc.max_seconds,
            coarse_until=tc.coarse_until if coarse else 0.0,
            views_at=tc.coarse_until if choose_views and tj.view_spacing > 0 else None,
            reset_until=cfg.strategy.reset_until,
            average_from=tj.average_from if averaging and tj.average_from < 1 else None,
            lr_means=tc.lr_means * scale,
            lr_means_final=tc.lr_means_final,
            lr_poses=tj.lr,
            lr_poses_final=tj.lr_final,
            sh_degree=cfg.model.sh_degree,
            sh_degree_interval=cfg.model.sh_degree_interval,
        )

    def fraction(self, step: int, elapsed: float) -> float:
        """How far through the budget ``step`` steps and ``elapsed`` seconds are, in [0, 1]."""
        frac = step / max(self.iters, 1)
        if self.max_seconds:
            frac = max(frac, elapsed / self.max_seconds)
        return min(frac, 1.0)

    def sh_degree_at(self, step: int, fraction: float) -> int:
        """The SH degree of the step after ``step`` steps, ``fraction`` of the budget (module docstring)."""
        if self.sh_degree <= 0:
            return 0
        level = max(step // self.sh_degree_interval, int(fraction * SH_REFERENCE_ITERS / self.sh_degree_interval))
        return min(self.sh_degree, level)

    def at(self, step: int, elapsed: float) -> Phase:
        """The phase of the step that starts after ``step`` steps and ``elapsed`` seconds (or, for
        ``averaging``, of the step that ended there)."""
        frac = self.fraction(step, elapsed)
        return Phase(
            fraction=frac,
            coarse=frac < self.coarse_until,
            views_due=self.views_at is not None and frac >= self.views_at,
            resets=frac < self.reset_until,
            averaging=self.average_from is not None and frac >= self.average_from,
            lr_means=self.lr_means * self.lr_means_final**frac,
            lr_poses=self.lr_poses * self.lr_poses_final**frac,
            sh_degree=self.sh_degree_at(step, frac),
        )
