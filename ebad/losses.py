"""Losses of EBAD-Gaussian as pure functions over image tensors.

Convention: images are [B, H, W, D] (or [H, W, D]) linear intensity; events enter as signed
per-pixel sums ``E`` [P, H, W] between consecutive virtual instants; ``c`` is the contrast
threshold in natural-log units; log intensities are ``log(I + eps)`` with ``eps = edi.LOG_EPS``.
"""
from __future__ import annotations

import typing
from typing import Sequence

import numpy as np
import torch
from torch import Tensor
from kornia.metrics import ssim as _kornia_ssim

from edi import LOG_EPS

from .config import EventNorm  # the norm of the L_ev residual: l1, mean |r| (ebad's default), or l2, mean r^2 (the paper's)

__all__ = ["luminance", "ssim_map", "ssim_map_kornia", "l1_ssim", "l1_ssim_each", "blur_loss",
           "event_loss", "edi_loss", "LUMA"]

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


def _stack(x: Tensor, dtype: torch.dtype) -> Tensor:  # [B, H, W, D] -> [B*D, H, W] contiguous (a view when D = 1)
    B, H, W, D = x.shape
    return x.to(dtype).permute(0, 3, 1, 2).reshape(B * D, H, W).contiguous()


def _unstack(x: Tensor, shape: torch.Size) -> Tensor:  # [B*D, H, W] -> [B, H, W, D]
    B, H, W, D = shape
    return x.reshape(B, D, H, W).permute(0, 2, 3, 1)


_EMPTY = (0, 0, 0)  # the kernels' "not wanted" array shape


def _kernel_forward(ctx, a: Tensor, b: Tensor, win: int, s_map: bool) -> tuple[np.ndarray | None, np.ndarray]:
    """``ebad._ssim_kernels.ssim_forward`` on stacks [N, H, W]; what the backward needs goes on
    ``ctx``. -> the SSIM map (when ``s_map``) and the per-task sums of S and |a - b|."""
    from . import _ssim_kernels as K

    A, B = a.detach().numpy(), b.detach().numpy()
    g = K.gauss_taps(win).astype(A.dtype)
    want = ctx.needs_input_grad[0] or ctx.needs_input_grad[1]
    s = np.empty(A.shape if s_map else _EMPTY, A.dtype)
    coef = np.empty((4,) + A.shape if want else (4,) + _EMPTY, A.dtype)
    sums = np.empty((K.num_tasks(A.shape[0], A.shape[1]), 2))
    _run(K.ssim_forward, A, B, g, s, coef, want, sums)
    ctx.save_for_backward(a, b)
    ctx.coef, ctx.g = coef, g
    return (s if s_map else None), sums


def _kernel_backward(ctx, grad_s: np.ndarray, gs_const: np.ndarray, l1_coef: np.ndarray) -> tuple:
    """``ebad._ssim_kernels.ssim_backward`` after ``_kernel_forward`` -> the gradients of a and b
    (None where not wanted)."""
    from . import _ssim_kernels as K

    a, b = ctx.saved_tensors
    want_a, want_b = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
    A, B = a.detach().numpy(), b.detach().numpy()
    ga = np.empty_like(A) if want_a else np.empty(_EMPTY, A.dtype)
    gb = np.empty_like(B) if want_b else np.empty(_EMPTY, A.dtype)
    # in the images' dtype: float64 ones would make the kernel compute its float32 loops in float64
    gs_const, l1_coef = gs_const.astype(A.dtype), l1_coef.astype(A.dtype)
    _run(K.ssim_backward, A, B, ctx.g, ctx.coef, grad_s, gs_const, l1_coef, ga, gb, want_a, want_b)
    return (torch.from_numpy(ga) if want_a else None), (torch.from_numpy(gb) if want_b else None)


def _run(kernel, *args) -> None:
    """A kernel of ``ebad._ssim_kernels`` or ``ebad._event_kernels`` with its bands handed out one
    at a time: the thread that starts first takes more of them instead of waiting for one woken
    late (in a training step the SSIM kernels on 173x130 images ran 1.4 to 1.8 times faster
    than with numba's static split)."""
    import numba

    with numba.parallel_chunksize(1):
        kernel(*args)


class _FusedSSIM(torch.autograd.Function):
    """The SSIM map of two image stacks [N, H, W] (``ebad._ssim_kernels``)."""

    @staticmethod
    def forward(ctx, a: Tensor, b: Tensor, win: int) -> Tensor:
        s, _ = _kernel_forward(ctx, a, b, win, s_map=True)
        return torch.from_numpy(s)

    @staticmethod
    def backward(ctx, grad_s: Tensor):
        a = ctx.saved_tensors[0]
        none = np.zeros(a.shape[0])  # no constant upstream gradient, no L1 term
        return *_kernel_backward(ctx, grad_s.detach().to(a.dtype).contiguous().numpy(), none, none), None


class _FusedL1SSIM(torch.autograd.Function):
    """``l1_ssim`` of groups of images of two stacks [N, H, W] (``group[n]`` in 0 .. P - 1 is image
    n's group) -> [P], in one kernel pass each way (``ebad._ssim_kernels``): no SSIM map, no L1
    graph, and no torch operation between the kernel and the losses for autograd to undo."""

    @staticmethod
    def forward(ctx, a: Tensor, b: Tensor, win: int, w: float, group: np.ndarray, P: int) -> Tensor:
        N, H, W = a.shape
        _, sums = _kernel_forward(ctx, a, b, win, s_map=False)
        s_img, l1_img = sums.reshape(N, -1, 2).sum(1).T  # per image: the sums of S and of |a - b|
        count = np.bincount(group, minlength=P) * float(H * W)  # the values each group's means run over
        s_mean = np.bincount(group, weights=s_img, minlength=P) / count
        l1_mean = np.bincount(group, weights=l1_img, minlength=P) / count
        ctx.w, ctx.group, ctx.inv_count = w, group, 1.0 / count
        return torch.from_numpy((1 - w) * l1_mean + w * (1 - s_mean)).to(a.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):  # [P]
        G = (grad.detach().to(torch.float64).numpy() * ctx.inv_count)[ctx.group]  # per image
        return *_kernel_backward(ctx, np.empty(_EMPTY, ctx.coef.dtype), -ctx.w * G, (1 - ctx.w) * G), None, None, \
            None, None


def _pair(a: Tensor, b: Tensor, names: tuple[str, str]) -> tuple[Tensor, Tensor, torch.dtype]:
    """Both as [B, H, W, D], checked to match, and the dtype the kernels compute in."""
    a = _bhwd(a, names[0])
    b = _bhwd(b, names[1])
    if a.shape != b.shape:
        raise ValueError(f"{names[0]} {tuple(a.shape)} and {names[1]} {tuple(b.shape)} differ in shape")
    dtype = a.dtype if a.dtype in (torch.float32, torch.float64) else torch.float32
    return a, b, dtype


def ssim_map(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """SSIM map with kornia's conventions (Gaussian window, sigma 1.5, reflect padding,
    c1 = 0.01^2, c2 = 0.03^2, eps 1e-12), in one fused kernel pass over the separable window
    (``ebad._ssim_kernels``) with its adjoint as the backward; gradients reach ``a`` and ``b``.

    ``ssim_map_kornia`` is the reference it is tested against. float32 and float64 inputs are
    computed in their own precision; other dtypes in float32."""
    a, b, dtype = _pair(a, b, ("a", "b"))
    win = _window_for(a.shape[1], a.shape[2], window)
    return _unstack(_FusedSSIM.apply(_stack(a, dtype), _stack(b, dtype), win), a.shape)


def ssim_map_kornia(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """The reference: kornia.metrics.ssim in [B, H, W, D] layout."""
    a = _bhwd(a, "a").permute(0, 3, 1, 2)
    b = _bhwd(b, "b").permute(0, 3, 1, 2)
    win = _window_for(a.shape[-2], a.shape[-1], window)
    return _kornia_ssim(a, b, win).permute(0, 2, 3, 1)


def l1_ssim(pred: Tensor, target: Tensor, ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """(1 - w) L1 + w (1 - SSIM), averaged over everything; [B,H,W,D] or [H,W,D] inputs. Both
    terms come from one kernel pass (and one for the gradient) when ``w`` > 0."""
    return l1_ssim_each([(pred, target)], ssim_weight, window)[0]


def l1_ssim_each(pairs: Sequence[tuple[Tensor, Tensor]], ssim_weight: float = 0.2, window: int = 7) -> list[Tensor]:
    """``l1_ssim`` of each (pred, target) pair, [B_i,H,W,D] or [H,W,D], all of one image size:
    one kernel call for all of them (a call has a fixed cost of about 0.1 ms per direction)."""
    checked = [_pair(p, t, (f"pred {i}", f"target {i}")) for i, (p, t) in enumerate(pairs)]
    if ssim_weight == 0:
        return [(p - t).abs().mean() for p, t, _ in checked]
    sizes = {p.shape[1:] for p, _, _ in checked}
    if len(sizes) > 1:
        raise ValueError(f"pairs must share one image size [H, W, D], got {sorted(tuple(x) for x in sizes)}")
    dtype = checked[0][2]
    pred = torch.cat([p for p, _, _ in checked]) if len(checked) > 1 else checked[0][0]
    target = torch.cat([t for _, t, _ in checked]) if len(checked) > 1 else checked[0][1]
    _, H, W, D = pred.shape
    group = np.repeat(np.arange(len(checked)), [p.shape[0] * D for p, _, _ in checked])  # per image of the stack
    losses = _FusedL1SSIM.apply(_stack(pred, dtype), _stack(target, dtype), _window_for(H, W, window),
                                float(ssim_weight), group, len(checked))
    return list(losses.unbind())


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
    L = luminance(renders)[..., 0]  # [V, H, W]
    if L.dtype not in (torch.float32, torch.float64):
        L = L.float()
    cc = torch.as_tensor(c, dtype=L.dtype).reshape(-1)
    return _EventLoss.apply(L, counts.to(L.dtype), cc[0], cc[-1], float(eps), norm == "l2")


class _EventLoss(torch.autograd.Function):
    """``event_loss`` of luminances L [V, H, W] in one kernel pass each way (``ebad._event_kernels``);
    gradients to L and to both thresholds."""

    @staticmethod
    def forward(ctx, L: Tensor, counts: Tensor, c_pos: Tensor, c_neg: Tensor, eps: float, l2: bool) -> Tensor:
        from . import _event_kernels as K

        V, H, W = L.shape
        Ln = np.ascontiguousarray(L.detach().numpy())
        log_L = np.log(np.maximum(Ln, 0) + Ln.dtype.type(eps))
        g = np.empty((V - 1, H, W), Ln.dtype)
        sums = np.empty((K.num_tasks(H), 3))
        _run(K.event_forward, log_L, np.ascontiguousarray(counts.detach().numpy()), float(c_pos), float(c_neg), l2,
             g, sums)
        loss, s_on, s_off = sums.sum(0)
        ctx.Ln, ctx.g, ctx.eps, ctx.inv_count = Ln, g, eps, 1.0 / g.size
        ctx.s_on, ctx.s_off = s_on, s_off
        return torch.tensor(loss / g.size, dtype=L.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):
        from . import _event_kernels as K

        scale = float(grad) * ctx.inv_count
        grad_L = None
        if ctx.needs_input_grad[0]:
            out = np.empty_like(ctx.Ln)
            _run(K.event_backward, ctx.Ln, ctx.g, scale, ctx.eps, out)
            grad_L = torch.from_numpy(out)
        dt = grad.dtype
        g_pos = torch.tensor(-scale * ctx.s_on, dtype=dt) if ctx.needs_input_grad[2] else None  # r falls with c_pos
        g_neg = torch.tensor(scale * ctx.s_off, dtype=dt) if ctx.needs_input_grad[3] else None
        return grad_L, None, g_pos, g_neg, None, None


def edi_loss(renders: Tensor,  # [H, W, D] or [V, H, W, D]
             latents: Tensor,  # the same shape
             ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """L_EDI: renders against the EDI latents of the frame at the same instants (the mid-exposure
    render and latent, or every virtual view's), averaged over them."""
    return l1_ssim(renders, latents, ssim_weight, window)
