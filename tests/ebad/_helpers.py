"""Small builders shared by the ebad tests."""

from __future__ import annotations

import torch

from ebad.lie import so3_exp


def random_c2w(F: int, seed: int = 0) -> torch.Tensor:  # -> [F, 4, 4] float32
    """F random rigid camera-to-world poses (rotation vectors and positions ~ N(0, 1))."""
    g = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4).repeat(F, 1, 1)
    c2w[:, :3, :3] = so3_exp(torch.randn(F, 3, generator=g))
    c2w[:, :3, 3] = torch.randn(F, 3, generator=g)
    return c2w
