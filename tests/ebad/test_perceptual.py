"""LPIPS where the weights are local; otherwise None with the reason, never a crash."""
from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from ebad.errors import EbadError
from ebad.perceptual import BACKBONE_FILES, lpips_or_none, lpips_status


def _imgs(seed=0, D=1):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 1, (16, 20, D)), rng.uniform(0, 1, (16, 20, D))


def test_missing_lpips_package_gives_the_reason(monkeypatch):
    monkeypatch.setitem(sys.modules, "lpips", None)  # import fails as if not installed
    value, reason = lpips_or_none(*_imgs())
    assert value is None and "lpips package is not installed" in reason and "pip install" in reason


def test_missing_torchvision_gives_the_reason(monkeypatch):
    monkeypatch.setitem(sys.modules, "lpips", types.ModuleType("lpips"))
    monkeypatch.setitem(sys.modules, "torchvision", None)
    value, reason = lpips_or_none(*_imgs())
    assert value is None and "torchvision" in reason


@pytest.mark.parametrize("net", sorted(BACKBONE_FILES))
def test_missing_backbone_weights_give_the_reason_without_download(monkeypatch, tmp_path, net):
    monkeypatch.setitem(sys.modules, "lpips", types.ModuleType("lpips"))
    monkeypatch.setitem(sys.modules, "torchvision", types.ModuleType("torchvision"))
    old = torch.hub.get_dir()
    torch.hub.set_dir(str(tmp_path))  # an empty cache
    try:
        value, reason = lpips_or_none(*_imgs(D=3), net=net)
    finally:
        torch.hub.set_dir(old)
    assert value is None and BACKBONE_FILES[net] in reason and str(tmp_path) in reason


def test_bad_arguments_raise():
    with pytest.raises(EbadError, match="net"):
        lpips_or_none(*_imgs(), net="resnet")
    a, b = _imgs()
    with pytest.raises(ValueError, match="shape"):
        lpips_or_none(a, b[:8])


def test_lpips_when_available():
    reason = lpips_status("alex")
    if reason is not None:
        pytest.skip(reason)
    a, b = _imgs(D=3)
    same, _ = lpips_or_none(a, a)
    diff, _ = lpips_or_none(a, b)
    assert same == pytest.approx(0.0, abs=1e-6) and diff > 0.05
