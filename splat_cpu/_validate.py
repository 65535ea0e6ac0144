"""Typed, early validation of the public inputs; every error names the argument.

Value checks on CPU tensors run in numpy: a torch reduction over a few thousand values is an
OpenMP parallel region, and without OMP_WAIT_POLICY=PASSIVE each region can cost
milliseconds on a busy machine (see `_numba_impl`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from ._sh import SH_MAX_DEGREE, num_sh_bases
from .constants import SCALE_MAX


def _values(x: Tensor) -> np.ndarray | Tensor:
    """The values to check: a numpy view on the CPU, the tensor itself elsewhere."""
    return x.detach().numpy() if x.device.type == "cpu" else x.detach()


def _all_finite(x: Tensor) -> bool:
    v = _values(x)
    return bool(np.isfinite(v).all()) if isinstance(v, np.ndarray) else bool(torch.isfinite(v).all())


def _check_tensor(name: str, x: object, ndim: int, tail: tuple[int | None, ...], like: Tensor | None = None) -> Tensor:
    if not isinstance(x, Tensor):
        raise ValueError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    if x.dim() != ndim:
        raise ValueError(f"{name}: expected {ndim} dimensions, got shape {tuple(x.shape)}")
    for i, want in enumerate(tail):
        got = x.shape[ndim - len(tail) + i]
        if want is not None and got != want:
            shape = ", ".join("*" if w is None else str(w) for w in tail)
            raise ValueError(f"{name}: expected shape [..., {shape}], got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise ValueError(f"{name}: expected a floating-point tensor, got dtype {x.dtype}")
    if x.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"{name}: expected float32 or float64, got {x.dtype}")
    if like is not None:
        if x.dtype != like.dtype:
            raise ValueError(f"{name}: dtype {x.dtype} differs from means' dtype {like.dtype}")
        if x.device != like.device:
            raise ValueError(f"{name}: device {x.device} differs from means' device {like.device}")
    if not _all_finite(x):
        raise ValueError(f"{name}: contains non-finite values (nan or inf)")
    return x


def validate_inputs(  # noqa: C901  (one check per argument, in the signature's order)
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    background: Tensor | None,  # [D]
    sh_degree: int | None = None,
) -> None:
    """Raise ValueError naming the first argument that is not what `rasterize` expects."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError(f"{name}: expected a Python int, got {type(v).__name__}")
        if v <= 0:
            raise ValueError(f"{name}: must be positive, got {v}")
    _check_tensor("means", means, 2, (3,))
    n = means.shape[0]
    _check_tensor("quats", quats, 2, (4,), means)
    _check_tensor("scales", scales, 2, (3,), means)
    _check_tensor("opacities", opacities, 1, (), means)
    if sh_degree is not None:
        if isinstance(sh_degree, bool) or not isinstance(sh_degree, int) or not 0 <= sh_degree <= SH_MAX_DEGREE:
            raise ValueError(f"sh_degree: expected None or an int in 0..{SH_MAX_DEGREE}, got {sh_degree!r}")
        _check_tensor("colors", colors, 3, (None, None), means)
        if colors.shape[1] < num_sh_bases(sh_degree):
            raise ValueError(
                f"colors: SH degree {sh_degree} needs [N, K, D] coefficients with K >= {num_sh_bases(sh_degree)}, "
                f"got shape {tuple(colors.shape)}"
            )
    elif isinstance(colors, Tensor) and colors.dim() == 3:
        _check_tensor("colors", colors, 3, (None, None), means)
    else:
        _check_tensor("colors", colors, 2, (None,), means)
    _check_tensor("viewmats", viewmats, 3, (4, 4), means)
    _check_tensor("Ks", Ks, 3, (3, 3), means)
    per_camera = sh_degree is None and colors.dim() == 3  # [C, N, D]
    for name, x in (("quats", quats), ("scales", scales), ("opacities", opacities)):
        if x.shape[0] != n:
            raise ValueError(f"{name}: expected {n} rows (one per Gaussian, as means), got shape {tuple(x.shape)}")
    if colors.shape[1 if per_camera else 0] != n:
        raise ValueError(f"colors: expected {n} Gaussians (as means), got shape {tuple(colors.shape)}")
    d = colors.shape[-1]
    if d < 1:
        raise ValueError(f"colors: expected at least one channel, got shape {tuple(colors.shape)}")
    c = viewmats.shape[0]
    if c < 1:
        raise ValueError("viewmats: expected at least one camera, got shape [0, 4, 4]")
    if Ks.shape[0] != c:
        raise ValueError(f"Ks: expected {c} cameras (as viewmats), got shape {tuple(Ks.shape)}")
    if per_camera and colors.shape[0] != c:
        raise ValueError(f"colors: per-camera colours need {c} cameras (as viewmats), got shape {tuple(colors.shape)}")
    if background is not None:
        _check_tensor("background", background, 1, (), means)
        if background.shape[0] != d:
            raise ValueError(f"background: expected {d} channels (as colors), got shape {tuple(background.shape)}")
    if n > 0:
        sv, ov, qv = _values(scales), _values(opacities), _values(quats)
        if bool((sv <= 0).any()):
            raise ValueError("scales: must be > 0 (activated scales, not logs)")
        if bool((sv > SCALE_MAX).any()):
            raise ValueError(
                f"scales: must be <= SCALE_MAX = {SCALE_MAX:g} (activated scales, not logs), "
                f"got {float(sv.max()):.3g}; beyond it the projected covariance overflows"
            )
        if bool(((ov < 0) | (ov > 1)).any()):
            raise ValueError("opacities: must lie in [0, 1] (activated opacities, not logits)")
        # the squared norm by columns: a numpy sum over a last axis of 4 took 76 us for 6k quaternions, this 18
        if bool(((qv[:, 0] * qv[:, 0] + qv[:, 1] * qv[:, 1] + qv[:, 2] * qv[:, 2] + qv[:, 3] * qv[:, 3]) == 0).any()):
            raise ValueError("quats: a quaternion has zero norm")
    vv, kv = _values(viewmats), _values(Ks)
    if bool((vv[:, 3, :3] != 0).any()) or bool((vv[:, 3, 3] != 1).any()):
        raise ValueError("viewmats: the last row of every 4x4 must be [0, 0, 0, 1]")
    if sh_degree is not None:
        rot = np.asarray(vv[:, :3, :3].cpu() if isinstance(vv, Tensor) else vv, dtype=np.float64)
        if not bool((np.abs(np.linalg.det(rot)) > 1e-12).all()):
            raise ValueError("viewmats: a rotation part is singular: no camera centre for view-dependent colours")
    if bool((kv[:, 0, 0] <= 0).any()) or bool((kv[:, 1, 1] <= 0).any()):
        raise ValueError("Ks: focal lengths fx = K[0, 0] and fy = K[1, 1] must be > 0")
    if (
        bool((kv[:, 0, 1] != 0).any())
        or bool((kv[:, 1, 0] != 0).any())
        or bool((kv[:, 2, :2] != 0).any())
        or bool((kv[:, 2, 2] != 1).any())
    ):
        raise ValueError("Ks: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
