"""``ebad view`` shows view-dependent colour: the splats' colours follow the browser's camera (SH evaluated
toward it, the response applied), throttled."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from ebad.cli.view import VIEW_COLOUR_INTERVAL, ViewColours, follow_view_colours, view_colors
from ebad.export import recorded_colors
from ebad.gaussians import render
from ebad.response import Response


def _params(n: int = 4, D: int = 3, degree: int = 3) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return {
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
        "scales": torch.full((n, 3), math.log(0.05)),
        "opacities": torch.full((n,), 12.0),  # alpha 0.999 (the rasteriser's cap) at the centre
        "colors": torch.randn(n, D, generator=g) * 0.5,
        "sh_rest": torch.randn(n, (degree + 1) ** 2 - 1, D, generator=g) * 0.2,
    }


def _look_at(centre: np.ndarray, target: np.ndarray) -> torch.Tensor:  # [4, 4] c2w, OpenCV axes
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(np.array([0.0, -1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = centre
    return torch.from_numpy(c2w).float()


@pytest.mark.parametrize("D", [3, 1])
def test_view_colours_are_what_ebad_gaussians_renders_from_that_centre(D):
    p = _params(D=D)
    centre = np.array([0.3, -0.2, -4.0])
    K = torch.tensor([[20.0, 0.0, 4.5], [0.0, 20.0, 4.5], [0.0, 0.0, 1.0]])  # pixel (4, 4) sees the optical axis
    seen = []
    for n in range(len(p["means"])):  # each Gaussian alone, at the image centre of a camera looking at it
        one = {k: v[n : n + 1] for k, v in p.items()}
        img, _, _ = render(one, _look_at(centre, one["means"][0].double().numpy())[None], K, 9, 9)
        seen.append(img[0, 4, 4].double().numpy() / 0.999)  # alpha 0.999 over a black background
    seen = np.repeat(np.stack(seen), 3 // D, 1)
    np.testing.assert_allclose(view_colors(p, centre), np.clip(seen, 0, 1), atol=2e-5)
    r = Response("gamma")
    with torch.no_grad():
        r.raw.copy_(torch.tensor([math.log(0.04 / 0.46), math.log(1.25), math.log(0.75)]))
    np.testing.assert_allclose(view_colors(p, centre, r), recorded_colors(seen, r), atol=2e-5)
    # another centre sees other colours (view-dependent), and a model of DC colours only the DC
    assert np.abs(view_colors(p, -centre) - view_colors(p, centre)).max() > 0.05
    dc = {k: v for k, v in p.items() if k != "sh_rest"}
    want = np.repeat(np.clip(0.5 + 0.28209479177387814 * dc["colors"].numpy(), 0, 1), 3 // D, 1)
    np.testing.assert_allclose(view_colors(dc, centre), want, atol=1e-6)


def test_recolouring_is_throttled_and_only_when_the_camera_moved():
    p = _params()
    now = [0.0]
    splats = SimpleNamespace(rgbs=None)
    vc = ViewColours({"splats": splats}, SimpleNamespace(params=p), clock=lambda: now[0])
    assert not vc.step()  # no camera yet
    vc.request([0.0, 0.0, -4.0])
    assert vc.step() and vc.updates == 1
    np.testing.assert_array_equal(splats.rgbs, view_colors(p, [0.0, 0.0, -4.0]))
    vc.request([0.0, 0.0, -4.0])  # the same position again: nothing to do
    now[0] += 10.0
    assert not vc.step() and vc.updates == 1
    vc.request([1.0, 0.0, -4.0])  # a move
    assert vc.step() and vc.updates == 2
    vc.request([2.0, 0.0, -4.0])  # a move within the interval waits ...
    vc.request([3.0, 0.0, -4.0])  # ... and only the last position of a burst is shown
    now[0] += 0.5 * VIEW_COLOUR_INTERVAL
    assert not vc.step() and vc.updates == 2
    now[0] += 0.5 * VIEW_COLOUR_INTERVAL
    assert vc.step() and vc.updates == 3
    np.testing.assert_array_equal(splats.rgbs, view_colors(p, [3.0, 0.0, -4.0]))


def test_the_viewer_follows_each_connecting_browsers_camera():
    p = _params()
    connected = []
    server = SimpleNamespace(on_client_connect=connected.append)
    assert (
        follow_view_colours(server, {}, SimpleNamespace(params={k: v for k, v in p.items() if k != "sh_rest"})) is None
    )
    assert not connected  # DC colours only: nothing to follow
    splats = SimpleNamespace(rgbs=None)
    vc = follow_view_colours(server, {"splats": splats}, SimpleNamespace(params=p))
    try:
        callbacks = []
        connected[0](SimpleNamespace(camera=SimpleNamespace(on_update=callbacks.append)))
        callbacks[0](SimpleNamespace(position=np.array([0.5, 0.0, -4.0])))
        for _ in range(200):  # the timer thread recolours within an interval or two
            if vc.updates:
                break
            time.sleep(0.01)
        assert vc.updates == 1
        np.testing.assert_array_equal(splats.rgbs, view_colors(p, [0.5, 0.0, -4.0]))
    finally:
        vc.stop()
