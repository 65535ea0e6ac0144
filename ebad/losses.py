"""Losses of EBAD-Gaussian as pure functions over image tensors.

Convention: images are [B, H, W, D] (or [H, W, D]) linear intensity; events enter as signed
per-pixel sums ``E`` [P, H, W] between consecutive virtual instants; ``c`` is the contrast
threshold in natural-log units; log intensities are ``log(I + eps)`` with ``eps = edi.LOG_EPS``.
"""
from __future__ import annotations

import typing

import numpy as np
import torch
from torch import Tensor
from kornia.metrics import ssim as _kornia_ssim

from edi import LOG_EPS

from .config import EventNorm  # the norm of the L_ev residual: l1, mean |r| (ebad's default), or l2, mean r^2 (the paper's)

__all__ = ["luminance", "ssim_map", "ssim_map_kornia", "l1_ssim", "blur_loss", "event_loss", "edi_loss",
           "LUMA"]

LUMA = (1 / 3, 1 / 3, 1 / 3)  # the intensity a colour event pixel sees: the channel mean, as scenes.simulate_events


def _bhwd(x: Tensor, name: str) -> Tensor:
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4:
        raise ValueError(f"{name} must be [H, W, D] or [B, H, W, D], got {tuple(x.shape)}")
    return x


def luminance(img: Tensor) -> Tensor:  # [..., D] -> [..., 1]
    """Grey images pass through; colour ones become the channel mean (``LUMA``)."""
    D = img.shape[-1]
    if D == 1:
        return img
    if D != 3:
        raise ValueError(f"luminance needs D = 1 or 3 channels, got {D}")
    w = torch.tensor(LUMA, dtype=img.dtype, device=img.device)
    return (img * w).sum(-1, keepdim=True)


def _window_for(h: int, w: int, window: int) -> int:
    win = int(window)
    limit = 2 * min(h, w) - 1  # reflect padding needs H, W > window // 2
    if win > limit:
        win = max(1, limit if limit % 2 else limit - 1)
    return win


class _FusedSSIM(torch.autograd.Function):
    """The SSIM map of two padded image stacks [N, H + 2p, W + 2p] (``ebad._ssim_kernels``)."""

    @staticmethod
    def forward(ctx, ap: Tensor, bp: Tensor, win: int) -> Tensor:
        from . import _ssim_kernels as K

        A, B = ap.detach().contiguous().numpy(), bp.detach().contiguous().numpy()
        g = K.gauss_taps(win).astype(A.dtype)
        N, H, W = A.shape[0], A.shape[1] - win + 1, A.shape[2] - win + 1
        want = ctx.needs_input_grad[0] or ctx.needs_input_grad[1]
        s = np.empty((N, H, W), A.dtype)
        coef = np.empty((4, N, H, W) if want else (4, 0, 0, 0), A.dtype)
        K.ssim_forward(A, B, g, s, coef, want)
        ctx.save_for_backward(ap, bp)
        ctx.coef, ctx.g = coef, g
        return torch.from_numpy(s)

    @staticmethod
    def backward(ctx, grad_s: Tensor):
        from . import _ssim_kernels as K

        ap, bp = ctx.saved_tensors
        want_a, want_b = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        A, B = ap.detach().contiguous().numpy(), bp.detach().contiguous().numpy()
        ga = np.empty_like(A) if want_a else np.empty((0, 0, 0), A.dtype)
        gb = np.empty_like(B) if want_b else np.empty((0, 0, 0), A.dtype)
        K.ssim_backward(A, B, ctx.g, ctx.coef, grad_s.detach().to(ap.dtype).contiguous().numpy(), ga, gb,
                        want_a, want_b)
        return (torch.from_numpy(ga) if want_a else None), (torch.from_numpy(gb) if want_b else None), None


def ssim_map(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """SSIM map with kornia's conventions (Gaussian window, sigma 1.5, reflect padding,
    c1 = 0.01^2, c2 = 0.03^2, eps 1e-12), in two fused passes over the separable window
    (``ebad._ssim_kernels``) with their adjoint as the backward; gradients reach ``a`` and ``b``.

    ``ssim_map_kornia`` is the reference it is tested against. float32 and float64 inputs are
    computed in their own precision; other dtypes in float32."""
    a = _bhwd(a, "a")
    b = _bhwd(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"a {tuple(a.shape)} and b {tuple(b.shape)} differ in shape")
    dtype = a.dtype if a.dtype in (torch.float32, torch.float64) else torch.float32
    Bn, H, W, D = a.shape
    win = _window_for(H, W, window)
    pad = win // 2

    def stack(x: Tensor) -> Tensor:  # [B, H, W, D] -> reflect-padded [B*D, H + 2p, W + 2p]
        x = x.to(dtype).permute(0, 3, 1, 2).reshape(Bn * D, 1, H, W)
        return torch.nn.functional.pad(x, (pad, pad, pad, pad), mode="reflect")[:, 0]

    s = _FusedSSIM.apply(stack(a), stack(b), win)  # [B*D, H, W]
    return s.reshape(Bn, D, H, W).permute(0, 2, 3, 1)


def ssim_map_kornia(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """The reference: kornia.metrics.ssim in [B, H, W, D] layout."""
    a = _bhwd(a, "a").permute(0, 3, 1, 2)
    b = _bhwd(b, "b").permute(0, 3, 1, 2)
    win = _window_for(a.shape[-2], a.shape[-1], window)
    return _kornia_ssim(a, b, win).permute(0, 2, 3, 1)


def l1_ssim(pred: Tensor, target: Tensor, ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """(1 - w) L1 + w (1 - SSIM), averaged over everything; [B,H,W,D] or [H,W,D] inputs."""
    pred = _bhwd(pred, "pred")
    target = _bhwd(target, "target")
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    l1 = (pred - target).abs().mean()
    if ssim_weight == 0:
        return l1
    return (1 - ssim_weight) * l1 + ssim_weight * (1 - ssim_map(pred, target, window).mean())


def blur_loss(renders: Tensor,  # [V, H, W, D]
              blurry: Tensor,  # [H, W, D]
              ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """L_blur: the mean of the V virtual renders against the blurry frame."""
    if renders.ndim != 4:
        raise ValueError(f"renders must be [V, H, W, D], got {tuple(renders.shape)}")
    return l1_ssim(renders.mean(0), blurry, ssim_weight, window)


def event_loss(renders: Tensor,  # [V, H, W, D]
               counts: Tensor,  # [V - 1, 2, H, W] ON and OFF event counts
               c: float | tuple[float, float] | Tensor, eps: float | None = None,
               norm: EventNorm = "l1") -> Tensor:
    """L_ev: the mean over pixels and consecutive instants of |r| (``norm="l1"``) or r^2 (``"l2"``),
    r = log L(t_{k+1}) - log L(t_k) - (c_pos N_on,k - c_neg N_off,k).

    ``L`` is the render's luminance (the render itself when grey); ``c`` one threshold or the pair
    (c_pos, c_neg) (a float, a 2-tuple, or a tensor of one or two values, differentiable).
    L1 is ebad's default (robust to noise events), L2 the paper's; one window (t_i, t_j) is
    ``event_loss(renders[[i, j]], virtual_views.window_counts(counts, i, j), c)``.
    """
    if norm not in typing.get_args(EventNorm):
        raise ValueError(f"norm must be one of {typing.get_args(EventNorm)}, got {norm!r}")
    V = renders.shape[0]
    if counts.shape != (V - 1, 2) + tuple(renders.shape[1:3]):
        raise ValueError(f"counts must be [V - 1, 2, H, W] = {(V - 1, 2) + tuple(renders.shape[1:3])}, "
                         f"got {tuple(counts.shape)}")
    if V < 2:
        return renders.sum() * 0.0
    eps = LOG_EPS if eps is None else eps
    logL = torch.log(luminance(renders)[..., 0].clamp_min(0) + eps)  # [V, H, W]
    diff = logL[1:] - logL[:-1]
    cc = torch.as_tensor(c, dtype=diff.dtype).reshape(-1)
    c_pos, c_neg = cc[0], cc[-1]
    counts = counts.to(diff.dtype)
    r = diff - (c_pos * counts[:, 0] - c_neg * counts[:, 1])
    return r.abs().mean() if norm == "l1" else r.square().mean()


def edi_loss(renders: Tensor,  # [H, W, D] or [V, H, W, D]
             latents: Tensor,  # the same shape
             ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """L_EDI: renders against the EDI latents of the frame at the same instants (the mid-exposure
    render and latent, or every virtual view's), averaged over them."""
    return l1_ssim(renders, latents, ssim_weight, window)
