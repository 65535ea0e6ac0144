"""Issue 30 item 5: the viewer hides the frustums of the cameras near the browser's camera (seen from among
them, as from the first camera of a slider, they cross the whole view as lines) and shows them from afar."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from ebad.runfolder import load_run
from tests.ebad.cli.test_view import _free_loopback_port


def test_frustum_depth_is_vipers():
    from ebad.cli.view import frustum_depth

    # viser's CameraFrustum: (tan(fov/2) aspect, tan(fov/2), 1) / cbrt(tan^2(fov/2) aspect / 3), times scale
    assert frustum_depth(0.5, math.pi / 2, 3.0) == pytest.approx(0.5)  # tan 1, volume 1
    assert frustum_depth(1.0, 2 * math.atan(0.5), 4 / 3) == pytest.approx((4 / 3 * 0.25 / 3) ** (-1 / 3))
    assert frustum_depth(1.0, 2 * math.atan(0.5), 4 / 3) == pytest.approx(9 ** (1 / 3))


def test_frustums_near_the_browser_camera_are_hidden(tiny_run):
    viser = pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    from ebad.cli.view import NEARBY_DEPTHS, build_scene, exposure_poses, frustum_depth, hide_nearby

    run = load_run(tiny_run.run)
    mid = exposure_poses(run.trajectories)[0]
    server = viser.ViserServer(host="127.0.0.1", port=_free_loopback_port(), verbose=False)
    try:
        views = [SimpleNamespace(name="far", c2w=mid[0].copy())]
        views[0].c2w[:3, 3] += 100.0  # a test camera far from every training camera
        handles = build_scene(server, run, views)
        fov = 2 * math.atan(0.5 * run.height / float(run.K[1, 1]))
        radius = NEARBY_DEPTHS * frustum_depth(handles["geometry"]["scale"], fov, run.width / run.height)
        assert handles["nearby"] == pytest.approx(radius)
        dist = np.linalg.norm(mid[:, :3, 3] - mid[0, :3, 3], axis=1)
        # the first view (camera 0): its own frustum and its neighbours' hidden, the others shown
        assert [f.visible for f in handles["train"]] == list(dist >= radius)
        assert not handles["train"][0].visible and handles["test"][0].visible
        assert dist.max() == pytest.approx(2.0175, abs=1e-3) and radius == pytest.approx(4.9969, abs=1e-3)
        # the browser's camera moves far away: every frustum shows; back among them: hidden again
        hide_nearby(handles, mid[0, :3, 3] + 50.0)
        assert all(f.visible for f in handles["train"] + handles["test"])
        hide_nearby(handles, views[0].c2w[:3, 3])
        assert not handles["test"][0].visible and all(f.visible for f in handles["train"])
        # a browser's camera message moves them (the callback build_scene registers for each client)
        client = SimpleNamespace(
            camera=SimpleNamespace(on_update=lambda cb: cb(SimpleNamespace(position=mid[0, :3, 3])))
        )
        for cb in server._client_connect_cb:
            cb(client)
        assert not handles["train"][0].visible and handles["test"][0].visible
    finally:
        server.stop()
