"""Issue 30 item 5: the viewer's first view is the first training camera's, a click on a camera flies
there, and a slider moves the view along a recovered exposure trajectory."""

from __future__ import annotations

import contextlib
import math
import socket
from types import SimpleNamespace

import numpy as np
import pytest

from ebad.runfolder import load_run


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Camera:
    """Stands in for a viser ``CameraHandle``: position moves the look-at point along, as viser's does."""

    def __init__(self):
        self.position = np.zeros(3)
        self.look_at = np.array([0.0, 0.0, 1.0])
        self.up_direction = np.array([0.0, -1.0, 0.0])
        self.fov = 1.0


def _client():
    return SimpleNamespace(camera=_Camera(), atomic=contextlib.nullcontext)


def _assert_at(camera, c2w: np.ndarray, K: np.ndarray, height: int) -> None:
    """The browser camera sits at ``c2w``'s centre, looks down its optical axis, with its up and field of view."""
    np.testing.assert_allclose(camera.position, c2w[:3, 3], atol=1e-9)
    ahead = np.asarray(camera.look_at) - np.asarray(camera.position)
    np.testing.assert_allclose(ahead / np.linalg.norm(ahead), c2w[:3, 2], atol=1e-9)
    np.testing.assert_allclose(camera.up_direction, -c2w[:3, 1], atol=1e-9)
    assert camera.fov == pytest.approx(2 * math.atan(0.5 * height / K[1, 1]))


def test_camera_view_is_the_cameras_own():
    from ebad.cli.view import camera_view

    c2w = np.eye(4)
    c2w[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # optical axis (column z) along world +x, image y along +z
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    v = camera_view(c2w, K, 48, 2.0)
    np.testing.assert_allclose(v["position"], [1, 2, 3])
    np.testing.assert_allclose(v["look_at"], [1 + 2.0, 2, 3])  # 2 ahead on the optical axis (column z = world x)
    np.testing.assert_allclose(v["up"], [0, 0, -1])  # -y column
    assert v["fov"] == pytest.approx(2 * math.atan(24 / 50))  # vertical
    assert v["fov"] == pytest.approx(0.895040, abs=1e-6)
    assert np.isfinite(camera_view(c2w, K, 48, 0.0)["look_at"]).all()  # never a zero look distance


def test_first_view_click_and_slider(tiny_run, monkeypatch):
    viser = pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    from ebad.cli.view import build_scene, exposure_poses

    run = load_run(tiny_run.run)
    mid, poses = exposure_poses(run.trajectories)
    server = viser.ViserServer(host="127.0.0.1", port=_free_loopback_port(), verbose=False)
    try:
        handles = build_scene(server, run)
        # the first view: the first training camera at mid-exposure, its vertical field of view
        ic = server.initial_camera
        first = SimpleNamespace(position=ic.position, look_at=ic.look_at, up_direction=ic.up, fov=ic.fov)
        _assert_at(first, mid[0], run.K, run.height)
        assert np.isfinite(np.asarray(ic.look_at)).all() and not np.allclose(ic.look_at, ic.position)
        # a click on camera 2's frustum flies the clicking browser there
        client = _client()
        frustum = handles["train"][2]
        assert len(frustum._impl.click_cb) == 1
        frustum._impl.click_cb[0].callback(SimpleNamespace(client=client, target=frustum))
        _assert_at(client.camera, mid[2], run.K, run.height)
        # the trajectory choice and the exposure-instant slider move every browser along that trajectory
        monkeypatch.setattr(server, "get_clients", lambda: {0: client})
        assert handles["instant"].max == poses.shape[1] - 1 and handles["instant"].value == poses.shape[1] // 2
        handles["frame"].value = run.names[1]
        _assert_at(client.camera, poses[1, poses.shape[1] // 2], run.K, run.height)
        handles["instant"].value = 0
        _assert_at(client.camera, poses[1, 0], run.K, run.height)  # the exposure's start
        handles["instant"].value = poses.shape[1] - 1
        _assert_at(client.camera, poses[1, -1], run.K, run.height)  # its end
        assert not np.allclose(poses[1, 0, :3, 3], poses[1, -1, :3, 3])  # the slider did move the camera
    finally:
        server.stop()
