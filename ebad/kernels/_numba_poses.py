"""The exposure trajectories' poses in closed form, with their derivatives carried forward (numba).

``ebad.trajectory``'s pose functions are torch compositions of a few dozen small operations
(``so3_exp`` through ``matrix_exp``, ``so3_log``, products, the anchoring); at a training step's
sizes (one frame, six instants) each costs a few microseconds forward and more backward, which
added up to a large part of a step's time outside the rasteriser. Here the same poses come
from one numba function in float64, and with them their derivatives with respect to every knot
(forward mode: each quantity carries its tangents along the P = K x 6 knot coordinates). The
backward is then one contraction of those tangents with the upstream gradient
(``ebad.kernels.poses.TrajectoryPoses``). The torch functions stay the reference (tests compare both).

Rotations use the closed forms of SO(3) (Barfoot, "State Estimation for Robotics", 7.1):
exp(w) = I + a W + b W^2 and its right Jacobian Jr(w) = I - b W + c W^2 (W = [w]x, a = sin t / t,
b = (1 - cos t) / t^2, c = (t - sin t) / t^3, t = |w|), so d exp(w) = exp(w) [Jr(w) dw]x; the
logarithm as ``ebad.lie.so3_log`` and d log(R) = Jr^-1(w) vee(R^T dR), Jr^-1(w) = I + W / 2 +
e W^2, e = (1 - (t / 2) cot(t / 2)) / t^2. Series replace the ratios near t = 0. A logarithm
within ``NEAR_PI_COS`` of pi is refused (``_poses`` returns False, ``ebad.kernels.poses`` raises
``NearPi``): the caller takes the torch path, as ``so3_log`` takes kornia's there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: below this cos(angle) a logarithm is refused (``ebad.lie._NEAR_PI_COS``: there vee(R - R^T) loses its digits)
NEAR_PI_COS = -0.9
_SMALL_EXP = 1e-4  # t^2 below which exp's and Jr's ratios come from their series (error ~ t^6 / 5040)
_SMALL_INV = 1e-2  # t^2 below which Jr^-1's ratio comes from its series (error ~ t^8 / 4.8e7)
_SMALL_LOG = 1e-10  # sin(t)^2 below which t / sin(t) comes from its series
#: the trajectory kinds with a closed form, and their number of knots (``ebad.trajectory.TRAJECTORIES``)
KINDS = {"linear": 2, "cubic": 4, "offset": 1}
_KIND_ID = {"linear": 0, "cubic": 1, "offset": 2}


# The numba functions below are written with scalar loops only: numba's array expressions, slice
# assignments and matmul compiled several times slower on a cold cache (a first run).


@njit(cache=True)
def _mm(A, B, out):  # pragma: no cover - jit
    """out = A B for 3 x 3 matrices; out must not be A or B."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def _mtm(A, B, out):  # pragma: no cover - jit
    """out = A^T B for 3 x 3 matrices."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[0, i] * B[0, j] + A[1, i] * B[1, j] + A[2, i] * B[2, j]


@njit(cache=True)
def _hat_into(v0, v1, v2, out):  # pragma: no cover - jit
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -v2, v1
    out[1, 0], out[1, 1], out[1, 2] = v2, 0.0, -v0
    out[2, 0], out[2, 1], out[2, 2] = -v1, v0, 0.0


@njit(cache=True)
def _exp_jr(w0, w1, w2, R, J):  # pragma: no cover - jit
    """R = exp([w]x) and J = Jr(w), 3 x 3, written."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    if t2 < _SMALL_EXP:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    else:
        t = math.sqrt(t2)
        a = math.sin(t) / t
        b = (1.0 - math.cos(t)) / t2
        c = (t - math.sin(t)) / (t2 * t)
    W = np.empty((3, 3))
    W2 = np.empty((3, 3))
    _hat_into(w0, w1, w2, W)
    _mm(W, W, W2)
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            R[i, j] = e + a * W[i, j] + b * W2[i, j]
            J[i, j] = e - b * W[i, j] + c * W2[i, j]


@njit(cache=True)
def _log_jinv(Q, w, Jinv):  # pragma: no cover - jit
    """w = log(Q) and Jinv = Jr(w)^-1 written; False (nothing written) within NEAR_PI_COS of pi."""
    v0 = 0.5 * (Q[2, 1] - Q[1, 2])
    v1 = 0.5 * (Q[0, 2] - Q[2, 0])
    v2 = 0.5 * (Q[1, 0] - Q[0, 1])
    cos = 0.5 * (Q[0, 0] + Q[1, 1] + Q[2, 2] - 1.0)
    if cos < NEAR_PI_COS:
        return False
    s2 = v0 * v0 + v1 * v1 + v2 * v2
    if s2 < _SMALL_LOG:
        f = 1.0 + s2 / 6.0 + 3.0 * s2 * s2 / 40.0
    else:
        s = math.sqrt(s2)
        f = math.atan2(s, cos) / s
    w[0], w[1], w[2] = v0 * f, v1 * f, v2 * f
    t2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if t2 < _SMALL_INV:
        e = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1209600.0
    else:
        t = math.sqrt(t2)
        e = (1.0 - 0.5 * t / math.tan(0.5 * t)) / t2
    W = np.empty((3, 3))
    W2 = np.empty((3, 3))
    _hat_into(w[0], w[1], w[2], W)
    _mm(W, W, W2)
    for i in range(3):
        for j in range(3):
            Jinv[i, j] = (1.0 if i == j else 0.0) + 0.5 * W[i, j] + e * W2[i, j]
    return True


@njit(cache=True)
def _rot_tangent(R, J, col, scale, out):  # pragma: no cover - jit
    """out = R [scale * J[:, col]]x: d exp(w) for dw = scale * e_col, left-multiplied by R."""
    H = np.empty((3, 3))
    _hat_into(scale * J[0, col], scale * J[1, col], scale * J[2, col], H)
    _mm(R, H, out)


@njit(cache=True)
def _frame(kind, Rm, tm, knots, u, scale, R, t, dR, dt):  # noqa: C901  (one numba pass for speed)  # pragma: no cover - jit
    """One frame's poses R [V, 3, 3], t [V, 3] at the instants u [V] and their tangents dR
    [P, V, 3, 3], dt [P, V, 3] (written; zero where a coordinate does not move them). False when a
    logarithm is near pi."""
    V = u.shape[0]
    P = dR.shape[0]
    for p in range(P):
        for v in range(V):
            for i in range(3):
                dt[p, v, i] = 0.0
                for j in range(3):
                    dR[p, v, i, j] = 0.0
    E = np.empty((3, 3))
    J = np.empty((3, 3))
    if kind == 2:  # offset: one pose at every instant
        _exp_jr(knots[0, 0], knots[0, 1], knots[0, 2], E, J)
        for v in range(V):
            _mm(Rm, E, R[v])
            for i in range(3):
                t[v, i] = tm[i] + scale * knots[0, 3 + i]
                _rot_tangent(R[v], J, i, 1.0, dR[i, v])
                dt[3 + i, v, i] = scale
        return True
    if kind == 1:  # cubic B-spline in the tangent space at the mid pose
        xi = np.empty(6)
        B = np.empty(4)
        for v in range(V):
            uu = u[v]
            B[0] = (1 - uu) ** 3 / 6
            B[1] = (3 * uu**3 - 6 * uu**2 + 4) / 6
            B[2] = (-3 * uu**3 + 3 * uu**2 + 3 * uu + 1) / 6
            B[3] = uu**3 / 6
            for i in range(6):
                xi[i] = B[0] * knots[0, i] + B[1] * knots[1, i] + B[2] * knots[2, i] + B[3] * knots[3, i]
            _exp_jr(xi[0], xi[1], xi[2], E, J)
            _mm(Rm, E, R[v])
            for i in range(3):
                t[v, i] = tm[i] + scale * xi[3 + i]
            for k in range(4):
                for i in range(3):
                    _rot_tangent(R[v], J, i, B[k], dR[6 * k + i, v])
                    dt[6 * k + 3 + i, v, i] = scale * B[k]
        return True
    # linear: R0 exp(u log(R0^T R1)), (1 - u) t0 + u t1; only the rotation coordinates 0-2 (start)
    # and 6-8 (end) move the rotations
    E1 = np.empty((3, 3))
    J1 = np.empty((3, 3))
    R0 = np.empty((3, 3))
    R1 = np.empty((3, 3))
    _exp_jr(knots[0, 0], knots[0, 1], knots[0, 2], E, J)
    _exp_jr(knots[1, 0], knots[1, 1], knots[1, 2], E1, J1)
    _mm(Rm, E, R0)
    _mm(Rm, E1, R1)
    dR0 = np.zeros((12, 3, 3))
    dR1 = np.zeros((12, 3, 3))
    for i in range(3):
        _rot_tangent(R0, J, i, 1.0, dR0[i])
        _rot_tangent(R1, J1, i, 1.0, dR1[6 + i])
    Q = np.empty((3, 3))
    _mtm(R0, R1, Q)
    rel = np.empty(3)
    Jinv = np.empty((3, 3))
    if not _log_jinv(Q, rel, Jinv):
        return False
    drel = np.zeros((12, 3))
    dQ = np.empty((3, 3))
    M1 = np.empty((3, 3))
    M2 = np.empty((3, 3))
    for p in (0, 1, 2, 6, 7, 8):
        _mtm(dR0[p], R1, M1)  # dQ = dR0^T R1 + R0^T dR1
        _mtm(R0, dR1[p], M2)
        for i in range(3):
            for j in range(3):
                dQ[i, j] = M1[i, j] + M2[i, j]
        _mtm(Q, dQ, M1)  # Q^T dQ, skew: its vector
        a0 = 0.5 * (M1[2, 1] - M1[1, 2])
        a1 = 0.5 * (M1[0, 2] - M1[2, 0])
        a2 = 0.5 * (M1[1, 0] - M1[0, 1])
        for i in range(3):
            drel[p, i] = Jinv[i, 0] * a0 + Jinv[i, 1] * a1 + Jinv[i, 2] * a2
    Eu = np.empty((3, 3))
    Ju = np.empty((3, 3))
    dEu = np.empty((3, 3))
    for v in range(V):
        uu = u[v]
        _exp_jr(uu * rel[0], uu * rel[1], uu * rel[2], Eu, Ju)
        _mm(R0, Eu, R[v])
        for i in range(3):
            t[v, i] = tm[i] + scale * ((1 - uu) * knots[0, 3 + i] + uu * knots[1, 3 + i])
            dt[3 + i, v, i] = scale * (1 - uu)
            dt[9 + i, v, i] = scale * uu
        for p in (0, 1, 2, 6, 7, 8):
            g0 = uu * (Ju[0, 0] * drel[p, 0] + Ju[0, 1] * drel[p, 1] + Ju[0, 2] * drel[p, 2])
            g1 = uu * (Ju[1, 0] * drel[p, 0] + Ju[1, 1] * drel[p, 1] + Ju[1, 2] * drel[p, 2])
            g2 = uu * (Ju[2, 0] * drel[p, 0] + Ju[2, 1] * drel[p, 1] + Ju[2, 2] * drel[p, 2])
            _hat_into(g0, g1, g2, M2)
            _mm(Eu, M2, dEu)  # d exp(u rel) = exp(u rel) [Jr(u rel) u drel]x
            _mm(dR0[p], Eu, M1)
            _mm(R0, dEu, M2)
            for i in range(3):
                for j in range(3):
                    dR[p, v, i, j] = M1[i, j] + M2[i, j]
    return True


@njit(cache=True)
def _poses(kind, c2w_mid, knots, u, scale, anchored, c2w, dC):  # noqa: C901  (one numba pass)  # pragma: no cover - jit
    """c2w [B, V, 4, 4] and dC [B, P, V, 3, 4] written (see ``ebad.kernels.poses.poses_with_tangents``);
    False when a logarithm is near pi."""
    B = knots.shape[0]
    P = knots.shape[1] * 6
    V = u.shape[0]
    Va = V + 1 if anchored else V
    ua = np.empty(Va)
    for v in range(V):
        ua[v] = u[v]
    if anchored:
        ua[V] = 0.5
    R = np.empty((Va, 3, 3))
    t = np.empty((Va, 3))
    dR = np.empty((P, Va, 3, 3))
    dt = np.empty((P, Va, 3))
    Rm = np.empty((3, 3))
    tm = np.empty(3)
    RM = np.eye(3)  # the anchoring M = T_mid T(0.5)^-1 (the identity when not anchored)
    tM = np.zeros(3)
    dRM = np.empty((3, 3))
    dtM = np.empty(3)
    M1 = np.empty((3, 3))
    M2 = np.empty((3, 3))
    for b in range(B):
        for i in range(3):
            tm[i] = c2w_mid[b, i, 3]
            for j in range(3):
                Rm[i, j] = c2w_mid[b, i, j]
        if not _frame(kind, Rm, tm, knots[b], ua, scale, R, t, dR, dt):
            return False
        if anchored:  # R_M = R_m Rh^T, t_M = t_m - R_M th
            for i in range(3):
                for j in range(3):
                    RM[i, j] = Rm[i, 0] * R[V, j, 0] + Rm[i, 1] * R[V, j, 1] + Rm[i, 2] * R[V, j, 2]
            for i in range(3):
                tM[i] = tm[i] - (RM[i, 0] * t[V, 0] + RM[i, 1] * t[V, 1] + RM[i, 2] * t[V, 2])
        for v in range(V):  # T_out = M T(u)
            _mm(RM, R[v], M1)
            for i in range(3):
                for j in range(3):
                    c2w[b, v, i, j] = M1[i, j]
                c2w[b, v, i, 3] = RM[i, 0] * t[v, 0] + RM[i, 1] * t[v, 1] + RM[i, 2] * t[v, 2] + tM[i]
                c2w[b, v, 3, i] = 0.0
            c2w[b, v, 3, 3] = 1.0
        for p in range(P):
            for i in range(3):
                dtM[i] = 0.0
                for j in range(3):
                    dRM[i, j] = 0.0
            if anchored:  # dR_M = R_m dRh^T, dt_M = -dR_M th - R_M dth
                for i in range(3):
                    for j in range(3):
                        dRM[i, j] = Rm[i, 0] * dR[p, V, j, 0] + Rm[i, 1] * dR[p, V, j, 1] + Rm[i, 2] * dR[p, V, j, 2]
                for i in range(3):
                    dtM[i] = -(dRM[i, 0] * t[V, 0] + dRM[i, 1] * t[V, 1] + dRM[i, 2] * t[V, 2]) - (
                        RM[i, 0] * dt[p, V, 0] + RM[i, 1] * dt[p, V, 1] + RM[i, 2] * dt[p, V, 2]
                    )
            for v in range(V):  # dT_out = dM T(u) + M dT(u)
                _mm(dRM, R[v], M1)
                _mm(RM, dR[p, v], M2)
                for i in range(3):
                    for j in range(3):
                        dC[b, p, v, i, j] = M1[i, j] + M2[i, j]
                    dC[b, p, v, i, 3] = (
                        dRM[i, 0] * t[v, 0]
                        + dRM[i, 1] * t[v, 1]
                        + dRM[i, 2] * t[v, 2]
                        + RM[i, 0] * dt[p, v, 0]
                        + RM[i, 1] * dt[p, v, 1]
                        + RM[i, 2] * dt[p, v, 2]
                        + dtM[i]
                    )
    return True
