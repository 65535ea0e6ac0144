"""Numba evaluation of view-dependent SH colours (`_sh.sh_colors`) and its hand-written backward.

Arithmetic in float64 whatever the input dtype. The camera centres (and the inverse rotations the backward needs)
are computed by the caller, once per call (`_numba_impl._SHColors`); the kernels go over the Gaussians in parallel
chunks, every camera inside, and the backward's camera-centre gradients are per-chunk partial sums (deterministic,
no atomics). Gradients reach the coefficients, the means and the camera centres; the clamp at 0 passes the gradient
where the unclamped colour is >= 0 (torch's ``clamp_min``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._sh import NORM_EPS, SH_C0, SH_C1, SH_C2, SH_C3

CHUNKS = 64  # Gaussians are processed in this many chunks (scratch once per chunk; the backward's partial sums)

_C2_0, _C2_1, _C2_2, _C2_3, _C2_4 = SH_C2
_C3_0, _C3_1, _C3_2, _C3_3, _C3_4, _C3_5, _C3_6 = SH_C3


@njit(cache=True, inline="always")
def _direction(means, g, campos, c):  # -> (x, y, z, |v|, 1 / max(|v|, eps)) of v = mean - camera centre
    vx = np.float64(means[g, 0]) - campos[c, 0]
    vy = np.float64(means[g, 1]) - campos[c, 1]
    vz = np.float64(means[g, 2]) - campos[c, 2]
    r = math.sqrt(vx * vx + vy * vy + vz * vz)
    inv = 1.0 / max(r, NORM_EPS)
    return vx * inv, vy * inv, vz * inv, r, inv


@njit(cache=True, inline="always")
def _basis(degree, x, y, z, b):  # b[:(degree + 1)^2] written: `_sh.sh_basis`
    b[0] = SH_C0
    if degree < 1:
        return
    b[1] = -SH_C1 * y
    b[2] = SH_C1 * z
    b[3] = -SH_C1 * x
    if degree < 2:
        return
    xx, yy, zz = x * x, y * y, z * z
    xy, yz, xz = x * y, y * z, x * z
    b[4] = _C2_0 * xy
    b[5] = _C2_1 * yz
    b[6] = _C2_2 * (2.0 * zz - xx - yy)
    b[7] = _C2_3 * xz
    b[8] = _C2_4 * (xx - yy)
    if degree < 3:
        return
    b[9] = _C3_0 * y * (3.0 * xx - yy)
    b[10] = _C3_1 * xy * z
    b[11] = _C3_2 * y * (4.0 * zz - xx - yy)
    b[12] = _C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
    b[13] = _C3_4 * x * (4.0 * zz - xx - yy)
    b[14] = _C3_5 * z * (xx - yy)
    b[15] = _C3_6 * x * (xx - 3.0 * yy)


@njit(cache=True, inline="always")
def _basis_vjp(degree, x, y, z, vb):  # -> (gx, gy, gz) = sum_k vb[k] d b_k / d (x, y, z), the polynomials' gradient
    gx = 0.0
    gy = 0.0
    gz = 0.0
    if degree < 1:
        return gx, gy, gz
    gx -= SH_C1 * vb[3]
    gy -= SH_C1 * vb[1]
    gz += SH_C1 * vb[2]
    if degree < 2:
        return gx, gy, gz
    xx, yy, zz = x * x, y * y, z * z
    xy, yz, xz = x * y, y * z, x * z
    gx += _C2_0 * y * vb[4] - 2.0 * _C2_2 * x * vb[6] + _C2_3 * z * vb[7] + 2.0 * _C2_4 * x * vb[8]
    gy += _C2_0 * x * vb[4] + _C2_1 * z * vb[5] - 2.0 * _C2_2 * y * vb[6] - 2.0 * _C2_4 * y * vb[8]
    gz += _C2_1 * y * vb[5] + 4.0 * _C2_2 * z * vb[6] + _C2_3 * x * vb[7]
    if degree < 3:
        return gx, gy, gz
    gx += (
        _C3_0 * 6.0 * xy * vb[9]
        + _C3_1 * yz * vb[10]
        - _C3_2 * 2.0 * xy * vb[11]
        - _C3_3 * 6.0 * xz * vb[12]
        + _C3_4 * (4.0 * zz - 3.0 * xx - yy) * vb[13]
        + _C3_5 * 2.0 * xz * vb[14]
        + _C3_6 * 3.0 * (xx - yy) * vb[15]
    )
    gy += (
        _C3_0 * 3.0 * (xx - yy) * vb[9]
        + _C3_1 * xz * vb[10]
        + _C3_2 * (4.0 * zz - xx - 3.0 * yy) * vb[11]
        - _C3_3 * 6.0 * yz * vb[12]
        - _C3_4 * 2.0 * xy * vb[13]
        - _C3_5 * 2.0 * yz * vb[14]
        - _C3_6 * 6.0 * xy * vb[15]
    )
    gz += (
        _C3_1 * xy * vb[10]
        + _C3_2 * 8.0 * yz * vb[11]
        + _C3_3 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * vb[12]
        + _C3_4 * 8.0 * xz * vb[13]
        + _C3_5 * (xx - yy) * vb[14]
    )
    return gx, gy, gz


@njit(cache=True, parallel=True)
def sh_forward(
    means,  # [N, 3]
    coeffs,  # [N, K, D], K >= (degree + 1)^2
    campos,  # [C, 3] float64 camera centres
    degree,
    out,  # [C, N, D] written
):
    n, n_cam, d = means.shape[0], campos.shape[0], coeffs.shape[2]
    nb = (degree + 1) * (degree + 1)
    n_chunks = min(n, CHUNKS)
    for ch in prange(n_chunks):
        b = np.empty(16)
        for g in range(ch * n // n_chunks, (ch + 1) * n // n_chunks):
            for c in range(n_cam):
                x, y, z, _, _ = _direction(means, g, campos, c)
                _basis(degree, x, y, z, b)
                for k in range(d):
                    s = 0.0
                    for j in range(nb):
                        s += b[j] * np.float64(coeffs[g, j, k])
                    out[c, g, k] = max(s + 0.5, 0.0)


@njit(cache=True, parallel=True)
def sh_backward(
    means,  # [N, 3]
    coeffs,  # [N, K, D]
    campos,  # [C, 3] float64
    degree,
    v_colors,  # [C, N, D] cotangent of the colours
    out_means,  # [N, 3] written
    out_coeffs,  # [N, K, D] accumulated (zeros from the caller; rows beyond the degree stay zero)
    out_campos,  # [n_chunks, C, 3] written: per-chunk sums of d/d camera centre
):
    n, n_cam, d = means.shape[0], campos.shape[0], coeffs.shape[2]
    nb = (degree + 1) * (degree + 1)
    n_chunks = out_campos.shape[0]
    for ch in prange(n_chunks):
        out_campos[ch] = 0.0
        b = np.empty(16)
        vb = np.empty(16)
        for g in range(ch * n // n_chunks, (ch + 1) * n // n_chunks):
            vm0 = 0.0
            vm1 = 0.0
            vm2 = 0.0
            for c in range(n_cam):
                x, y, z, r, inv = _direction(means, g, campos, c)
                _basis(degree, x, y, z, b)
                vb[:nb] = 0.0
                for k in range(d):
                    s = 0.0
                    for j in range(nb):
                        s += b[j] * np.float64(coeffs[g, j, k])
                    if not s + 0.5 >= 0.0:
                        continue  # clamped: no gradient
                    vs = np.float64(v_colors[c, g, k])
                    for j in range(nb):
                        out_coeffs[g, j, k] += b[j] * vs
                        vb[j] += np.float64(coeffs[g, j, k]) * vs
                if degree == 0:
                    continue
                gx, gy, gz = _basis_vjp(degree, x, y, z, vb)
                # d = v / max(|v|, eps): v_v = (g - d (d . g)) / |v|, or g / eps below eps (torch's normalize)
                if r > NORM_EPS:
                    dot = gx * x + gy * y + gz * z
                    gx, gy, gz = (gx - dot * x) * inv, (gy - dot * y) * inv, (gz - dot * z) * inv
                else:
                    gx, gy, gz = gx * inv, gy * inv, gz * inv
                vm0 += gx
                vm1 += gy
                vm2 += gz
                out_campos[ch, c, 0] -= gx
                out_campos[ch, c, 1] -= gy
                out_campos[ch, c, 2] -= gz
            out_means[g, 0] = vm0
            out_means[g, 1] = vm1
            out_means[g, 2] = vm2
