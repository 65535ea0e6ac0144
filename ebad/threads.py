"""The process's thread set-up, in one explicit place: ``configure()``.

Nothing in ``ebad`` (or ``splat_cpu``) changes a process-wide setting when it is imported. The
command line's ``main`` and ``ebad.reconstruct`` call ``configure()`` before any work:

1. OMP_WAIT_POLICY=PASSIVE, only while torch is not loaded (torch's OpenMP runtime reads it
   once, when it loads) and only when the environment does not set it already (a user's value
   wins). Idle OpenMP threads then sleep instead of spinning between parallel regions and
   taking the cores from numba's threads and from other work.
2. numba's threading layer, from the policy actually in force (``splat_cpu._omp``): "omp" on
   sleeping OpenMP threads (it wakes them sooner than numba's own pool), numba's "workqueue"
   when they spin, e.g. when torch was loaded first without the policy. A layer the user chose
   is kept; once numba has launched its threads, nothing changes.

torch's own thread count is the caller's business: ``torch_single_threaded`` runs torch on one
thread and restores the count after (``ebad.loop.train``, ``ebad.evaluate``'s pose refinement).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from splat_cpu import _omp
from splat_cpu._omp import NumbaLayer

__all__ = ["ThreadSetup", "configure", "torch_single_threaded"]


@dataclass(frozen=True)
class ThreadSetup:
    """What ``configure`` found and did."""

    policy_set: bool  # this call set OMP_WAIT_POLICY=PASSIVE (torch not loaded yet, the variable unset)
    threads_sleep: bool  # OpenMP's idle threads sleep: PASSIVE was (or will be) in force when torch loads
    numba_layer: NumbaLayer  # chosen here (omp, workqueue), or left alone: the user's choice, threads already launched


def configure() -> ThreadSetup:
    """Set up the process's threads (see the module docstring); safe to call more than once."""
    policy_set = _omp.set_wait_policy("PASSIVE")
    return ThreadSetup(
        policy_set=policy_set, threads_sleep=_omp.openmp_threads_sleep(), numba_layer=_omp.choose_threading_layer()
    )


@contextmanager
def torch_single_threaded() -> Iterator[None]:
    """torch single-threaded for the duration, its thread count restored after. A step's torch
    operations are small: on one thread they neither spin between parallel regions (when
    OpenMP's threads do not sleep) nor wait for sleeping threads to wake, and the parallel work is
    numba's (rasteriser, SSIM), whose threads are its own; measured faster than two threads
    (docs/results.md)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
