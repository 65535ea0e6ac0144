"""LPIPS where the weights are local; otherwise None with the reason, never a crash."""

from __future__ import annotations

import sys
import types
from typing import ClassVar

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


class _StubLPIPS(torch.nn.Module):
    """Stands in for ``lpips.LPIPS``: records what it is given and returns a known distance per
    image (the mean squared difference), [B, 1, 1, 1] as lpips does."""

    calls: ClassVar[list] = []

    def __init__(self, net="alex", pretrained=True, verbose=True):
        super().__init__()
        self.net, self.pretrained = net, pretrained
        _StubLPIPS.calls.append(("init", net, pretrained))

    def forward(self, a, b):
        _StubLPIPS.calls.append(("forward", a.clone(), b.clone(), torch.is_grad_enabled()))
        return ((a - b) ** 2).mean(dim=(1, 2, 3), keepdim=True)


@pytest.fixture
def stub_lpips(monkeypatch, tmp_path):
    """The lpips path end to end without its weights: stub lpips and torchvision modules and an
    (empty) backbone file in a temporary torch.hub cache. CI cannot run the real one: the test
    extras install neither lpips nor torchvision, and torchvision downloads the ImageNet backbone
    (alexnet 233 MB) on first use, which needs the network (``test_lpips_when_available`` runs it
    where the weights are cached)."""
    from ebad import perceptual

    mod = types.ModuleType("lpips")
    mod.LPIPS = _StubLPIPS
    monkeypatch.setitem(sys.modules, "lpips", mod)
    monkeypatch.setitem(sys.modules, "torchvision", types.ModuleType("torchvision"))
    old = torch.hub.get_dir()
    torch.hub.set_dir(str(tmp_path))
    for name in BACKBONE_FILES.values():
        (tmp_path / "checkpoints").mkdir(exist_ok=True)
        (tmp_path / "checkpoints" / name).write_bytes(b"")
    perceptual._model.cache_clear()
    _StubLPIPS.calls = []
    yield _StubLPIPS.calls
    perceptual._model.cache_clear()
    torch.hub.set_dir(old)


@pytest.mark.parametrize("D", [1, 3])
def test_lpips_path_feeds_the_network_the_recorded_values_rgb_in_minus_one_to_one(stub_lpips, D):
    """The images are already display values (the capture's recorded domain): no second curve."""
    a, b = _imgs(D=D)
    assert lpips_status("alex") is None
    value, reason = lpips_or_none(a, b)
    assert reason is None
    (_, net, pretrained), (_, ta, tb, grad) = stub_lpips
    assert net == "alex" and pretrained and not grad
    assert ta.shape == tb.shape == (1, 3, 16, 20) and ta.dtype == torch.float32
    for t, x in ((ta, a), (tb, b)):
        want = torch.from_numpy(2 * x - 1).float().permute(2, 0, 1)  # [D, H, W], values as they are
        assert torch.allclose(t[0], want.expand(3, -1, -1), atol=1e-6)  # grey repeated into R, G and B
    assert -1 <= float(ta.min()) and float(ta.max()) <= 1
    assert value == pytest.approx(float(((ta - tb) ** 2).mean()), rel=1e-6)


def test_lpips_path_averages_a_batch_and_builds_each_network_once(stub_lpips):
    a, b = _imgs(D=3)
    batch_a, batch_b = np.stack([a, a, b]), np.stack([b, a, a])
    value, _ = lpips_or_none(batch_a, batch_b)
    first = lpips_or_none(a, b)[0]
    assert value == pytest.approx(2 / 3 * first, rel=1e-6)  # one of three pairs is identical
    lpips_or_none(torch.from_numpy(a), torch.from_numpy(b), net="vgg")  # tensors too
    assert [c[1] for c in stub_lpips if c[0] == "init"] == ["alex", "vgg"]
