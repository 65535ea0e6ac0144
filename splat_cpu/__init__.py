"""splat_cpu: a small differentiable 3D Gaussian rasteriser that is fast on a CPU.

    images, alphas, meta = splat_cpu.rasterize(means, quats, scales, opacities, colors,
                                               viewmats, Ks, width, height, background=None)

Semantics are gsplat's "classic" mode (see `splat_cpu.constants` and docs/conventions.md),
with its frustum clamp of the projection's Jacobian (`constants.FRUSTUM_MARGIN`).
`rasterize` uses the numba tile kernels for CPU tensors and the pure-torch reference
elsewhere; `rasterize_reference` always uses the reference.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

from . import constants
from ._sh import SH_C0, SH_MAX_DEGREE, num_sh_bases, sh_colors

if TYPE_CHECKING:  # torch loads on the first call, not on import (``_omp`` is read before torch by ``ebad``)
    from torch import Tensor

__all__ = ["rasterize", "rasterize_reference", "sh_colors", "num_sh_bases", "SH_C0", "SH_MAX_DEGREE", "constants"]


def _fast_path():
    """The numba path, or None (with a warning saying the fix) when numba cannot be imported."""
    try:
        from ._numba_impl import rasterize_numba
    except ImportError as exc:  # pragma: no cover - numba is a declared dependency
        warnings.warn(
            f"splat_cpu: numba unavailable ({exc}); using the slow torch reference. "
            "Install it with `pip install numba`.",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    return rasterize_numba


def rasterize(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
    sh_degree: int | None = None,
) -> tuple[Tensor, Tensor, dict]:
    """Render N 3D Gaussians into C pinhole cameras, differentiably.

    Args:
        means: [N, 3] world positions.
        quats: [N, 4] rotations (w, x, y, z); normalised inside.
        scales: [N, 3] standard deviations along the rotated axes, > 0 (activated).
        opacities: [N] in [0, 1] (activated).
        colors: [N, D] per-Gaussian values, any D >= 1 (1 grey, 3 colour, or features); [C, N, D] per camera;
            or, with `sh_degree`, [N, K, D] spherical-harmonic coefficients, K >= (sh_degree + 1)^2.
        viewmats: [C, 4, 4] world-to-camera, OpenCV axes (x right, y down, z forward).
        Ks: [C, 3, 3] intrinsics in pixels, no skew; the top-left pixel's centre is (0.5, 0.5).
        width, height: image size in pixels, > 0.
        background: [D] composited as T_final * background, or None (black).
        sh_degree: None (colours as given), or 0..3: view-dependent colours from the coefficients in `colors`,
            the INRIA / gsplat convention: colour = max(SH(d) . coeffs + 0.5, 0) per channel, d the unit vector
            from the camera centre (the inverse viewmat's translation) to the mean, in world space; only the
            first (sh_degree + 1)^2 coefficients are read (`splat_cpu.sh_colors`).

    Returns:
        images: [C, H, W, D]; alphas: [C, H, W, 1] (1 - final transmittance);
        meta: dict with "radii" [C, N, 2] int32 (0 where culled), "means2d" [C, N, 2] (in
        the autograd graph: call retain_grad() for screen-space gradients), "depths" [C, N],
        "n_visible" [C], "path" ("numba" or "torch"), "timings" (ms per stage; on the numba
        path the backward adds "backward_project_ms" and "backward_composite_ms" when it runs).

    Gradients flow to means, quats, scales, opacities, colors, viewmats and background (with `sh_degree`, to the
    coefficients, and through the view direction to the means and the viewmats).
    Raises ValueError naming the argument for wrong shapes, dtypes, devices, non-finite
    values, non-positive width/height, scales <= 0 or opacities outside [0, 1].
    """
    from ._torch_impl import rasterize_reference as _reference
    from ._validate import validate_inputs

    validate_inputs(means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree)
    if means.device.type == "cpu":
        rasterize_numba = _fast_path()
        if rasterize_numba is not None:
            return rasterize_numba(
                means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree
            )
    return _reference(means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree)


def rasterize_reference(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
    sh_degree: int | None = None,
) -> tuple[Tensor, Tensor, dict]:
    """The pure-torch path (any device), same contract as `rasterize`; slow but short."""
    from ._torch_impl import rasterize_reference as _reference
    from ._validate import validate_inputs

    validate_inputs(means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree)
    return _reference(means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree)
