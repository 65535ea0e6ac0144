"""Numba EWA projection of N Gaussians into C cameras, with its hand-written backward.

The fast twin of `_project.project` (same rules, same outputs), fused per Gaussian: the
rotation and the 3D covariance are computed once and shared by the C cameras (the V
virtual views of one exposure). Arithmetic is float64 whatever the input dtype, so scales
up to `constants.SCALE_MAX` stay finite. The backward follows gsplat's
`fully_fused_projection` VJPs: conic -> 2D covariance -> (J W, Sigma) -> (mean, pose,
quaternion, scale), with its frustum clamp of x/z and y/z in the Jacobian (`_project.frustum_limits`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .constants import ALPHA_MIN, COV2D_BLUR, FRUSTUM_MARGIN, NEAR

_INT32_MAX = 2**31 - 1
_FORWARD_CHUNKS = 64  # Gaussians are projected in this many chunks (scratch arrays once per chunk)


@njit(cache=True, inline="always")
def _rotmat(qw, qx, qy, qz, r):  # normalised quaternion (w, x, y, z) -> r [3, 3] written
    r[0, 0] = 1.0 - 2.0 * (qy * qy + qz * qz)
    r[0, 1] = 2.0 * (qx * qy - qw * qz)
    r[0, 2] = 2.0 * (qx * qz + qw * qy)
    r[1, 0] = 2.0 * (qx * qy + qw * qz)
    r[1, 1] = 1.0 - 2.0 * (qx * qx + qz * qz)
    r[1, 2] = 2.0 * (qy * qz - qw * qx)
    r[2, 0] = 2.0 * (qx * qz - qw * qy)
    r[2, 1] = 2.0 * (qy * qz + qw * qx)
    r[2, 2] = 1.0 - 2.0 * (qx * qx + qy * qy)


@njit(cache=True, inline="always")
def _covariance(quats, scales, g, q, m, cov):  # q [4], m = R S [3, 3], cov = M M^T [3, 3] written
    nrm = math.sqrt(quats[g, 0] ** 2 + quats[g, 1] ** 2 + quats[g, 2] ** 2 + quats[g, 3] ** 2)
    for i in range(4):
        q[i] = quats[g, i] / nrm
    _rotmat(q[0], q[1], q[2], q[3], m)
    for j in range(3):
        s = np.float64(scales[g, j])
        for i in range(3):
            m[i, j] *= s
    for i in range(3):
        for j in range(3):
            cov[i, j] = m[i, 0] * m[j, 0] + m[i, 1] * m[j, 1] + m[i, 2] * m[j, 2]
    return nrm


@njit(cache=True, inline="always")
def _camera_point(viewmats, c, means, g, p):  # p = W mean + t [3] written
    for i in range(3):
        p[i] = (
            viewmats[c, i, 0] * means[g, 0]
            + viewmats[c, i, 1] * means[g, 1]
            + viewmats[c, i, 2] * means[g, 2]
            + viewmats[c, i, 3]
        )


@njit(cache=True, inline="always")
def _frustum_limits(ks, c, width, height):  # -> (x neg, x pos, y neg, y pos): `_project.frustum_limits`
    fx, fy = np.float64(ks[c, 0, 0]), np.float64(ks[c, 1, 1])
    cx, cy = np.float64(ks[c, 0, 2]), np.float64(ks[c, 1, 2])
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    return (
        cx / fx + FRUSTUM_MARGIN * tan_x,
        (width - cx) / fx + FRUSTUM_MARGIN * tan_x,
        cy / fy + FRUSTUM_MARGIN * tan_y,
        (height - cy) / fy + FRUSTUM_MARGIN * tan_y,
    )


@njit(cache=True, inline="always")
def _clamped(x, z, lim_neg, lim_pos):  # -> (x/z clamped to [-lim_neg, lim_pos], whether it was inside)
    r = x / z
    return min(max(r, -lim_neg), lim_pos), -lim_neg <= r <= lim_pos


@njit(cache=True, inline="always")
def _jw(viewmats, c, fx, fy, xc, yc, z, t):  # t = J W [2, 3] written (J at the mean, x/z and y/z clamped)
    j00, j02 = fx / z, -fx * xc / z
    j11, j12 = fy / z, -fy * yc / z
    for k in range(3):
        t[0, k] = j00 * viewmats[c, 0, k] + j02 * viewmats[c, 2, k]
        t[1, k] = j11 * viewmats[c, 1, k] + j12 * viewmats[c, 2, k]


@njit(cache=True, inline="always")
def _project_one(
    means,
    quats,
    scales,
    opacities,
    viewmats,
    ks,
    width,
    height,
    g,
    q,
    m,
    cov,
    p,
    t,
    out_means2d,
    out_conics,
    out_depths,
    out_radii,
    out_box,
    out_valid,
):
    """project_forward for Gaussian g into every camera; q, m, cov, p, t are scratch."""
    n_cam = viewmats.shape[0]
    _covariance(quats, scales, g, q, m, cov)
    op = np.float64(opacities[g])
    extend = math.sqrt(2.0 * math.log(max(op, ALPHA_MIN) / ALPHA_MIN))
    for c in range(n_cam):
        out_means2d[c, g, 0] = 0.0
        out_means2d[c, g, 1] = 0.0
        out_conics[c, g, 0] = 1.0
        out_conics[c, g, 1] = 0.0
        out_conics[c, g, 2] = 1.0
        out_depths[c, g] = 0.0
        out_radii[c, g, 0] = 0
        out_radii[c, g, 1] = 0
        out_box[c, g, 0] = 0
        out_box[c, g, 1] = -1
        out_box[c, g, 2] = 0
        out_box[c, g, 3] = -1
        out_valid[c, g] = False
        _camera_point(viewmats, c, means, g, p)
        x, y, z = p[0], p[1], p[2]
        if not z > NEAR or op < ALPHA_MIN:
            continue
        fx, fy = np.float64(ks[c, 0, 0]), np.float64(ks[c, 1, 1])
        lxn, lxp, lyn, lyp = _frustum_limits(ks, c, width, height)
        xc = _clamped(x, z, lxn, lxp)[0]
        yc = _clamped(y, z, lyn, lyp)[0]
        _jw(viewmats, c, fx, fy, xc, yc, z, t)
        ca = COV2D_BLUR
        cb = 0.0
        cc = COV2D_BLUR
        for i in range(3):
            for j in range(3):
                ca += t[0, i] * cov[i, j] * t[0, j]
                cb += t[0, i] * cov[i, j] * t[1, j]
                cc += t[1, i] * cov[i, j] * t[1, j]
        det = ca * cc - cb * cb
        if not (det > 0.0 and math.isfinite(det)):
            continue
        u = fx * x / z + np.float64(ks[c, 0, 2])
        v = fy * y / z + np.float64(ks[c, 1, 2])
        rx = math.ceil(extend * math.sqrt(ca))
        ry = math.ceil(extend * math.sqrt(cc))
        # pixel i is inside when |i + 0.5 - u| <= rx; clamp in float64 before any integer conversion
        x0 = min(max(math.ceil(u - rx - 0.5), 0.0), float(width))
        x1 = min(max(math.floor(u + rx - 0.5), -1.0), float(width - 1))
        y0 = min(max(math.ceil(v - ry - 0.5), 0.0), float(height))
        y1 = min(max(math.floor(v + ry - 0.5), -1.0), float(height - 1))
        if x0 > x1 or y0 > y1:
            continue
        out_valid[c, g] = True
        out_means2d[c, g, 0] = u
        out_means2d[c, g, 1] = v
        out_conics[c, g, 0] = cc / det
        out_conics[c, g, 1] = -cb / det
        out_conics[c, g, 2] = ca / det
        out_depths[c, g] = z
        out_radii[c, g, 0] = np.int32(min(rx, float(_INT32_MAX)))
        out_radii[c, g, 1] = np.int32(min(ry, float(_INT32_MAX)))
        out_box[c, g, 0] = np.int64(x0)
        out_box[c, g, 1] = np.int64(x1)
        out_box[c, g, 2] = np.int64(y0)
        out_box[c, g, 3] = np.int64(y1)


@njit(cache=True, parallel=True)
def project_forward(
    means,  # [N, 3]
    quats,  # [N, 4]
    scales,  # [N, 3]
    opacities,  # [N]
    viewmats,  # [C, 4, 4]
    ks,  # [C, 3, 3]
    width,
    height,
    out_means2d,  # [C, N, 2] written (0 where culled)
    out_conics,  # [C, N, 3] written ((1, 0, 1) where culled)
    out_depths,  # [C, N] written (0 where culled)
    out_radii,  # [C, N, 2] int32 written (0 where culled)
    out_box,  # [C, N, 4] int64 written: inclusive (x0, x1, y0, y1), (0, -1, 0, -1) where culled
    out_valid,  # [C, N] bool written
):
    n = means.shape[0]
    n_chunks = min(n, _FORWARD_CHUNKS)
    for chunk in prange(n_chunks):
        q = np.empty(4)  # scratch of the chunk (allocated once per chunk, not per Gaussian)
        m = np.empty((3, 3))
        cov = np.empty((3, 3))
        p = np.empty(3)
        t = np.empty((2, 3))
        for g in range(chunk * n // n_chunks, (chunk + 1) * n // n_chunks):
            _project_one(
                means,
                quats,
                scales,
                opacities,
                viewmats,
                ks,
                width,
                height,
                g,
                q,
                m,
                cov,
                p,
                t,
                out_means2d,
                out_conics,
                out_depths,
                out_radii,
                out_box,
                out_valid,
            )


@njit(cache=True, parallel=True)
def project_backward(
    means,  # [N, 3]
    quats,  # [N, 4]
    scales,  # [N, 3]
    viewmats,  # [C, 4, 4]
    ks,  # [C, 3, 3]
    width,
    height,
    valid,  # [C, N] bool
    conics,  # [C, N, 3] the forward's conics (float64)
    v_means2d,  # [C, N, 2]
    v_conics,  # [C, N, 3]
    out_means,  # [N, 3] written
    out_quats,  # [N, 4] written
    out_scales,  # [N, 3] written
    out_view,  # [n_chunks, C, 3, 4] written: per-chunk sums of d/d viewmats[:, :3, :4]
):
    n = means.shape[0]
    n_cam = viewmats.shape[0]
    n_chunks = out_view.shape[0]
    for ch in prange(n_chunks):
        out_view[ch] = 0.0
        q = np.empty(4)
        m = np.empty((3, 3))
        cov = np.empty((3, 3))
        p = np.empty(3)
        t = np.empty((2, 3))
        v_cov = np.empty((3, 3))  # d/d Sigma (3D), summed over cameras
        v_t = np.empty((2, 3))
        tsig = np.empty((2, 3))
        vr = np.empty((3, 3))
        for g in range(ch * n // n_chunks, (ch + 1) * n // n_chunks):
            nrm = _covariance(quats, scales, g, q, m, cov)
            v_cov[:] = 0.0
            vm0 = 0.0
            vm1 = 0.0
            vm2 = 0.0
            for c in range(n_cam):
                if not valid[c, g]:
                    continue
                _camera_point(viewmats, c, means, g, p)
                x, y, z = p[0], p[1], p[2]
                fx, fy = np.float64(ks[c, 0, 0]), np.float64(ks[c, 1, 1])
                lxn, lxp, lyn, lyp = _frustum_limits(ks, c, width, height)
                xc, x_in = _clamped(x, z, lxn, lxp)
                yc, y_in = _clamped(y, z, lyn, lyp)
                _jw(viewmats, c, fx, fy, xc, yc, z, t)
                # conic Q = Sigma2d^-1 with Q01 used once: dL = tr(G dQ), G = [[va, vb/2], [vb/2, vc]]
                qa, qb, qc = conics[c, g, 0], conics[c, g, 1], conics[c, g, 2]
                ga, gb, gc = v_conics[c, g, 0], 0.5 * v_conics[c, g, 1], v_conics[c, g, 2]
                # V = -Q G Q (symmetric): d/d Sigma2d
                h00 = qa * ga + qb * gb
                h01 = qa * gb + qb * gc
                h10 = qb * ga + qc * gb
                h11 = qb * gb + qc * gc
                w00 = -(h00 * qa + h01 * qb)
                w01 = -(h00 * qb + h01 * qc)
                w11 = -(h10 * qb + h11 * qc)
                # Sigma2d = T Sigma T^T: v_T = 2 V T Sigma, v_Sigma += T^T V T
                for k in range(3):
                    tsig[0, k] = t[0, 0] * cov[0, k] + t[0, 1] * cov[1, k] + t[0, 2] * cov[2, k]
                    tsig[1, k] = t[1, 0] * cov[0, k] + t[1, 1] * cov[1, k] + t[1, 2] * cov[2, k]
                for k in range(3):
                    v_t[0, k] = 2.0 * (w00 * tsig[0, k] + w01 * tsig[1, k])
                    v_t[1, k] = 2.0 * (w01 * tsig[0, k] + w11 * tsig[1, k])
                for i in range(3):
                    for j in range(3):
                        v_cov[i, j] += t[0, i] * (w00 * t[0, j] + w01 * t[1, j]) + t[1, i] * (
                            w01 * t[0, j] + w11 * t[1, j]
                        )
                # T = J W: v_J = v_T W^T, v_W += J^T v_T
                j00, j02 = fx / z, -fx * xc / z
                j11, j12 = fy / z, -fy * yc / z
                vj00 = 0.0
                vj02 = 0.0
                vj11 = 0.0
                vj12 = 0.0
                for k in range(3):
                    vj00 += v_t[0, k] * viewmats[c, 0, k]
                    vj02 += v_t[0, k] * viewmats[c, 2, k]
                    vj11 += v_t[1, k] * viewmats[c, 1, k]
                    vj12 += v_t[1, k] * viewmats[c, 2, k]
                for k in range(3):
                    out_view[ch, c, 0, k] += j00 * v_t[0, k]
                    out_view[ch, c, 1, k] += j11 * v_t[1, k]
                    out_view[ch, c, 2, k] += j02 * v_t[0, k] + j12 * v_t[1, k]
                # p = (x, y, z): through J and through (u, v) = (fx x / z + cx, fy y / z + cy); J02 = -fx x / z^2
                # inside the frustum's limits, -fx xc / z with a constant xc outside them (gsplat's clamp)
                vu, vv = v_means2d[c, g, 0], v_means2d[c, g, 1]
                iz = 1.0 / z
                iz2 = iz * iz
                vx = vu * fx * iz - (vj02 * fx * iz2 if x_in else 0.0)
                vy = vv * fy * iz - (vj12 * fy * iz2 if y_in else 0.0)
                vz = (
                    -vu * fx * x * iz2
                    - vv * fy * y * iz2
                    - vj00 * fx * iz2
                    - vj11 * fy * iz2
                    + vj02 * fx * (2.0 * x * iz2 * iz if x_in else xc * iz2)
                    + vj12 * fy * (2.0 * y * iz2 * iz if y_in else yc * iz2)
                )
                # p = W mean + t
                for k in range(3):
                    out_view[ch, c, k, 0] += (vx if k == 0 else vy if k == 1 else vz) * means[g, 0]
                    out_view[ch, c, k, 1] += (vx if k == 0 else vy if k == 1 else vz) * means[g, 1]
                    out_view[ch, c, k, 2] += (vx if k == 0 else vy if k == 1 else vz) * means[g, 2]
                out_view[ch, c, 0, 3] += vx
                out_view[ch, c, 1, 3] += vy
                out_view[ch, c, 2, 3] += vz
                vm0 += viewmats[c, 0, 0] * vx + viewmats[c, 1, 0] * vy + viewmats[c, 2, 0] * vz
                vm1 += viewmats[c, 0, 1] * vx + viewmats[c, 1, 1] * vy + viewmats[c, 2, 1] * vz
                vm2 += viewmats[c, 0, 2] * vx + viewmats[c, 1, 2] * vy + viewmats[c, 2, 2] * vz
            out_means[g, 0] = vm0
            out_means[g, 1] = vm1
            out_means[g, 2] = vm2
            # Sigma = M M^T, M = R S: v_M = (v_Sigma + v_Sigma^T) M; v_R = v_M S; v_s_j = sum_i v_M_ij R_ij
            for j in range(3):
                s = np.float64(scales[g, j])
                vs = 0.0
                for i in range(3):
                    vmij = 0.0
                    for k in range(3):
                        vmij += (v_cov[i, k] + v_cov[k, i]) * m[k, j]
                    vr[i, j] = vmij * s
                    vs += vmij * m[i, j] / s
                out_scales[g, j] = vs
            w, qx, qy, qz = q[0], q[1], q[2], q[3]
            dw = 2.0 * (qx * (vr[2, 1] - vr[1, 2]) + qy * (vr[0, 2] - vr[2, 0]) + qz * (vr[1, 0] - vr[0, 1]))
            dx = 2.0 * (
                -2.0 * qx * (vr[1, 1] + vr[2, 2])
                + qy * (vr[1, 0] + vr[0, 1])
                + qz * (vr[2, 0] + vr[0, 2])
                + w * (vr[2, 1] - vr[1, 2])
            )
            dy = 2.0 * (
                qx * (vr[1, 0] + vr[0, 1])
                - 2.0 * qy * (vr[0, 0] + vr[2, 2])
                + qz * (vr[2, 1] + vr[1, 2])
                + w * (vr[0, 2] - vr[2, 0])
            )
            dz = 2.0 * (
                qx * (vr[2, 0] + vr[0, 2])
                + qy * (vr[2, 1] + vr[1, 2])
                - 2.0 * qz * (vr[0, 0] + vr[1, 1])
                + w * (vr[1, 0] - vr[0, 1])
            )
            # q = quats / |quats|: project out the radial part
            dot = dw * w + dx * qx + dy * qy + dz * qz
            out_quats[g, 0] = (dw - dot * w) / nrm
            out_quats[g, 1] = (dx - dot * qx) / nrm
            out_quats[g, 2] = (dy - dot * qy) / nrm
            out_quats[g, 3] = (dz - dot * qz) / nrm
