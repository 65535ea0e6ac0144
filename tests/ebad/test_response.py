"""ebad.response: the camera response curve."""

from __future__ import annotations

import pytest
import torch

from ebad.response import Response


def test_linear_is_the_identity_and_gamma_starts_there():
    x = torch.linspace(0, 1, 50)[:, None]
    assert torch.equal(Response("linear")(x), x)
    r = Response("gamma")
    assert torch.allclose(r(x), x, atol=1e-5)
    v = r.values()
    assert v["gain"] == pytest.approx(1.0) and v["gamma"] == pytest.approx(1.0) and v["black"] < 1e-5


def test_gamma_is_monotone_and_saturates():
    r = Response("gamma")
    with torch.no_grad():
        r.raw.copy_(torch.tensor([0.0, 0.3, -0.4]))  # black 0.25, gain 1.35, gamma 0.67
    x = torch.linspace(0, 2, 400)
    y = r(x).detach()
    assert bool((y[1:] >= y[:-1]).all())
    assert y[-1] == pytest.approx(1.0) and y[0] == pytest.approx(r.values()["black"], abs=1e-3)


def test_fitting_recovers_a_known_curve():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2000, generator=g) * 0.9
    truth = 0.04 + 0.96 * (1.25 * x).clamp(max=1) ** 0.75
    r = Response("gamma")
    opt = torch.optim.Adam(r.parameters(), lr=0.05)
    for _ in range(400):
        opt.zero_grad()
        ((r(x) - truth) ** 2).mean().backward()
        opt.step()
    v = r.values()
    assert v["gamma"] == pytest.approx(0.75, rel=0.05) and v["gain"] == pytest.approx(1.25, rel=0.05)
    assert v["black"] == pytest.approx(0.04, abs=0.01)


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="response kind"):
        Response("spline")
