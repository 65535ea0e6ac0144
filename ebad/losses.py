"""Losses of EBAD-Gaussian as pure functions over image tensors: the method's torch reference.

Convention: images are [B, H, W, D] (or [H, W, D]) linear intensity; events enter as signed
per-pixel sums ``E`` [P, H, W] between consecutive virtual instants; ``c`` is the contrast
threshold in natural-log units; log intensities are ``log(I + eps)`` with ``eps = edi.LOG_EPS``.

Colour DAVIS (a capture with ``cfa``, DESIGN.md): every sensor pixel sits behind one filter of a
Bayer array, its events fire on the log of that one channel and its APS records that one channel.
The losses take the filter as ``cfa`` weights F [H, W, 3] (``cfa_weights``): the fraction of each
training pixel's sensor pixels behind the R, G and B filters (one-hot at the sensor's resolution;
at 1/s of it, ``ebad.data.downscale``, the fractions of the s x s block, 1/4 R, 1/2 G, 1/4 B for
s = 2). Then

- L_ev's log signal is ``sum_d F_d log(I_d + eps)``: at full resolution the log of the pixel's own
  channel of the render (the render's mosaic); on a pooled pixel the mean of its sensor pixels'
  log changes, which is what its pooled (mean per sensor pixel) event count measures;
- L_blur and L_EDI against one-channel (raw mosaic) frames and latents compare ``sum_d F_d I_d``
  (``cfa_project``: the render's mosaic at full resolution, its block mean at 1/s, the block
  mean of the raw frame there); against RGB frames they compare RGB.

Without ``cfa`` a colour render's events are those of its luminance (``LUMA``, the channel mean).

Each loss below is written in torch as what it computes (the SSIM is kornia's). On CPU tensors the
same values and gradients come from ``ebad.kernels`` instead (numba passes with hand-written
adjoints, one autograd node each way), chosen in one place, ``ebad.kernels.use_kernels``; inside
``ebad.kernels.torch_reference()`` the torch code below runs everywhere (the kernels' tests
compare both).
"""

from __future__ import annotations

import typing
from collections.abc import Sequence

import torch
from kornia.metrics import ssim as _kornia_ssim
from torch import Tensor

from edi import LOG_EPS

from .config import (
    EventNorm,
)  # the norm of the L_ev residual: l1, mean |r| (ebad's default), or l2, mean r^2 (the paper's)
from .kernels import LUMA, use_kernels

__all__ = [
    "luminance",
    "cfa_weights",
    "cfa_project",
    "ssim_map",
    "ssim_map_kornia",
    "l1_ssim",
    "l1_ssim_each",
    "blur_loss",
    "exposure_losses",
    "event_loss",
    "edi_loss",
    "LUMA",
]


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


def cfa_weights(pattern: str, height: int, width: int, factor: int = 1, dtype=torch.float32) -> Tensor:
    """[height // factor, width // factor, 3]: the fraction of each pixel's sensor pixels behind the R,
    G and B filters of a Bayer ``pattern`` (``edi.cfa``), for frames ``factor`` times smaller than
    the ``height`` x ``width`` sensor (the top-left blocks, as ``ebad.data.downscale``): one-hot at
    factor 1; 1/4, 1/2, 1/4 on every 2 x 2 (or any even) block."""
    from edi.cfa import channel_map

    onehot = torch.nn.functional.one_hot(torch.from_numpy(channel_map(pattern, height, width)), 3).to(dtype)
    if factor == 1:
        return onehot
    pooled = torch.nn.functional.avg_pool2d(onehot.permute(2, 0, 1)[None], factor)[0]
    return pooled.permute(1, 2, 0).contiguous()


def cfa_project(img: Tensor, cfa: Tensor) -> Tensor:  # [..., H, W, 3] x [H, W, 3] -> [..., H, W, 1]
    """What a colour DAVIS's APS records of a (linear) RGB image: ``sum_d F_d img_d`` with the
    ``cfa_weights`` F, the image's mosaic at full resolution (``edi.cfa.mosaic``) and its block mean on
    downscaled frames."""
    if img.shape[-1] != 3 or tuple(cfa.shape) != (*img.shape[-3:-1], 3):
        raise ValueError(
            f"cfa_project needs [..., H, W, 3] and cfa [H, W, 3], got {tuple(img.shape)}, {tuple(cfa.shape)}"
        )
    return (img * cfa.to(img.dtype)).sum(-1, keepdim=True)


def _check_cfa(cfa: Tensor | None, H: int, W: int, D: int) -> None:
    if cfa is None:
        return
    if D != 3:
        raise ValueError(f"a cfa needs colour renders (D = 3), got D = {D}")
    if tuple(cfa.shape) != (H, W, 3):
        raise ValueError(f"cfa must be [H, W, 3] = {(H, W, 3)}, got {tuple(cfa.shape)}")


def _window_for(h: int, w: int, window: int) -> int:
    win = int(window)
    limit = 2 * min(h, w) - 1  # reflect padding needs H, W > window // 2
    if win > limit:
        win = max(1, limit if limit % 2 else limit - 1)
    return win


def _pair(a: Tensor, b: Tensor, names: tuple[str, str]) -> tuple[Tensor, Tensor, torch.dtype]:
    """Both as [B, H, W, D], checked to match, and the dtype a loss of them is computed in."""
    a = _bhwd(a, names[0])
    b = _bhwd(b, names[1])
    if a.shape != b.shape:
        raise ValueError(f"{names[0]} {tuple(a.shape)} and {names[1]} {tuple(b.shape)} differ in shape")
    dtype = a.dtype if a.dtype in (torch.float32, torch.float64) else torch.float32
    return a, b, dtype


def ssim_map(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """SSIM map with kornia's conventions (Gaussian window, sigma 1.5, reflect padding,
    c1 = 0.01^2, c2 = 0.03^2, eps 1e-12); gradients reach ``a`` and ``b``. The window shrinks to
    what reflect padding allows on images smaller than it.

    The reference is ``ssim_map_kornia``; on CPU tensors one fused kernel pass over the separable
    window computes it, with its adjoint as the backward (``ebad.kernels``). float32 and float64
    inputs are computed in their own precision; other dtypes in float32."""
    a, b, dtype = _pair(a, b, ("a", "b"))
    win = _window_for(a.shape[1], a.shape[2], window)
    if use_kernels(a, b):
        from .kernels import losses as fast

        return fast.ssim_map(a, b, win, dtype)
    return _ssim_kornia(a.to(dtype), b.to(dtype), win)


def _ssim_kornia(a: Tensor, b: Tensor, win: int) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """kornia.metrics.ssim itself, with a window of ``win`` taps (no clamp)."""
    return _kornia_ssim(a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2), win).permute(0, 2, 3, 1)


def ssim_map_kornia(a: Tensor, b: Tensor, window: int = 7) -> Tensor:  # [B,H,W,D] x2 -> [B,H,W,D]
    """The reference: kornia.metrics.ssim in [B, H, W, D] layout."""
    a = _bhwd(a, "a")
    b = _bhwd(b, "b")
    return _ssim_kornia(a, b, _window_for(a.shape[1], a.shape[2], window))


def l1_ssim(pred: Tensor, target: Tensor, ssim_weight: float = 0.2, window: int = 7) -> Tensor:
    """(1 - w) L1 + w (1 - SSIM), averaged over everything; [B,H,W,D] or [H,W,D] inputs. On CPU
    tensors both terms come from one kernel pass (and one for the gradient) when ``w`` > 0."""
    return l1_ssim_each([(pred, target)], ssim_weight, window)[0]


def l1_ssim_each(pairs: Sequence[tuple[Tensor, Tensor]], ssim_weight: float = 0.2, window: int = 7) -> list[Tensor]:
    """``l1_ssim`` of each (pred, target) pair, [B_i,H,W,D] or [H,W,D], all of one image size: on
    CPU tensors one kernel call for all of them (each call has a fixed cost)."""
    checked = [_pair(p, t, (f"pred {i}", f"target {i}")) for i, (p, t) in enumerate(pairs)]
    if ssim_weight == 0:
        return [(p - t).abs().mean() for p, t, _ in checked]
    sizes = {p.shape[1:] for p, _, _ in checked}
    if len(sizes) > 1:
        raise ValueError(f"pairs must share one image size [H, W, D], got {sorted(tuple(x) for x in sizes)}")
    dtype = checked[0][2]
    preds, targets = [p for p, _, _ in checked], [t for _, t, _ in checked]
    _, H, W, _ = preds[0].shape
    win = _window_for(H, W, window)
    if use_kernels(*preds, *targets):
        from .kernels import losses as fast

        return fast.l1_ssim_each(preds, targets, ssim_weight, win, dtype)
    return [_l1_ssim_torch(p.to(dtype), t.to(dtype), ssim_weight, win) for p, t in zip(preds, targets)]


def _l1_ssim_torch(pred: Tensor, target: Tensor, w: float, win: int) -> Tensor:  # [B,H,W,D] x2 -> []
    """The reference of ``l1_ssim``: (1 - w) mean |pred - target| + w (1 - mean SSIM)."""
    return (1 - w) * (pred - target).abs().mean() + w * (1 - _ssim_kornia(pred, target, win).mean())


def blur_loss(
    renders: Tensor,  # [V, H, W, D]
    blurry: Tensor,  # [H, W, D]
    ssim_weight: float = 0.2,
    window: int = 7,
) -> Tensor:
    """L_blur: the mean of the V virtual renders against the blurry frame."""
    if renders.ndim != 4:
        raise ValueError(f"renders must be [V, H, W, D], got {tuple(renders.shape)}")
    return l1_ssim(renders.mean(0), blurry, ssim_weight, window)


def event_loss(
    renders: Tensor,  # [V, H, W, D]
    counts: Tensor,  # [V - 1, 2, H, W] ON and OFF event counts
    c: float | tuple[float, float] | Tensor,
    eps: float | None = None,
    norm: EventNorm = "l1",
    cfa: Tensor | None = None,  # [H, W, 3] cfa_weights of a colour DAVIS (renders D = 3)
) -> Tensor:
    """L_ev: the mean over pixels and consecutive instants of |r| (``norm="l1"``) or r^2 (``"l2"``),
    r = l(t_{k+1}) - l(t_k) - (c_pos N_on,k - c_neg N_off,k).

    ``l`` is log L with ``L`` the render's luminance (the render itself when grey); with ``cfa``
    (the ``cfa_weights`` F of a colour DAVIS) ``l = sum_d F_d log(I_d + eps)``, the log of each pixel's
    own channel (the module docstring). ``c`` one threshold or the pair (c_pos, c_neg) (a float, a
    2-tuple, or a tensor of one or two values, differentiable). L1 is ebad's default (robust to
    noise events), L2 the paper's; one window (t_i, t_j) is
    ``event_loss(renders[[i, j]], virtual_views.window_counts(counts, i, j), c)``.
    """
    if norm not in typing.get_args(EventNorm):
        raise ValueError(f"norm must be one of {typing.get_args(EventNorm)}, got {norm!r}")
    V = renders.shape[0]
    if counts.shape != (V - 1, 2) + tuple(renders.shape[1:3]):
        raise ValueError(
            f"counts must be [V - 1, 2, H, W] = {(V - 1, 2) + tuple(renders.shape[1:3])}, got {tuple(counts.shape)}"
        )
    _check_cfa(cfa, renders.shape[1], renders.shape[2], renders.shape[3])
    if V < 2:
        return renders.sum() * 0.0
    eps = LOG_EPS if eps is None else eps
    L = luminance(renders)[..., 0] if cfa is None else renders  # [V, H, W] or [V, H, W, 3]
    if L.dtype not in (torch.float32, torch.float64):
        L = L.float()
    cc = torch.as_tensor(c, dtype=L.dtype).reshape(-1)
    counts = counts.to(L.dtype)
    F = None if cfa is None else cfa.to(L.dtype)
    if use_kernels(L, counts, cc, F):
        from .kernels import losses as fast

        return fast.event_loss(L, counts, cc[0], cc[-1], float(eps), norm == "l2", F)
    log_L = torch.log(L.clamp_min(0) + eps)  # a negative render (no light) counts as 0
    if F is not None:
        log_L = (log_L * F).sum(-1)  # each pixel's own channel (the fractions of a pooled block)
    r = log_L[1:] - log_L[:-1] - (cc[0] * counts[:, 0] - cc[-1] * counts[:, 1])  # [V - 1, H, W]
    return r.abs().mean() if norm == "l1" else r.square().mean()


def edi_loss(
    renders: Tensor,  # [H, W, D] or [V, H, W, D]
    latents: Tensor,  # the same shape
    ssim_weight: float = 0.2,
    window: int = 7,
) -> Tensor:
    """L_EDI: renders against the EDI latents of the frame at the same instants (the mid-exposure
    render and latent, or every virtual view's), averaged over them."""
    return l1_ssim(renders, latents, ssim_weight, window)


def exposure_losses(
    images: Tensor,  # [V', H, W, D] one exposure's renders (irradiance), its V virtual views first
    V: int,
    blurry: Tensor,  # [H, W, D] L_blur's target ([H, W, 1] raw mosaic with a cfa)
    latents: Tensor | None = None,  # [H, W, D] (against images[mid]) or [V, H, W, D] (against images[:V])
    mid: int | None = None,  # index in images of the render compared with a [H, W, D] latent
    counts: Tensor | None = None,  # [E - 1, 2, H, W] ON / OFF counts between consecutive event_views
    event_views: Sequence[int] = (),  # the E indices in images of L_ev's instants, in time order
    c: float | tuple[float, float] | Tensor = 0.2,
    ssim_weight: float = 0.2,
    window: int = 7,
    eps: float | None = None,
    norm: EventNorm = "l1",
    cfa: Tensor | None = None,  # [H, W, 3] cfa_weights of a colour DAVIS (images D = 3)
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor]:
    """L_blur, L_EDI and L_ev of one exposure's renders, for a linear response: the reference is
    ``blur_loss(images[:V], blurry)``, ``edi_loss(images[mid], latents)`` (or ``edi_loss(images[:V],
    latents)`` for a latent per view) and ``event_loss(images[event_views], counts, c, cfa=cfa)``.
    With ``cfa`` and one-channel (raw mosaic) ``blurry`` and ``latents``, L_blur and L_EDI compare
    ``cfa_project(images, cfa)`` (the renders' mosaic) with them instead of ``images``.

    On CPU tensors the kernels give the same values and gradients in ONE autograd node, from one
    L1 + SSIM kernel pass over every compared image and one L_ev pass, with the gradient of
    ``images`` written into one array: composed from torch operations, the slices, the mean and
    the stacks of the renders each added a full-size temporary and its backward to a training
    step. L_EDI is None without ``latents``, L_ev None with fewer than two ``event_views``; ``c``
    as ``event_loss`` (differentiable).
    Returns (L_blur, L_EDI, L_ev, the mean of the V renders [H, W, D] (projected with a raw mosaic), detached)."""
    if images.ndim != 4 or images.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"images must be float32 or float64 [V', H, W, D], got {images.dtype} {tuple(images.shape)}")
    Vp, H, W, D = images.shape
    if not 1 <= V <= Vp:
        raise ValueError(f"V must be in [1, {Vp}] (the renders given), got {V}")
    _check_cfa(cfa, H, W, D)
    project = cfa is not None and blurry.ndim == 3 and blurry.shape[-1] == 1  # raw mosaic targets
    Dt = 1 if project else D  # the channels of the targets
    if tuple(blurry.shape) != (H, W, Dt):
        raise ValueError(f"blurry must be [H, W, D] = {(H, W, Dt)}, got {tuple(blurry.shape)}")
    views = latents is not None and latents.ndim == 4
    if latents is not None:
        want = (V, H, W, Dt) if views else (H, W, Dt)
        if tuple(latents.shape) != want:
            raise ValueError(f"latents must be [H, W, D] or [V, H, W, D] = {(V, H, W, Dt)}, got {tuple(latents.shape)}")
        if not views and (mid is None or not 0 <= mid < Vp):
            raise ValueError(f"mid must index one of the {Vp} renders when latents is [H, W, D], got {mid}")
    event_views = tuple(int(i) for i in event_views)
    if len(event_views) >= 2:
        if counts is None or tuple(counts.shape) != (len(event_views) - 1, 2, H, W):
            raise ValueError(
                f"counts must be [E - 1, 2, H, W] = {(len(event_views) - 1, 2, H, W)}, "
                f"got {None if counts is None else tuple(counts.shape)}"
            )
        if len(set(event_views)) != len(event_views) or not all(0 <= i < Vp for i in event_views):
            raise ValueError(f"event_views must be distinct indices of the {Vp} renders, got {event_views}")
    if norm not in typing.get_args(EventNorm):
        raise ValueError(f"norm must be one of {typing.get_args(EventNorm)}, got {norm!r}")
    cc = torch.as_tensor(c, dtype=images.dtype).reshape(-1)
    win = _window_for(H, W, window)
    eps = LOG_EPS if eps is None else float(eps)
    F = None if cfa is None else cfa.to(images.dtype)
    if use_kernels(images, blurry, latents, counts, cc, F):
        from .kernels import losses as fast

        return fast.exposure_losses(
            images,
            V,
            blurry,
            latents,
            mid,
            counts,
            event_views,
            cc[0],
            cc[-1],
            win,
            ssim_weight,
            eps,
            norm == "l2",
            F,
            project,
        )
    compared = cfa_project(images, F) if project and F is not None else images
    blur = blur_loss(compared[:V], blurry, ssim_weight, window)
    edi = None if latents is None else edi_loss(compared[:V] if views else compared[mid], latents, ssim_weight, window)
    ev = None
    if len(event_views) >= 2:
        assert counts is not None  # checked above
        ev = event_loss(images[list(event_views)], counts, cc, eps, norm, F)
    return blur, edi, ev, compared[:V].mean(0).detach()
