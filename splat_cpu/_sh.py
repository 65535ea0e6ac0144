"""View-dependent colour from real spherical harmonics up to degree 3 (the INRIA / gsplat convention), pure torch.

Per Gaussian and channel, K = (degree + 1)^2 coefficients (DC first, then the K - 1 of degrees 1..3 in INRIA's
order); per camera, the direction d = normalise(mean - camera centre) in world space (the camera centre from the
inverse of the viewmat, as gsplat's `rasterization`), and

    colour = max(sum_k SH_k(d) coeffs[k] + 0.5, 0)

with INRIA's real basis (`sh_utils.eval_sh`): SH_0 = C0, then -C1 y, C1 z, -C1 x, then the degree-2 and degree-3
polynomials below. The numba twin is `_numba_sh`; this is the reference both paths are tested against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # torch loads on the first call, not on import (see `splat_cpu`)
    from torch import Tensor

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
SH_MAX_DEGREE = 3
NORM_EPS = 1e-12  # directions are v / max(|v|, NORM_EPS) (torch.nn.functional.normalize's default)


def num_sh_bases(degree: int) -> int:
    """Coefficients per channel of degree ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:  # [..., 3] unit -> [..., (degree + 1)^2]
    """The real SH basis of INRIA's ``eval_sh`` at unit directions, degree 0..3."""
    import torch

    out = [torch.full_like(dirs[..., 0], SH_C0)]
    if degree >= 1:
        x, y, z = dirs.unbind(-1)
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out += [
            SH_C2[0] * xy,
            SH_C2[1] * yz,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * xz,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def camera_centres(viewmats: Tensor) -> Tensor:  # [C, 4, 4] -> [C, 3]
    """World positions of the cameras: -R^-1 t (the translation of the inverse viewmat)."""
    import torch

    rot, trans = viewmats[:, :3, :3], viewmats[:, :3, 3]
    return -torch.linalg.solve(rot, trans[..., None])[..., 0]


def sh_colors(means: Tensor, coeffs: Tensor, viewmats: Tensor, degree: int) -> Tensor:
    """Per-camera colours [C, N, D] from coefficients [N, K, D] (K >= (degree + 1)^2; the first ones used).

    Computed in float64 (except on MPS) and returned in the coefficients' dtype, as the numba twin does."""
    import torch

    out_dtype = coeffs.dtype
    if means.device.type != "mps":
        means, coeffs, viewmats = means.double(), coeffs.double(), viewmats.double()
    nb = num_sh_bases(degree)
    dirs = torch.nn.functional.normalize(means[None] - camera_centres(viewmats)[:, None], dim=-1, eps=NORM_EPS)
    basis = sh_basis(degree, dirs)  # [C, N, nb]
    colors = torch.einsum("cnk,nkd->cnd", basis, coeffs[:, :nb]) + 0.5
    return colors.clamp_min(0.0).to(out_dtype)
