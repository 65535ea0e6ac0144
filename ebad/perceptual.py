"""LPIPS (Zhang et al. 2018) where its weights are on this machine, else the reason it is absent.

The PyPI ``lpips`` package ships only the small linear heads (``lpips/weights/v0.1/alex.pth``
6 KB, ``vgg.pth`` 7 KB, ``squeeze.pth`` 11 KB); the ImageNet backbones come from torchvision,
which downloads them on first use into torch.hub's cache (``torch.hub.get_dir()/checkpoints``).
Offline that download fails, so ``lpips_or_none`` never triggers it: it computes LPIPS only
when the lpips package, torchvision and the backbone file are all present, and otherwise
returns ``None`` with the reason. It raises only for a wrong argument.

Convention: LPIPS was trained on display-referred photographs in [-1, 1], RGB. The images ebad
scores are in the capture's recorded domain (the camera's response applied, ``ebad.export``), i.e.
already display values like the frames and test images: they are mapped to [-1, 1] as they are,
with no second transfer curve, and a grey image is repeated into three channels (the network
needs RGB).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

from .errors import UserError

__all__ = ["lpips_or_none", "lpips_status", "BACKBONE_FILES"]

# torchvision's ImageNet checkpoints that lpips.LPIPS(net=...) loads
BACKBONE_FILES = {
    "alex": "alexnet-owt-7be5be79.pth",
    "vgg": "vgg16-397923af.pth",
    "squeeze": "squeezenet1_1-b8a52dc0.pth",
}
INSTALL_LPIPS = "pip install lpips torchvision"


def _check_net(net: str) -> None:
    if net not in BACKBONE_FILES:
        raise UserError(f"LPIPS net must be one of {sorted(BACKBONE_FILES)}, got {net!r}")


def lpips_status(net: str = "alex") -> str | None:
    """None when LPIPS with backbone ``net`` can be computed offline, else why not."""
    _check_net(net)
    try:
        import lpips  # noqa: F401
    except ImportError:
        return f"LPIPS absent: the lpips package is not installed ({INSTALL_LPIPS})"
    try:
        import torchvision  # noqa: F401
    except ImportError:
        return f"LPIPS absent: lpips needs torchvision for its {net} backbone ({INSTALL_LPIPS})"
    ckpt = Path(torch.hub.get_dir()) / "checkpoints" / BACKBONE_FILES[net]
    if not ckpt.is_file():
        return (
            f"LPIPS absent: the {net} backbone weights are not in the local cache ({ckpt}); the lpips "
            "package ships only its linear heads and torchvision downloads the backbone on first use, "
            "which needs the network once"
        )
    return None


@lru_cache(maxsize=len(BACKBONE_FILES))
def _model(net: str):
    import lpips

    return lpips.LPIPS(net=net, pretrained=True, verbose=False).eval()


def _to_lpips_input(x) -> torch.Tensor:  # [H, W, D] or [B, H, W, D] recorded [0, 1] -> [B, 3, H, W] in [-1, 1]
    a = np.asarray(x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else x, dtype=np.float64)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4 or a.shape[-1] not in (1, 3):
        raise ValueError(f"images must be [H, W, 1|3] or [B, H, W, 1|3], got {a.shape}")
    t = torch.from_numpy(np.clip(a, 0.0, 1.0)).float().permute(0, 3, 1, 2)
    if t.shape[1] == 1:
        t = t.expand(-1, 3, -1, -1)
    return t * 2 - 1


def lpips_or_none(pred, target, net: str = "alex") -> tuple[float | None, str | None]:
    """Mean LPIPS of ``pred`` against ``target`` ([H, W, D] or [B, H, W, D], recorded values in [0, 1]),
    as ``(value, None)``, or ``(None, reason)`` when the weights are not available offline."""
    reason = lpips_status(net)
    p, t = _to_lpips_input(pred), _to_lpips_input(target)
    if p.shape != t.shape:
        raise ValueError(f"pred {tuple(p.shape)} and target {tuple(t.shape)} differ in shape")
    if reason is not None:
        return None, reason
    with torch.no_grad():
        return float(_model(net)(p, t).mean()), None
