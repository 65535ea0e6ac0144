"""Where the loop, the run and the scoring helpers lived before they were split (issue 33).

The names are re-exported here so that older imports keep working; new code imports them from
their own modules: ``ebad.loop`` (``frame_losses``, ``train_step``, ``train``, ``should_stop``,
``step_profile``, ``coarse_data``, ``views_from_trajectories``), ``ebad.run`` (``reconstruct``,
``Run``, ``RunMetrics``, ``warm_up``), ``ebad.callbacks`` (``Callback``, ``Evaluator``,
``ProgressBar``, ``Checkpointer``, ``StepHook``) and ``ebad.scoring`` (``ViewScores``,
``render_images``, ``score_views``, ``with_poses``, ``evaluate_views``).
"""

from __future__ import annotations

from .callbacks import Callback, Checkpointer, Evaluator, ProgressBar, StepHook
from .loop import coarse_data, frame_losses, should_stop, step_profile, train, train_step, views_from_trajectories
from .run import Run, RunMetrics, reconstruct, warm_up
from .scoring import ViewScores, evaluate_views, render_images, score_views, with_poses

__all__ = [
    "Run",
    "RunMetrics",
    "ViewScores",
    "with_poses",
    "score_views",
    "frame_losses",
    "train_step",
    "train",
    "should_stop",
    "reconstruct",
    "evaluate_views",
    "coarse_data",
    "views_from_trajectories",
    "step_profile",
    "render_images",
    "Callback",
    "Evaluator",
    "ProgressBar",
    "Checkpointer",
    "StepHook",
    "warm_up",
]
