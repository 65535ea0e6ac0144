"""Losses of EBAD-Gaussian as pure functions over image tensors.

Convention: images are [B, H, W, D] (or [H, W, D]) linear intensity; events enter as signed
per-pixel sums ``E`` [P, H, W] between consecutive virtual instants; ``c`` is the contrast
threshold in natural-log units; log intensities are ``log(I + eps)`` with ``eps = edi.LOG_EPS``.
"""
from __future__ import annotations

import typing

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


def _gauss_window(win: int, dtype, device, sigma: float = 1.5) -> Tensor:  # -> [win, win]
    x = torch.arange(win, dtype=dtype, device=device) - (win - 1) / 2
    g = torch.exp(-(x * x) / (2 * sigma * sigma))
    g = g / g.sum()
    return g[:, None] * g[None, :]


def _window_for(h: int, w: int, window: int) -> int:
    win = int(window)
    limit = 2 * min(h, w) - 1  # reflect padding needs H, W > window // 2
    if win > limit:
        win = max(1, limit if limit % 2 else limit - 1)
    return win


def ssim_map(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """SSIM map with kornia's conventions (Gaussian window, sigma 1.5, reflect padding,
    c1 = 0.01^2, c2 = 0.03^2, eps 1e-12) in one grouped convolution of the five moments.

    ``ssim_map_kornia`` is the reference it is tested against (same values, ~5x slower here)."""
    a = _bhwd(a, "a").permute(0, 3, 1, 2)
    b = _bhwd(b, "b").permute(0, 3, 1, 2)
    B, D, H, W = a.shape
    win = _window_for(H, W, window)
    k = _gauss_window(win, a.dtype, a.device)
    x = torch.cat([a, b, a * a, b * b, a * b], 1)  # [B, 5D, H, W]
    pad = win // 2
    x = torch.nn.functional.pad(x, (pad, pad, pad, pad), mode="reflect")
    m = torch.nn.functional.conv2d(x, k.expand(5 * D, 1, win, win), groups=5 * D)
    mu1, mu2, s11, s22, s12 = m.split(D, 1)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    mu11, mu22, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    num = (2 * mu12 + c1) * (2 * (s12 - mu12) + c2)
    den = (mu11 + mu22 + c1) * ((s11 - mu11) + (s22 - mu22) + c2)
    return (num / (den + 1e-12)).permute(0, 2, 3, 1)


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
