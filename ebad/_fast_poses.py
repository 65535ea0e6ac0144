"""The exposure trajectories' poses in closed form, with their derivatives carried forward.

``ebad.trajectory``'s pose functions are torch compositions of a few dozen small operations
(``so3_exp`` through ``matrix_exp``, ``so3_log``, products, the anchoring); at a training step's
sizes (one frame, six instants) each costs a few microseconds forward and more backward, and an
anchored linear trajectory took 1.4 ms a step, forward and backward. Here the same poses come
from numpy in float64, and with them their derivatives with respect to every knot (forward-mode:
each quantity carries its tangents along the P = K x 6 knot coordinates, a few dozen). The
backward is then one contraction of those tangents with the upstream gradient
(``TrajectoryPoses``).

Rotations use the closed forms of SO(3) (Barfoot, "State Estimation for Robotics", 7.1):
exp(w) = I + a W + b W^2 and its right Jacobian Jr(w) = I - b W + c W^2 (W = [w]x, a = sin t / t,
b = (1 - cos t) / t^2, c = (t - sin t) / t^3, t = |w|), so d exp(w) = exp(w) [Jr(w) dw]x; the
logarithm as ``ebad.lie.so3_log`` and d log(R) = Jr^-1(w) vee(R^T dR), Jr^-1(w) = I + W / 2 +
e W^2, e = (1 - (t / 2) cot(t / 2)) / t^2. Series replace the ratios near t = 0. Rotations whose
logarithm is needed within ``NEAR_PI_COS`` of pi are refused (``NearPi``): the caller takes the
torch path, as ``so3_log`` takes kornia's there.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = ["TrajectoryPoses", "NearPi", "poses_with_tangents", "fast_poses_available", "so3_exp", "so3_log"]

#: below this cos(angle) a logarithm is refused (``ebad.lie._NEAR_PI_COS``: there vee(R - R^T) loses its digits)
NEAR_PI_COS = -0.9
_SMALL_EXP = 1e-4  # t^2 below which exp's and Jr's ratios come from their series (error ~ t^6 / 5040)
_SMALL_INV = 1e-2  # t^2 below which Jr^-1's ratio comes from its series (error ~ t^8 / 4.8e7)
_SMALL_LOG = 1e-10  # sin(t)^2 below which t / sin(t) comes from its series


class NearPi(ValueError):
    """A rotation whose logarithm is wanted is within ``NEAR_PI_COS`` of pi."""


def _hat(w: np.ndarray) -> np.ndarray:  # [..., 3] -> [..., 3, 3] the skew matrix [w]x
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def _vee(M: np.ndarray) -> np.ndarray:  # [..., 3, 3] -> [..., 3] the vector of M's skew part
    return 0.5 * np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)


def _exp_ratios(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # [...] each: a, b, c
    t2 = (w * w).sum(-1)
    small = t2 < _SMALL_EXP
    t2s = np.where(small, 1.0, t2)
    t = np.sqrt(t2s)
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / t2s)
    c = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / (t2s * t))
    return a, b, c


def so3_exp(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [..., 3] -> R [..., 3, 3], Jr [..., 3, 3]
    """Rotation matrices and right Jacobians of rotation vectors (float64)."""
    a, b, c = _exp_ratios(w)
    W = _hat(w)
    W2 = W @ W
    eye = np.eye(3)
    return (eye + a[..., None, None] * W + b[..., None, None] * W2,
            eye - b[..., None, None] * W + c[..., None, None] * W2)


def so3_log(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [..., 3, 3] -> w [..., 3], Jr^-1(w) [..., 3, 3]
    """Rotation vectors and inverse right Jacobians of rotations (float64), angles below pi;
    raises ``NearPi`` within ``NEAR_PI_COS`` of pi."""
    v = _vee(R)
    cos = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1)
    if bool((cos < NEAR_PI_COS).any()):
        raise NearPi("a rotation is near pi")
    s2 = (v * v).sum(-1)
    small = s2 < _SMALL_LOG
    s = np.sqrt(np.where(small, 1.0, s2))
    w = v * np.where(small, 1 + s2 / 6 + 3 * s2 * s2 / 40, np.arctan2(s, cos) / s)[..., None]
    t2 = (w * w).sum(-1)
    near = t2 < _SMALL_INV
    t = np.sqrt(np.where(near, 1.0, t2))
    e = np.where(near, 1 / 12 + t2 / 720 + t2 * t2 / 30240 + t2 ** 3 / 1209600,
                 (1 - 0.5 * t / np.tan(0.5 * t)) / np.where(near, 1.0, t2))
    W = _hat(w)
    return w, np.eye(3) + 0.5 * W + e[..., None, None] * (W @ W)


def _rot_tangent(R: np.ndarray, J: np.ndarray, dw: np.ndarray) -> np.ndarray:
    """d(exp(w)) = exp(w) [Jr(w) dw]x for tangents dw [B, P, ..., 3] of w [B, ..., 3] -> [B, P, ..., 3, 3]."""
    return R[:, None] @ _hat((J[:, None] @ dw[..., None])[..., 0])


def _linear(Rm, tm, knots, u, scale):
    """R [B, V, 3, 3], t [B, V, 3] and their tangents [B, P, V, ...] of ``linear_poses``."""
    B, K, _ = knots.shape
    P = 6 * K
    basis = np.eye(P).reshape(P, K, 6)  # tangent p moves knot coordinate p
    E, Jr = so3_exp(knots[:, :, :3])  # [B, 2, 3, 3]
    R01 = Rm[:, None] @ E  # start and end rotations
    dR01 = _rot_tangent(R01, Jr, np.broadcast_to(basis[None, :, :, :3], (B, P, K, 3)))  # [B, P, 2, 3, 3]
    t01 = tm[:, None] + scale * knots[:, :, 3:]
    dt01 = np.broadcast_to(scale * basis[None, :, :, 3:], (B, P, K, 3))
    R0, R1, dR0, dR1 = R01[:, 0], R01[:, 1], dR01[:, :, 0], dR01[:, :, 1]
    Q = R0.swapaxes(-1, -2) @ R1
    dQ = dR0.swapaxes(-1, -2) @ R1[:, None] + R0.swapaxes(-1, -2)[:, None] @ dR1
    rel, Jinv = so3_log(Q)  # [B, 3]
    drel = (Jinv[:, None] @ _vee(Q.swapaxes(-1, -2)[:, None] @ dQ)[..., None])[..., 0]  # [B, P, 3]
    a = u[None, :, None] * rel[:, None]  # [B, V, 3]
    Eu, Ju = so3_exp(a)
    dEu = _rot_tangent(Eu, Ju, u[None, None, :, None] * drel[:, :, None])  # [B, P, V, 3, 3]
    R = R0[:, None] @ Eu
    dR = dR0[:, :, None] @ Eu[:, None] + R0[:, None, None] @ dEu
    uu = u[None, :, None]
    t = (1 - uu) * t01[:, 0, None] + uu * t01[:, 1, None]
    dt = (1 - uu[:, None]) * dt01[:, :, 0, None] + uu[:, None] * dt01[:, :, 1, None]
    return R, t, dR, dt


def _bspline(u: np.ndarray) -> np.ndarray:  # [V] -> [V, 4], as ``trajectory.bspline_weights``
    u2, u3 = u * u, u * u * u
    return np.stack([(1 - u) ** 3 / 6, (3 * u3 - 6 * u2 + 4) / 6, (-3 * u3 + 3 * u2 + 3 * u + 1) / 6, u3 / 6], -1)


def _cubic(Rm, tm, knots, u, scale):
    """``cubic_poses`` and tangents (see ``_linear``)."""
    B, K, _ = knots.shape
    P = 6 * K
    Bw = _bspline(u)  # [V, 4]
    xi = Bw @ knots  # [B, V, 6]
    dxi = np.zeros((P, len(u), 6))  # coordinate i of knot k moves xi[:, i] by B[:, k]
    for k in range(K):
        for i in range(6):
            dxi[6 * k + i, :, i] = Bw[:, k]
    E, Jr = so3_exp(xi[..., :3])
    R = Rm[:, None] @ E
    dR = _rot_tangent(R, Jr, np.broadcast_to(dxi[None, ..., :3], (B, P, len(u), 3)))
    t = tm[:, None] + scale * xi[..., 3:]
    dt = np.broadcast_to(scale * dxi[None, ..., 3:], (B, P, len(u), 3))
    return R, t, dR, dt


def _offset(Rm, tm, knots, u, scale):
    """``offset_poses`` and tangents (see ``_linear``)."""
    B = knots.shape[0]
    V = len(u)
    basis = np.eye(6)
    E, Jr = so3_exp(knots[:, 0, :3])
    R = Rm @ E  # [B, 3, 3]
    dR = _rot_tangent(R, Jr, np.broadcast_to(basis[None, :, :3], (B, 6, 3)))  # [B, 6, 3, 3]
    t = tm + scale * knots[:, 0, 3:]
    dt = np.broadcast_to(scale * basis[None, :, 3:], (B, 6, 3))
    return (np.broadcast_to(R[:, None], (B, V, 3, 3)), np.broadcast_to(t[:, None], (B, V, 3)),
            np.broadcast_to(dR[:, :, None], (B, 6, V, 3, 3)), np.broadcast_to(dt[:, :, None], (B, 6, V, 3)))


_KINDS = {"linear": _linear, "cubic": _cubic, "offset": _offset}


def poses_with_tangents(kind: str, c2w_mid: np.ndarray, knots: np.ndarray, u: np.ndarray, scale: float,
                        anchored: bool) -> tuple[np.ndarray, np.ndarray]:
    """c2w [B, V, 4, 4] of a trajectory kind with knots (``ebad.trajectory``'s ``linear``, ``cubic``,
    ``offset``), anchored or not, and its tangents along every knot coordinate: dC [B, P, V, 3, 4]
    (the top three rows), P = K x 6 in the knots' [K, 6] order. float64 throughout; raises
    ``NearPi`` (see the module docstring)."""
    Rm, tm = c2w_mid[:, :3, :3], c2w_mid[:, :3, 3]
    V = len(u)
    if anchored:
        u = np.append(u, 0.5)
    R, t, dR, dt = _KINDS[kind](Rm, tm, knots, u, scale)
    if anchored:  # left-multiply by M = T_mid T(0.5)^-1: R_M = R_m Rh^T, t_M = t_m - R_M th
        Rh, th, dRh, dth = R[:, V], t[:, V], dR[:, :, V], dt[:, :, V]
        R, t, dR, dt = R[:, :V], t[:, :V], dR[:, :, :V], dt[:, :, :V]
        RM = Rm @ Rh.swapaxes(-1, -2)  # [B, 3, 3]
        dRM = Rm[:, None] @ dRh.swapaxes(-1, -2)  # [B, P, 3, 3]
        tM = tm - (RM @ th[..., None])[..., 0]
        dtM = -(dRM @ th[:, None, :, None])[..., 0] - (RM[:, None] @ dth[..., None])[..., 0]
        dR = dRM[:, :, None] @ R[:, None] + RM[:, None, None] @ dR
        dt = ((dRM[:, :, None] @ t[:, None, ..., None])[..., 0] + (RM[:, None, None] @ dt[..., None])[..., 0]
              + dtM[:, :, None])
        R = RM[:, None] @ R
        t = (RM[:, None] @ t[..., None])[..., 0] + tM[:, None]
    B = R.shape[0]
    c2w = np.zeros((B, V, 4, 4))
    c2w[..., :3, :3], c2w[..., :3, 3], c2w[..., 3, 3] = R, t, 1.0
    dC = np.empty(dR.shape[:3] + (3, 4))
    dC[..., :3], dC[..., 3] = dR, dt
    return c2w, dC


class TrajectoryPoses(torch.autograd.Function):
    """c2w [B, V, 4, 4] from knots [B, K, 6] (``poses_with_tangents``), the gradient of the knots
    by one contraction of the tangents with the upstream gradient."""

    @staticmethod
    def forward(ctx, knots: Tensor, c2w_mid: Tensor, u: Tensor, kind: str, scale: float, anchored: bool) -> Tensor:
        c2w, dC = poses_with_tangents(kind, c2w_mid.detach().double().numpy(), knots.detach().double().numpy(),
                                      u.detach().double().numpy(), scale, anchored)
        ctx.dC, ctx.knot_shape = dC, knots.shape
        return torch.from_numpy(c2w).to(knots.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):  # [B, V, 4, 4]
        G = grad.detach().double().numpy()[..., :3, :]
        B, P = ctx.dC.shape[:2]
        gk = np.einsum("bpvij,bvij->bp", ctx.dC, G).reshape(ctx.knot_shape)
        return torch.from_numpy(gk).to(grad.dtype), None, None, None, None, None


def fast_poses_available(kind: str) -> bool:
    """Whether ``poses_with_tangents`` has the kind (``fixed`` needs no derivative at all)."""
    return kind in _KINDS

