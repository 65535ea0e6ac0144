"""The exposure trajectories' poses in closed form, with their derivatives carried forward.

``ebad.trajectory``'s pose functions are torch compositions of a few dozen small operations
(``so3_exp`` through ``matrix_exp``, ``so3_log``, products, the anchoring); at a training step's
sizes (one frame, six instants) each costs a few microseconds forward and more backward, and an
anchored linear trajectory took 1.4 ms a step, forward and backward. Here the same poses come
from one numba function in float64, and with them their derivatives with respect to every knot
(forward mode: each quantity carries its tangents along the P = K x 6 knot coordinates). The
backward is then one contraction of those tangents with the upstream gradient
(``TrajectoryPoses``). The torch functions stay the reference (tests compare both).

Rotations use the closed forms of SO(3) (Barfoot, "State Estimation for Robotics", 7.1):
exp(w) = I + a W + b W^2 and its right Jacobian Jr(w) = I - b W + c W^2 (W = [w]x, a = sin t / t,
b = (1 - cos t) / t^2, c = (t - sin t) / t^3, t = |w|), so d exp(w) = exp(w) [Jr(w) dw]x; the
logarithm as ``ebad.lie.so3_log`` and d log(R) = Jr^-1(w) vee(R^T dR), Jr^-1(w) = I + W / 2 +
e W^2, e = (1 - (t / 2) cot(t / 2)) / t^2. Series replace the ratios near t = 0. A logarithm
within ``NEAR_PI_COS`` of pi is refused (``NearPi``): the caller takes the torch path, as
``so3_log`` takes kornia's there.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit
from torch import Tensor

__all__ = ["TrajectoryPoses", "NearPi", "poses_with_tangents", "fast_poses_available", "KINDS"]

#: below this cos(angle) a logarithm is refused (``ebad.lie._NEAR_PI_COS``: there vee(R - R^T) loses its digits)
NEAR_PI_COS = -0.9
_SMALL_EXP = 1e-4  # t^2 below which exp's and Jr's ratios come from their series (error ~ t^6 / 5040)
_SMALL_INV = 1e-2  # t^2 below which Jr^-1's ratio comes from its series (error ~ t^8 / 4.8e7)
_SMALL_LOG = 1e-10  # sin(t)^2 below which t / sin(t) comes from its series
#: the trajectory kinds with a closed form, and their number of knots (``ebad.trajectory.TRAJECTORIES``)
KINDS = {"linear": 2, "cubic": 4, "offset": 1}
_KIND_ID = {"linear": 0, "cubic": 1, "offset": 2}


class NearPi(ValueError):
    """A rotation whose logarithm is wanted is within ``NEAR_PI_COS`` of pi."""


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
    _hat_into(w0, w1, w2, W)
    W2 = W @ W
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
    _hat_into(w[0], w[1], w[2], W)
    W2 = W @ W
    for i in range(3):
        for j in range(3):
            Jinv[i, j] = (1.0 if i == j else 0.0) + 0.5 * W[i, j] + e * W2[i, j]
    return True


@njit(cache=True)
def _rot_tangent(R, J, col, scale, out):  # pragma: no cover - jit
    """out = R [scale * J[:, col]]x: d exp(w) for dw = scale * e_col, left-multiplied by R."""
    H = np.empty((3, 3))
    _hat_into(scale * J[0, col], scale * J[1, col], scale * J[2, col], H)
    out[:, :] = R @ H


@njit(cache=True)
def _vee_skew(M):  # pragma: no cover - jit
    return 0.5 * (M[2, 1] - M[1, 2]), 0.5 * (M[0, 2] - M[2, 0]), 0.5 * (M[1, 0] - M[0, 1])


@njit(cache=True)
def _frame(kind, Rm, tm, knots, u, scale, R, t, dR, dt):  # pragma: no cover - jit
    """One frame's poses R [V, 3, 3], t [V, 3] at the instants u [V] and their tangents dR
    [P, V, 3, 3], dt [P, V, 3] (written; zero where a coordinate does not move them). False when a
    logarithm is near pi."""
    V = u.shape[0]
    dR[:] = 0.0
    dt[:] = 0.0
    E = np.empty((3, 3))
    J = np.empty((3, 3))
    if kind == 2:  # offset: one pose at every instant
        _exp_jr(knots[0, 0], knots[0, 1], knots[0, 2], E, J)
        R0 = Rm @ E
        for v in range(V):
            R[v] = R0
            for i in range(3):
                t[v, i] = tm[i] + scale * knots[0, 3 + i]
                _rot_tangent(R0, J, i, 1.0, dR[i, v])
                dt[3 + i, v, i] = scale
        return True
    if kind == 1:  # cubic B-spline in the tangent space at the mid pose
        for v in range(V):
            uu = u[v]
            u2 = uu * uu
            u3 = u2 * uu
            B = ((1 - uu) ** 3 / 6, (3 * u3 - 6 * u2 + 4) / 6, (-3 * u3 + 3 * u2 + 3 * uu + 1) / 6, u3 / 6)
            xi = np.zeros(6)
            for k in range(4):
                for i in range(6):
                    xi[i] += B[k] * knots[k, i]
            _exp_jr(xi[0], xi[1], xi[2], E, J)
            R[v] = Rm @ E
            for i in range(3):
                t[v, i] = tm[i] + scale * xi[3 + i]
            for k in range(4):
                for i in range(3):
                    _rot_tangent(R[v], J, i, B[k], dR[6 * k + i, v])
                    dt[6 * k + 3 + i, v, i] = scale * B[k]
        return True
    # linear: R0 exp(u log(R0^T R1)), (1 - u) t0 + u t1
    E1 = np.empty((3, 3))
    J1 = np.empty((3, 3))
    _exp_jr(knots[0, 0], knots[0, 1], knots[0, 2], E, J)
    _exp_jr(knots[1, 0], knots[1, 1], knots[1, 2], E1, J1)
    R0 = Rm @ E
    R1 = Rm @ E1
    dR0 = np.zeros((12, 3, 3))
    dR1 = np.zeros((12, 3, 3))
    for i in range(3):
        _rot_tangent(R0, J, i, 1.0, dR0[i])
        _rot_tangent(R1, J1, i, 1.0, dR1[6 + i])
    Q = R0.T @ R1
    rel = np.empty(3)
    Jinv = np.empty((3, 3))
    if not _log_jinv(Q, rel, Jinv):
        return False
    drel = np.zeros((12, 3))
    for p in (0, 1, 2, 6, 7, 8):
        dQ = dR0[p].T @ R1 + R0.T @ dR1[p]
        a0, a1, a2 = _vee_skew(Q.T @ dQ)
        for i in range(3):
            drel[p, i] = Jinv[i, 0] * a0 + Jinv[i, 1] * a1 + Jinv[i, 2] * a2
    Eu = np.empty((3, 3))
    Ju = np.empty((3, 3))
    dEu = np.empty((3, 3))
    H = np.empty((3, 3))
    for v in range(V):
        uu = u[v]
        _exp_jr(uu * rel[0], uu * rel[1], uu * rel[2], Eu, Ju)
        R[v] = R0 @ Eu
        for i in range(3):
            t[v, i] = tm[i] + scale * ((1 - uu) * knots[0, 3 + i] + uu * knots[1, 3 + i])
            dt[3 + i, v, i] = scale * (1 - uu)
            dt[9 + i, v, i] = scale * uu
        for p in (0, 1, 2, 6, 7, 8):
            g = Ju @ (uu * drel[p])
            _hat_into(g[0], g[1], g[2], H)
            dEu[:, :] = Eu @ H
            dR[p, v] = dR0[p] @ Eu + R0 @ dEu
    return True


@njit(cache=True)
def _poses(kind, c2w_mid, knots, u, scale, anchored, c2w, dC):  # pragma: no cover - jit
    """c2w [B, V, 4, 4] and dC [B, P, V, 3, 4] written (see ``poses_with_tangents``); False when a
    logarithm is near pi."""
    B = knots.shape[0]
    P = knots.shape[1] * 6
    V = u.shape[0]
    Va = V + 1 if anchored else V
    ua = np.empty(Va)
    ua[:V] = u
    if anchored:
        ua[V] = 0.5
    R = np.empty((Va, 3, 3))
    t = np.empty((Va, 3))
    dR = np.empty((P, Va, 3, 3))
    dt = np.empty((P, Va, 3))
    for b in range(B):
        Rm = np.ascontiguousarray(c2w_mid[b, :3, :3])
        tm = c2w_mid[b, :3, 3].copy()
        if not _frame(kind, Rm, tm, knots[b], ua, scale, R, t, dR, dt):
            return False
        for v in range(V):
            c2w[b, v] = 0.0
            c2w[b, v, 3, 3] = 1.0
        if anchored:  # left-multiply by M = T_mid T(0.5)^-1: R_M = R_m Rh^T, t_M = t_m - R_M th
            RM = Rm @ np.ascontiguousarray(R[V].T)
            tM = tm - RM @ t[V]
            for v in range(V):
                c2w[b, v, :3, :3] = RM @ R[v]
                c2w[b, v, :3, 3] = RM @ t[v] + tM
            for p in range(P):
                dRM = Rm @ np.ascontiguousarray(dR[p, V].T)
                dtM = -(dRM @ t[V]) - RM @ dt[p, V]
                for v in range(V):
                    dC[b, p, v, :, :3] = dRM @ R[v] + RM @ dR[p, v]
                    dC[b, p, v, :, 3] = dRM @ t[v] + RM @ dt[p, v] + dtM
        else:
            for v in range(V):
                c2w[b, v, :3, :3] = R[v]
                c2w[b, v, :3, 3] = t[v]
                for p in range(P):
                    dC[b, p, v, :, :3] = dR[p, v]
                    dC[b, p, v, :, 3] = dt[p, v]
    return True


def poses_with_tangents(kind: str, c2w_mid: np.ndarray, knots: np.ndarray, u: np.ndarray, scale: float,
                        anchored: bool) -> tuple[np.ndarray, np.ndarray]:
    """c2w [B, V, 4, 4] of a trajectory kind with knots (``ebad.trajectory``'s ``linear``, ``cubic``,
    ``offset`` on c2w_mid [B, 4, 4], knots [B, K, 6], u [V]), anchored or not, and its tangents
    along every knot coordinate: dC [B, P, V, 3, 4] (the top three rows), P = K x 6 in the knots'
    [K, 6] order. float64 throughout; raises ``NearPi`` (see the module docstring)."""
    B, K, _ = knots.shape
    V = len(u)
    c2w = np.empty((B, V, 4, 4))
    dC = np.empty((B, 6 * K, V, 3, 4))
    if not _poses(_KIND_ID[kind], np.ascontiguousarray(c2w_mid, np.float64), np.ascontiguousarray(knots, np.float64),
                  np.ascontiguousarray(u, np.float64), float(scale), bool(anchored), c2w, dC):
        raise NearPi("a rotation whose logarithm a linear trajectory needs is near pi")
    return c2w, dC


class TrajectoryPoses(torch.autograd.Function):
    """c2w [B, V, 4, 4] from knots [B, K, 6] (``poses_with_tangents``), the gradient of the knots
    by one contraction of the tangents with the upstream gradient."""

    @staticmethod
    def forward(ctx, knots: Tensor, c2w_mid: Tensor, u: Tensor, kind: str, scale: float, anchored: bool) -> Tensor:
        c2w, dC = poses_with_tangents(kind, c2w_mid.detach().numpy(), knots.detach().numpy(), u.detach().numpy(),
                                      scale, anchored)
        ctx.dC, ctx.knot_shape = dC, knots.shape
        return torch.from_numpy(c2w).to(knots.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):  # [B, V, 4, 4]
        G = grad.detach().numpy()[..., :3, :].astype(np.float64)
        gk = np.einsum("bpvij,bvij->bp", ctx.dC, G).reshape(ctx.knot_shape)
        return torch.from_numpy(gk).to(grad.dtype), None, None, None, None, None


def fast_poses_available(kind: str) -> bool:
    """Whether ``poses_with_tangents`` has the kind (``fixed`` needs no derivative at all)."""
    return kind in KINDS
