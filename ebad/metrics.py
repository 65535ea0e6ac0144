"""Image quality metrics for evaluation (numpy or torch in, floats out)."""

from __future__ import annotations

import numpy as np
import torch

from .losses import ssim_map

__all__ = ["psnr", "ssim"]


def _t(x) -> torch.Tensor:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(np.ascontiguousarray(x))
    return x.detach().float()


def psnr(pred, target) -> float:
    """PSNR in dB for images in [0, 1] ([H, W, D] or [B, H, W, D]); capped at 100 dB."""
    p, t = _t(pred), _t(target)
    if p.shape != t.shape:
        raise ValueError(f"pred {tuple(p.shape)} and target {tuple(t.shape)} differ in shape")
    mse = float(((p.clamp(0, 1) - t) ** 2).mean())
    return 100.0 if mse <= 1e-10 else float(10 * np.log10(1.0 / mse))


def ssim(pred, target, window: int = 11) -> float:
    """Mean SSIM (kornia, Gaussian window 11, sigma 1.5) for images in [0, 1]."""
    p, t = _t(pred), _t(target)
    if p.shape != t.shape:
        raise ValueError(f"pred {tuple(p.shape)} and target {tuple(t.shape)} differ in shape")
    return float(ssim_map(p.clamp(0, 1), t, window).mean())
