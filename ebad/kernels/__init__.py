"""ebad's fast kernels: numba passes with hand-written adjoints, and their autograd glue.

The method reads in ``ebad.losses`` (L_blur, L_ev, L_EDI, L1 + SSIM) and ``ebad.trajectory``
(the exposure trajectories' poses), written as plain torch: the reference. This package computes
the same values and gradients faster on the CPU, and is tested equal to that reference
(``tests/ebad/kernels``):

- ``_numba_ssim``: SSIM and L1 in one fused pass over the separable window, and its adjoint;
- ``_numba_event``: L_ev's residuals in one pass, and its gradient in another;
- ``_numba_poses``: the linear, cubic and offset trajectories' poses in closed form, with their
  derivatives carried forward;
- ``losses`` and ``poses``: the autograd Functions around them (numpy in, numpy out; one node
  each way), and the entry points ``ebad.losses`` and ``ebad.trajectory`` call.

Which path runs is decided in one place, ``use_kernels``: the kernels for CPU tensors, the torch
reference for any other device or inside ``torch_reference()``. ``losses`` imports its numba
modules on a loss's first call, and numba compiles each kernel on its first call, or loads it from
its cache (``ebad.run.warm_up`` does both before timed work).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__ = ["LUMA", "torch_reference", "use_kernels"]

#: The channel weights of the intensity a colour event pixel sees when the capture has no colour
#: filter (or ``loss.cfa_events luminance``): the channel mean, as ``scenes.simulate_events``. A
#: colour DAVIS's pixels see their own channel instead (``ebad.losses.cfa_weights``). Here, below
#: both ``ebad.losses`` (the reference) and the kernels.
LUMA = (1 / 3, 1 / 3, 1 / 3)

_enabled = True  # False inside ``torch_reference()``


def use_kernels(*tensors) -> bool:
    """The one dispatch: True when the kernels compute a loss or a pose of these tensors (all on
    the CPU; None entries are ignored), False when the torch reference does."""
    return _enabled and all(t is None or t.device.type == "cpu" for t in tensors)


@contextlib.contextmanager
def torch_reference() -> Iterator[None]:
    """Within: every loss and trajectory pose is computed by its torch reference (for tests and
    for comparisons; the kernels are the default on the CPU)."""
    global _enabled
    before, _enabled = _enabled, False
    try:
        yield
    finally:
        _enabled = before
