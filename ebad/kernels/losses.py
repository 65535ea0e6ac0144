"""The losses' numba kernels (``_numba_ssim``, ``_numba_event``) as autograd Functions, and the entry points
``ebad.losses`` dispatches to.

Each entry point takes what ``ebad.losses`` has checked and prepared (the [B, H, W, D] images,
the window after ``ebad.losses``' clamp for small images, the dtype the kernels compute in, the
thresholds as tensors) and gives the value of the loss of the same name there, with its
gradients from the kernels' adjoints: one kernel pass each way, numpy in and numpy out, no torch
operation between the kernels and the losses for autograd to undo. ``ebad.losses``' torch code
is the reference these are tested against (``tests/ebad/kernels/test_losses.py``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from splat_cpu._omp import choose_threading_layer

from . import LUMA

__all__ = ["event_loss", "exposure_losses", "l1_ssim_each", "ssim_map"]


def ssim_map(
    a: Tensor,  # [B, H, W, D]
    b: Tensor,  # [B, H, W, D]
    win: int,
    dtype: torch.dtype,
) -> Tensor:  # [B, H, W, D]
    """``ebad.losses.ssim_map`` with a window of ``win`` taps, computed in ``dtype``."""
    return _unstack(_FusedSSIM.apply(_stack(a, dtype), _stack(b, dtype), win), a.shape)


def l1_ssim_each(
    preds: Sequence[Tensor],  # P x [B_i, H, W, D]
    targets: Sequence[Tensor],  # P x [B_i, H, W, D]
    ssim_weight: float,
    win: int,
    dtype: torch.dtype,
) -> list[Tensor]:  # P x []
    """``ebad.losses.l1_ssim_each`` of the pairs (one image size, ``ssim_weight`` > 0) in one kernel
    call each way, computed in ``dtype``."""
    pred = torch.cat(list(preds)) if len(preds) > 1 else preds[0]
    target = torch.cat(list(targets)) if len(targets) > 1 else targets[0]
    D = pred.shape[-1]
    group = np.repeat(np.arange(len(preds)), [p.shape[0] * D for p in preds])  # per image of the stack
    losses = _FusedL1SSIM.apply(_stack(pred, dtype), _stack(target, dtype), win, float(ssim_weight), group, len(preds))
    return list(losses.unbind())


def event_loss(
    L: Tensor,  # [V, H, W] luminances, or [V, H, W, 3] colour renders with cfa; float32 or float64
    counts: Tensor,  # [V - 1, 2, H, W] in L's dtype
    c_pos: Tensor,
    c_neg: Tensor,  # [] in L's dtype
    eps: float,
    l2: bool,
    cfa: Tensor | None = None,  # [H, W, 3] ebad.losses.cfa_weights in L's dtype
) -> Tensor:
    """``ebad.losses.event_loss`` of luminances ``L`` (V >= 2), or of colour renders seen through a
    colour DAVIS's filter ``cfa``; gradients to L and both thresholds."""
    F = None if cfa is None else np.ascontiguousarray(cfa.detach().numpy())
    return _EventLoss.apply(L, counts, c_pos, c_neg, eps, l2, F)


def exposure_losses(
    images: Tensor,  # [V', H, W, D] float32 or float64, its V virtual views first
    V: int,
    blurry: Tensor,  # [H, W, D]
    latents: Tensor | None,  # [H, W, D] (against images[mid]) or [V, H, W, D] (against images[:V])
    mid: int | None,  # index in images of the render compared with a [H, W, D] latent
    counts: Tensor | None,  # [E - 1, 2, H, W]
    event_views: tuple[int, ...],  # E distinct indices in images, in time order (fewer than 2: no L_ev)
    c_pos: Tensor,  # [] in images' dtype
    c_neg: Tensor,  # [] in images' dtype
    win: int,
    ssim_weight: float,
    eps: float,
    l2: bool,
    cfa: Tensor | None = None,  # [H, W, 3] ebad.losses.cfa_weights in images' dtype (images D = 3)
    project: bool = False,  # L_blur and L_EDI compare the renders' cfa projection (raw mosaic targets)
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
    """``ebad.losses.exposure_losses`` (its inputs checked there) in one autograd node: L_blur,
    L_EDI (None without latents), L_ev (None with fewer than two event views) and the mean of the
    V renders [H, W, D] (projected through ``cfa`` when ``project``), detached."""
    views = latents is not None and latents.ndim == 4
    mid_index = None
    if latents is not None and not views:
        assert mid is not None  # ebad.losses.exposure_losses checks mid with a [H, W, D] latent
        mid_index = int(mid)
    spec = _ExposureSpec(
        V=V,
        mid=mid_index,
        views=views,
        event_views=event_views if len(event_views) >= 2 else (),
        win=win,
        w=float(ssim_weight),
        eps=float(eps),
        l2=l2,
        cfa=None if cfa is None else np.ascontiguousarray(cfa.detach().numpy()),
        project=project,
    )
    losses, mean = _ExposureLosses.apply(images, c_pos, c_neg, blurry, latents, counts, spec)
    blur, edi, ev = losses.unbind()
    return blur, (edi if latents is not None else None), (ev if spec.event_views else None), mean


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


def _ssim_pass(
    A: np.ndarray, B: np.ndarray, win: int, want: bool, s_map: bool
) -> tuple[np.ndarray | None, np.ndarray, _SSIMPass]:
    """``_numba_ssim.ssim_forward`` on stacks [N, H, W] of one dtype -> the SSIM map (when
    ``s_map``), each image's sums of S and of |a - b| [N, 2], and what the adjoint needs."""
    from . import _numba_ssim as K

    g = K.window_taps(win).astype(A.dtype)
    s = np.empty(A.shape if s_map else _EMPTY, A.dtype)
    coef = np.empty((4,) + A.shape if want else (4,) + _EMPTY, A.dtype)
    sums = np.empty((K.num_tasks(A.shape[0], A.shape[1]), 2))
    _run(K.ssim_forward, A, B, g, s, coef, want, sums)
    return (s if s_map else None), sums.reshape(A.shape[0], -1, 2).sum(1), _SSIMPass(A, B, g, coef)


def _ssim_adjoint(
    p: _SSIMPass, grad_s: np.ndarray, gs_const: np.ndarray, l1_coef: np.ndarray, want_a: bool, want_b: bool
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``_numba_ssim.ssim_backward`` after ``_ssim_pass`` -> the gradients of the stacks
    (None where not wanted). ``grad_s``: the map's upstream gradient [N, H, W] (or empty),
    ``gs_const`` and ``l1_coef``: each image's constant gradient of its mean S and of its mean
    |a - b| summed per pixel [N]."""
    from . import _numba_ssim as K

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
    """A kernel of ``_numba_ssim`` or ``_numba_event`` with its bands handed out one
    at a time: the thread that starts first takes more of them instead of waiting for one woken
    late (faster than numba's static split in a training step)."""
    import numba

    choose_threading_layer()  # before numba's first parallel launch, unless chosen already (splat_cpu._omp)
    with numba.parallel_chunksize(1):
        kernel(*args)


class _FusedSSIM(torch.autograd.Function):
    """The SSIM map of two image stacks [N, H, W] (``_numba_ssim``)."""

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
    n's group) -> [P], in one kernel pass each way (``_numba_ssim``): no SSIM map, no L1
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
        return (
            *_kernel_backward(ctx, np.empty(_EMPTY, ctx.ssim.A.dtype), -ctx.w * G, (1 - ctx.w) * G),
            None,
            None,
            None,
            None,
        )


def _group_l1_ssim(sums: np.ndarray, group: np.ndarray, P: int, pixels: int, w: float) -> tuple[np.ndarray, np.ndarray]:
    """(1 - w) mean |a - b| + w (1 - mean S) of each of P groups of images, from each image's sums
    of S and |a - b| [N, 2] (``group[n]``: image n's group, every image ``pixels`` values) -> the
    losses [P] and 1 / the number of values of each group's means [P]."""
    count = np.bincount(group, minlength=P) * float(pixels)
    s_mean = np.bincount(group, weights=sums[:, 0], minlength=P) / count
    l1_mean = np.bincount(group, weights=sums[:, 1], minlength=P) / count
    return (1 - w) * l1_mean + w * (1 - s_mean), 1.0 / count


def _log_signal(X: np.ndarray, F: np.ndarray | None, eps: float) -> np.ndarray:
    """L_ev's log signal [V, H, W]: log(max(X, 0) + eps) of luminances X [V, H, W], or with a colour
    DAVIS's channel fractions F [H, W, 3] sum_d F_d log(max(X_d, 0) + eps) of renders X [V, H, W, 3]."""
    log_X = np.log(np.maximum(X, 0) + X.dtype.type(eps))
    if F is None:
        return log_X
    return np.ascontiguousarray(np.einsum("vhwd,hwd->vhw", log_X, F))


def _event_pass(
    log_L: np.ndarray, counts: np.ndarray, c_pos: float | Tensor, c_neg: float | Tensor, l2: bool
) -> tuple[float, np.ndarray, float, float]:
    """``_numba_event.event_forward`` on log signals [V, H, W] (``_log_signal``) and counts
    [V - 1, 2, H, W] of one dtype -> the loss (mean over windows and pixels), dloss/dr per window
    and pixel g [V - 1, H, W] before the mean, and the sums of g N_on and g N_off."""
    from . import _numba_event as K

    V, H, W = log_L.shape
    g = np.empty((V - 1, H, W), log_L.dtype)
    sums = np.empty((K.num_tasks(H), 3))
    _run(K.event_forward, log_L, counts, float(c_pos), float(c_neg), l2, g, sums)
    loss, s_on, s_off = sums.sum(0)
    return float(loss / g.size), g, float(s_on), float(s_off)


def _event_adjoint(X: np.ndarray, g: np.ndarray, scale: float, eps: float, F: np.ndarray | None) -> np.ndarray:
    """``_numba_event.event_backward`` -> the gradient of the luminances [V, H, W] (renders
    [V, H, W, 3] with channel fractions F [H, W, 3]) for an upstream gradient ``scale`` of the sum
    (the loss's gradient over the number of residuals). Grey is one channel without fractions."""
    from . import _numba_event as K

    out = np.empty_like(X)
    if F is None:
        F = np.empty((0, 0, 0), X.dtype)
    _run(K.event_backward, X.reshape(*X.shape[:3], -1), F, g, scale, eps, out.reshape(*X.shape[:3], -1))
    return out


class _EventLoss(torch.autograd.Function):
    """``event_loss`` of luminances L [V, H, W] (or colour renders [V, H, W, 3] through channel
    fractions F) in one kernel pass each way (``_numba_event``); gradients to L and to both thresholds."""

    @staticmethod
    def forward(
        ctx, L: Tensor, counts: Tensor, c_pos: Tensor, c_neg: Tensor, eps: float, l2: bool, F: np.ndarray | None
    ) -> Tensor:
        Ln = np.ascontiguousarray(L.detach().numpy())
        loss, ctx.g, ctx.s_on, ctx.s_off = _event_pass(
            _log_signal(Ln, F, eps), np.ascontiguousarray(counts.detach().numpy()), c_pos, c_neg, l2
        )
        ctx.Ln, ctx.F, ctx.eps, ctx.inv_count = Ln, F, eps, 1.0 / ctx.g.size
        return torch.tensor(loss, dtype=L.dtype)

    @staticmethod
    def backward(ctx, grad: Tensor):
        scale = float(grad) * ctx.inv_count
        grad_L = (
            torch.from_numpy(_event_adjoint(ctx.Ln, ctx.g, scale, ctx.eps, ctx.F)) if ctx.needs_input_grad[0] else None
        )
        g_pos, g_neg = _threshold_grads(
            scale, ctx.s_on, ctx.s_off, ctx.needs_input_grad[2], ctx.needs_input_grad[3], grad.dtype
        )
        return grad_L, None, g_pos, g_neg, None, None, None


def _threshold_grads(
    scale: float, s_on: float, s_off: float, want_pos: bool, want_neg: bool, dtype: torch.dtype
) -> tuple[Tensor | None, Tensor | None]:
    """The gradients of L_ev with respect to c_pos and c_neg from ``_event_pass``'s sums (r falls
    with c_pos, rises with c_neg), for an upstream gradient ``scale`` of the sum."""
    return (
        torch.tensor(-scale * s_on, dtype=dtype) if want_pos else None,
        torch.tensor(scale * s_off, dtype=dtype) if want_neg else None,
    )


@dataclass(frozen=True)
class _ExposureSpec:
    """``exposure_losses``' choices, as ``_ExposureLosses`` takes them."""

    V: int
    mid: int | None  # the render compared with a mid-exposure latent (None: no L_EDI, or one latent per view)
    views: bool  # one latent per virtual view
    event_views: tuple[int, ...]  # L_ev's renders (empty: no L_ev)
    win: int
    w: float
    eps: float
    l2: bool
    cfa: np.ndarray | None = None  # [H, W, 3] channel fractions of a colour DAVIS (ebad.losses.cfa_weights)
    project: bool = False  # L_blur and L_EDI compare sum_d cfa_d images_d (raw mosaic targets)


def _hwd_stack(
    x: np.ndarray,
) -> np.ndarray:  # [B, H, W, D] -> [B*D, H, W] contiguous (a view when D = 1 and contiguous)
    B, H, W, D = x.shape
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2)).reshape(B * D, H, W)


class _ExposureLosses(torch.autograd.Function):
    """``exposure_losses``: (L_blur, L_EDI, L_ev) [3] and the mean render; gradients to the renders
    and to both thresholds."""

    @staticmethod
    def forward(
        ctx,
        images: Tensor,
        c_pos: Tensor,
        c_neg: Tensor,
        blurry: Tensor,
        latents: Tensor | None,
        counts: Tensor | None,
        spec: _ExposureSpec,
    ):
        X = np.ascontiguousarray(images.detach().numpy())
        dt = X.dtype
        Vp, H, W, D = X.shape
        F = spec.cfa
        # what L_blur and L_EDI compare: the renders, or their cfa projection [.., H, W, 1] (raw mosaic targets)
        Xc = np.einsum("vhwd,hwd->vhw", X, F)[..., None] if spec.project and F is not None else X
        Dc = Xc.shape[-1]
        mean = Xc[: spec.V].mean(0, dtype=dt)  # [H, W, Dc]
        preds, targets = [mean[None]], [np.asarray(blurry.detach().numpy(), dt)[None]]
        if latents is not None:
            lat = np.asarray(latents.detach().numpy(), dt)
            preds.append(Xc[: spec.V] if spec.views else Xc[spec.mid][None])
            targets.append(lat if spec.views else lat[None])
        A = _hwd_stack(np.concatenate(preds))
        B = _hwd_stack(np.concatenate(targets))
        group = np.repeat(np.arange(len(preds)), [p.shape[0] * Dc for p in preds])
        _, sums, ctx.ssim = _ssim_pass(A, B, spec.win, images.requires_grad, s_map=False)
        image_losses, ctx.inv_count = _group_l1_ssim(sums, group, len(preds), H * W, spec.w)
        ev = 0.0
        if spec.event_views:
            assert counts is not None  # ebad.losses.exposure_losses checks counts with two or more event views
            Xe = X[list(spec.event_views)]
            if F is not None:  # [E, H, W, 3] colour renders, seen through the filter
                Ln = np.ascontiguousarray(Xe)
            else:  # [E, H, W] luminance
                Ln = np.ascontiguousarray(Xe[..., 0] if D == 1 else Xe @ np.asarray(LUMA, dt))
            ev, ctx.g, ctx.s_on, ctx.s_off = _event_pass(
                _log_signal(Ln, F, spec.eps),
                np.ascontiguousarray(counts.detach().numpy(), dtype=dt),
                c_pos,
                c_neg,
                spec.l2,
            )
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
            per_image = (G[: len(ctx.inv_count)] * ctx.inv_count)[ctx.group]
            ga, _ = _ssim_adjoint(
                ctx.ssim, np.empty(_EMPTY, ctx.ssim.A.dtype), -spec.w * per_image, (1 - spec.w) * per_image, True, False
            )
            assert ga is not None  # want_a
            if spec.project:  # the gradient of the projection sum_d F_d X_d: [P images, H, W, 1] * F
                ga = ga.reshape(-1, H, W)[..., None] * spec.cfa
            else:
                ga = ga.reshape(-1, D, H, W).transpose(0, 2, 3, 1)  # [P images, H, W, D]
            blur_share = ga[0] / ga.dtype.type(spec.V)  # the mean's gradient, to each of the V renders
            if spec.views and Vp == spec.V:  # each render's own L_EDI gradient plus its share: one pass
                out = ga[1:] + blur_share
            else:
                out = np.empty(ctx.shape, ga.dtype)
                out[: spec.V] = blur_share
                out[spec.V :] = 0
                if spec.views:
                    out[: spec.V] += ga[1:]
                elif spec.mid is not None:
                    out[spec.mid] += ga[1]
            if spec.event_views:
                gl = _event_adjoint(ctx.Ln, ctx.g, float(G[2]) / ctx.g.size, spec.eps, spec.cfa)  # [E, H, W(, 3)]
                e0, e1 = spec.event_views[0], spec.event_views[-1]
                consecutive = spec.event_views == tuple(range(e0, e1 + 1))
                idx = slice(e0, e1 + 1) if consecutive else list(spec.event_views)  # a slice adds in place
                if spec.cfa is not None:
                    out[idx] += gl
                else:
                    out[idx] += gl[..., None] if D == 1 else gl[..., None] * np.asarray(LUMA, gl.dtype)
            grad_images = torch.from_numpy(np.ascontiguousarray(out))
        if spec.event_views:
            g_pos, g_neg = _threshold_grads(
                float(G[2]) / ctx.g.size,
                ctx.s_on,
                ctx.s_off,
                ctx.needs_input_grad[1],
                ctx.needs_input_grad[2],
                grad.dtype,
            )
        return grad_images, g_pos, g_neg, None, None, None, None
