"""Losses of EBAD-Gaussian as pure functions over image tensors.

Convention: images are [B, H, W, D] (or [H, W, D]) linear intensity; events enter as signed
per-pixel sums ``E`` [P, H, W] between consecutive virtual instants; ``c`` is the contrast
threshold in natural-log units; log intensities are ``log(I + eps)`` with ``eps = edi.LOG_EPS``.
"""
from __future__ import annotations

import typing
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
from torch import Tensor
from kornia.metrics import ssim as _kornia_ssim

from edi import LOG_EPS

from .config import EventNorm  # the norm of the L_ev residual: l1, mean |r| (ebad's default), or l2, mean r^2 (the paper's)

__all__ = ["luminance", "ssim_map", "ssim_map_kornia", "l1_ssim", "l1_ssim_each", "blur_loss", "exposure_losses",
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


@dataclass
class _SSIMPass:
    """What ``_ssim_pass`` leaves for ``_ssim_adjoint``: both stacks [N, H, W], the window's taps
    and dS/d(moments) [4, N, H, W] (empty when no gradient was wanted)."""

    A: np.ndarray
    B: np.ndarray
    g: np.ndarray
    coef: np.ndarray


def _ssim_pass(A: np.ndarray, B: np.ndarray, win: int, want: bool,
               s_map: bool) -> tuple[np.ndarray | None, np.ndarray, _SSIMPass]:
    """``ebad._ssim_kernels.ssim_forward`` on stacks [N, H, W] of one dtype -> the SSIM map (when
    ``s_map``), each image's sums of S and of |a - b| [N, 2], and what the adjoint needs."""
    from . import _ssim_kernels as K

    g = K.window_taps(win).astype(A.dtype)
    s = np.empty(A.shape if s_map else _EMPTY, A.dtype)
    coef = np.empty((4,) + A.shape if want else (4,) + _EMPTY, A.dtype)
    sums = np.empty((K.num_tasks(A.shape[0], A.shape[1]), 2))
    _run(K.ssim_forward, A, B, g, s, coef, want, sums)
    return (s if s_map else None), sums.reshape(A.shape[0], -1, 2).sum(1), _SSIMPass(A, B, g, coef)


def _ssim_adjoint(p: _SSIMPass, grad_s: np.ndarray, gs_const: np.ndarray, l1_coef: np.ndarray, want_a: bool,
                  want_b: bool) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``ebad._ssim_kernels.ssim_backward`` after ``_ssim_pass`` -> the gradients of the stacks
    (None where not wanted). ``grad_s``: the map's upstream gradient [N, H, W] (or empty),
    ``gs_const`` and ``l1_coef``: each image's constant gradient of its mean S and of its mean
    |a - b| summed per pixel [N]."""
    from . import _ssim_kernels as K

    A, B = p.A, p.B
    ga = np.empty_like(A) if want_a else np.empty(_EMPTY, A.dtype)
    gb = np.empty_like(B) if want_b else np.empty(_EMPTY, A.dtype)
    # in the images' dtype: float64 ones would make the kernel compute its float32 loops in float64
    gs_const, l1_coef = gs_const.astype(A.dtype), l1_coef.astype(A.dtype)
    _run(K.ssim_backward, A, B, p.g, p.coef, grad_s, gs_const, l1_coef, ga, gb, want_a, want_b)
    return (ga if want_a else None), (gb if want_b else None)


def _kernel_forward(ctx, a: Tensor, b: Tensor, win: int, s_map: bool) -> tuple[np.ndarray | None, np.ndarray]:
    """``_ssim_pass`` on tensor stacks [N, H, W], what the backward needs on ``ctx`` -> the SSIM
    map (when ``s_map``) and each image's sums of S and |a - b| [N, 2]."""
    want = ctx.needs_input_grad[0] or ctx.needs_input_grad[1]
    s, sums, ctx.ssim = _ssim_pass(a.detach().numpy(), b.detach().numpy(), win, want, s_map)
    return s, sums


def _kernel_backward(ctx, grad_s: np.ndarray, gs_const: np.ndarray, l1_coef: np.ndarray) -> tuple:
    """``_ssim_adjoint`` after ``_kernel_forward`` -> the gradients of a and b as tensors (None
    where not wanted)."""
    ga, gb = _ssim_adjoint(ctx.ssim, grad_s, gs_const, l1_coef, ctx.needs_input_grad[0], ctx.needs_input_grad[1])
    return (None if ga is None else torch.from_numpy(ga)), (None if gb is None else torch.from_numpy(gb))


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
        A = ctx.ssim.A
        none = np.zeros(A.shape[0])  # no constant upstream gradient, no L1 term
        return *_kernel_backward(ctx, np.ascontiguousarray(grad_s.detach().numpy(), dtype=A.dtype), none, none), None


class _FusedL1SSIM(torch.autograd.Function):
    """``l1_ssim`` of groups of images of two stacks [N, H, W] (``group[n]`` in 0 .. P - 1 is image
    n's group) -> [P], in one kernel pass each way (``ebad._ssim_kernels``): no SSIM map, no L1
    graph, and no torch operation between the kernel and the losses for autograd to undo."""

    @staticmethod
    def forward(ctx, a: Tensor, b: Tensor, win: int, w: float, group: np.ndarray, P: int) -> Tensor:
        _, sums = _kernel_forward(ctx, a, b, win, s_map=False)
        loss, ctx.inv_count = _group_l1_ssim(sums, group, P, a.shape[1] * a.shape[2], w)
        ctx.w, ctx.group = w, group
        return torch.from_numpy(loss).to(a.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):  # [P]
        G = (grad.detach().to(torch.float64).numpy() * ctx.inv_count)[ctx.group]  # per image
        return *_kernel_backward(ctx, np.empty(_EMPTY, ctx.ssim.A.dtype), -ctx.w * G, (1 - ctx.w) * G), None, None, \
            None, None


def _group_l1_ssim(sums: np.ndarray, group: np.ndarray, P: int, pixels: int, w: float) -> tuple[np.ndarray, np.ndarray]:
    """(1 - w) mean |a - b| + w (1 - mean S) of each of P groups of images, from each image's sums
    of S and |a - b| [N, 2] (``group[n]``: image n's group, every image ``pixels`` values) -> the
    losses [P] and 1 / the number of values of each group's means [P]."""
    count = np.bincount(group, minlength=P) * float(pixels)
    s_mean = np.bincount(group, weights=sums[:, 0], minlength=P) / count
    l1_mean = np.bincount(group, weights=sums[:, 1], minlength=P) / count
    return (1 - w) * l1_mean + w * (1 - s_mean), 1.0 / count


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


def _event_pass(Ln: np.ndarray, counts: np.ndarray, c_pos: float, c_neg: float, eps: float,
                l2: bool) -> tuple[float, np.ndarray, float, float]:
    """``ebad._event_kernels.event_forward`` on luminances [V, H, W] and counts [V - 1, 2, H, W] of
    one dtype -> the loss (mean over windows and pixels), dloss/dr per window and pixel g
    [V - 1, H, W] before the mean, and the sums of g N_on and g N_off."""
    from . import _event_kernels as K

    V, H, W = Ln.shape
    log_L = np.log(np.maximum(Ln, 0) + Ln.dtype.type(eps))
    g = np.empty((V - 1, H, W), Ln.dtype)
    sums = np.empty((K.num_tasks(H), 3))
    _run(K.event_forward, log_L, counts, float(c_pos), float(c_neg), l2, g, sums)
    loss, s_on, s_off = sums.sum(0)
    return float(loss / g.size), g, float(s_on), float(s_off)


def _event_adjoint(Ln: np.ndarray, g: np.ndarray, scale: float, eps: float) -> np.ndarray:
    """``ebad._event_kernels.event_backward`` -> the gradient of the luminances [V, H, W] for an
    upstream gradient ``scale`` of the sum (the loss's gradient over the number of residuals)."""
    from . import _event_kernels as K

    out = np.empty_like(Ln)
    _run(K.event_backward, Ln, g, scale, eps, out)
    return out


class _EventLoss(torch.autograd.Function):
    """``event_loss`` of luminances L [V, H, W] in one kernel pass each way (``ebad._event_kernels``);
    gradients to L and to both thresholds."""

    @staticmethod
    def forward(ctx, L: Tensor, counts: Tensor, c_pos: Tensor, c_neg: Tensor, eps: float, l2: bool) -> Tensor:
        Ln = np.ascontiguousarray(L.detach().numpy())
        loss, ctx.g, ctx.s_on, ctx.s_off = _event_pass(Ln, np.ascontiguousarray(counts.detach().numpy()), c_pos, c_neg,
                                                       eps, l2)
        ctx.Ln, ctx.eps, ctx.inv_count = Ln, eps, 1.0 / ctx.g.size
        return torch.tensor(loss, dtype=L.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):
        scale = float(grad) * ctx.inv_count
        grad_L = torch.from_numpy(_event_adjoint(ctx.Ln, ctx.g, scale, ctx.eps)) if ctx.needs_input_grad[0] else None
        g_pos, g_neg = _threshold_grads(scale, ctx.s_on, ctx.s_off, ctx.needs_input_grad[2], ctx.needs_input_grad[3],
                                        grad.dtype)
        return grad_L, None, g_pos, g_neg, None, None


def _threshold_grads(scale: float, s_on: float, s_off: float, want_pos: bool, want_neg: bool,
                     dtype: torch.dtype) -> tuple[Tensor | None, Tensor | None]:
    """The gradients of L_ev with respect to c_pos and c_neg from ``_event_pass``'s sums (r falls
    with c_pos, rises with c_neg), for an upstream gradient ``scale`` of the sum."""
    return (torch.tensor(-scale * s_on, dtype=dtype) if want_pos else None,
            torch.tensor(scale * s_off, dtype=dtype) if want_neg else None)


def edi_loss(renders: Tensor,  # [H, W, D] or [V, H, W, D]
             latents: Tensor,  # the same shape
             ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """L_EDI: renders against the EDI latents of the frame at the same instants (the mid-exposure
    render and latent, or every virtual view's), averaged over them."""
    return l1_ssim(renders, latents, ssim_weight, window)


def exposure_losses(
    images: Tensor,  # [V', H, W, D] one exposure's renders (irradiance), its V virtual views first
    V: int,
    blurry: Tensor,  # [H, W, D] L_blur's target
    latents: Tensor | None = None,  # [H, W, D] (against images[mid]) or [V, H, W, D] (against images[:V])
    mid: int | None = None,  # index in images of the render compared with a [H, W, D] latent
    counts: Tensor | None = None,  # [E - 1, 2, H, W] ON / OFF counts between consecutive event_views
    event_views: Sequence[int] = (),  # the E indices in images of L_ev's instants, in time order
    c: float | tuple[float, float] | Tensor = 0.2,
    ssim_weight: float = 0.2,
    window: int = 7,
    eps: float | None = None,
    norm: EventNorm = "l1",
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
    """L_blur, L_EDI and L_ev of one exposure's renders in ONE autograd node, for a linear response.

    The same values and gradients as ``blur_loss(images[:V], blurry)``, ``edi_loss(images[mid],
    latents)`` (or ``edi_loss(images[:V], latents)`` for a latent per view) and
    ``event_loss(images[event_views], counts, c)``, from one L1 + SSIM kernel pass over every
    compared image and one L_ev pass, with the gradient of ``images`` written into one array:
    composed from torch operations, the slices, the mean and the stacks of the renders each added
    a full-size temporary and its backward to a training step. L_EDI is None without ``latents``,
    L_ev None with fewer than two ``event_views``; ``c`` as ``event_loss`` (differentiable).
    Returns (L_blur, L_EDI, L_ev, the mean of the V renders [H, W, D], detached)."""
    if images.ndim != 4 or images.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"images must be float32 or float64 [V', H, W, D], got {images.dtype} {tuple(images.shape)}")
    Vp, H, W, D = images.shape
    if not 1 <= V <= Vp:
        raise ValueError(f"V must be in [1, {Vp}] (the renders given), got {V}")
    if tuple(blurry.shape) != (H, W, D):
        raise ValueError(f"blurry must be [H, W, D] = {(H, W, D)}, got {tuple(blurry.shape)}")
    views = latents is not None and latents.ndim == 4
    if latents is not None:
        want = (V, H, W, D) if views else (H, W, D)
        if tuple(latents.shape) != want:
            raise ValueError(f"latents must be [H, W, D] or [V, H, W, D] = {(V, H, W, D)}, got {tuple(latents.shape)}")
        if not views and (mid is None or not 0 <= mid < Vp):
            raise ValueError(f"mid must index one of the {Vp} renders when latents is [H, W, D], got {mid}")
    event_views = tuple(int(i) for i in event_views)
    if len(event_views) >= 2:
        if counts is None or tuple(counts.shape) != (len(event_views) - 1, 2, H, W):
            raise ValueError(f"counts must be [E - 1, 2, H, W] = {(len(event_views) - 1, 2, H, W)}, "
                             f"got {None if counts is None else tuple(counts.shape)}")
        if len(set(event_views)) != len(event_views) or not all(0 <= i < Vp for i in event_views):
            raise ValueError(f"event_views must be distinct indices of the {Vp} renders, got {event_views}")
    if norm not in typing.get_args(EventNorm):
        raise ValueError(f"norm must be one of {typing.get_args(EventNorm)}, got {norm!r}")
    cc = torch.as_tensor(c, dtype=images.dtype).reshape(-1)
    spec = _ExposureSpec(V=V, mid=None if latents is None or views else int(mid), views=views,
                         event_views=event_views if len(event_views) >= 2 else (),
                         win=_window_for(H, W, window), w=float(ssim_weight),
                         eps=LOG_EPS if eps is None else float(eps), l2=norm == "l2")
    losses, mean = _ExposureLosses.apply(images, cc[0], cc[-1], blurry, latents, counts, spec)
    blur, edi, ev = losses.unbind()
    return blur, (edi if latents is not None else None), (ev if spec.event_views else None), mean


@dataclass(frozen=True)
class _ExposureSpec:
    """``exposure_losses``'s choices, as ``_ExposureLosses`` takes them."""

    V: int
    mid: int | None  # the render compared with a mid-exposure latent (None: no L_EDI, or one latent per view)
    views: bool  # one latent per virtual view
    event_views: tuple[int, ...]  # L_ev's renders (empty: no L_ev)
    win: int
    w: float
    eps: float
    l2: bool


def _hwd_stack(x: np.ndarray) -> np.ndarray:  # [B, H, W, D] -> [B*D, H, W] contiguous (a view when D = 1 and contiguous)
    B, H, W, D = x.shape
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2)).reshape(B * D, H, W)


class _ExposureLosses(torch.autograd.Function):
    """``exposure_losses``: (L_blur, L_EDI, L_ev) [3] and the mean render; gradients to the renders
    and to both thresholds."""

    @staticmethod
    def forward(ctx, images: Tensor, c_pos: Tensor, c_neg: Tensor, blurry: Tensor, latents: Tensor | None,
                counts: Tensor | None, spec: _ExposureSpec):
        X = np.ascontiguousarray(images.detach().numpy())
        dt = X.dtype
        Vp, H, W, D = X.shape
        mean = X[:spec.V].mean(0, dtype=dt)  # [H, W, D]
        preds, targets = [mean[None]], [np.asarray(blurry.detach().numpy(), dt)[None]]
        if latents is not None:
            lat = np.asarray(latents.detach().numpy(), dt)
            preds.append(X[:spec.V] if spec.views else X[spec.mid][None])
            targets.append(lat if spec.views else lat[None])
        A = _hwd_stack(np.concatenate(preds))
        B = _hwd_stack(np.concatenate(targets))
        group = np.repeat(np.arange(len(preds)), [p.shape[0] * D for p in preds])
        _, sums, ctx.ssim = _ssim_pass(A, B, spec.win, images.requires_grad, s_map=False)
        image_losses, ctx.inv_count = _group_l1_ssim(sums, group, len(preds), H * W, spec.w)
        ev = 0.0
        if spec.event_views:
            Xe = X[list(spec.event_views)]
            Ln = np.ascontiguousarray(Xe[..., 0] if D == 1 else Xe @ np.asarray(LUMA, dt))  # [E, H, W] luminance
            ev, ctx.g, ctx.s_on, ctx.s_off = _event_pass(Ln, np.ascontiguousarray(counts.detach().numpy(), dtype=dt),
                                                         c_pos, c_neg, spec.eps, spec.l2)
            ctx.Ln = Ln
        ctx.spec, ctx.group, ctx.shape = spec, group, X.shape
        mean_t = torch.from_numpy(mean)
        ctx.mark_non_differentiable(mean_t)
        losses = np.array([image_losses[0], image_losses[1] if latents is not None else 0.0, ev])
        return torch.from_numpy(losses).to(images.dtype), mean_t

    @staticmethod
    def backward(ctx, grad: Tensor, _grad_mean):  # [3]
        spec = ctx.spec
        Vp, H, W, D = ctx.shape
        G = grad.detach().to(torch.float64).numpy()
        grad_images = None
        g_pos = g_neg = None
        if ctx.needs_input_grad[0]:
            per_image = (G[:len(ctx.inv_count)] * ctx.inv_count)[ctx.group]
            ga, _ = _ssim_adjoint(ctx.ssim, np.empty(_EMPTY, ctx.ssim.A.dtype), -spec.w * per_image,
                                  (1 - spec.w) * per_image, True, False)
            ga = ga.reshape(-1, D, H, W).transpose(0, 2, 3, 1)  # [P images, H, W, D]
            blur_share = ga[0] / ga.dtype.type(spec.V)  # the mean's gradient, to each of the V renders
            if spec.views and Vp == spec.V:  # each render's own L_EDI gradient plus its share: one pass
                out = ga[1:] + blur_share
            else:
                out = np.empty(ctx.shape, ga.dtype)
                out[:spec.V] = blur_share
                out[spec.V:] = 0
                if spec.views:
                    out[:spec.V] += ga[1:]
                elif spec.mid is not None:
                    out[spec.mid] += ga[1]
            if spec.event_views:
                gl = _event_adjoint(ctx.Ln, ctx.g, float(G[2]) / ctx.g.size, spec.eps)  # [E, H, W]
                e0, e1 = spec.event_views[0], spec.event_views[-1]
                consecutive = spec.event_views == tuple(range(e0, e1 + 1))
                idx = slice(e0, e1 + 1) if consecutive else list(spec.event_views)  # a slice adds in place
                out[idx] += gl[..., None] if D == 1 else gl[..., None] * np.asarray(LUMA, gl.dtype)
            grad_images = torch.from_numpy(np.ascontiguousarray(out))
        if spec.event_views:
            g_pos, g_neg = _threshold_grads(float(G[2]) / ctx.g.size, ctx.s_on, ctx.s_off, ctx.needs_input_grad[1],
                                            ctx.needs_input_grad[2], grad.dtype)
        return grad_images, g_pos, g_neg, None, None, None, None
