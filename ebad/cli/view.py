"""``ebad view RUN``: an interactive 3D viewer of a run in the web browser (viser).

Shows the Gaussians (drawn by the browser with WebGL, so the server needs no GPU), every
training camera as a frustum at its mid-exposure pose (blue) with its recovered exposure
trajectory as a polyline of camera centres (red, start to end), and, with ``--capture``,
the capture's test views (green frustums).

The server listens on ``--host`` (default 127.0.0.1, this machine only) port ``--port``
(default 8080); open http://localhost:8080. On a remote machine, forward the port over
SSH from your own computer and open the same address there::

    ssh -L 8080:localhost:8080 user@remote-host

``--host 0.0.0.0`` serves every network interface instead (anyone who can reach the port
sees the scene). viser's Share button (a public tunnel through share.viser.studio) is off, and a
client's share request is refused. A ``--host`` this machine cannot resolve or listen on is one
error line (exit 2). Needs ``viser``: ``pip install viser`` (or the ``view`` extra). Stop with Ctrl-C.
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass
from typing import Annotated

import numpy as np
import tyro

from ..errors import UserError

NAME = "view"
HELP = "interactive 3D viewer of a run in the browser (viser): Gaussians, cameras, exposure trajectories"

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
INSTALL_VIEW = "pip install viser (or the 'view' extra)"
TRAJECTORY_SAMPLES = 9  # camera centres per exposure polyline
FRUSTUM_FRACTION = 0.15  # frustum depth as a fraction of the camera spread (or the scene extent)
BACK_OFF = 0.6  # the initial view sits this fraction of the camera-to-scene distance behind the cameras
LINE_PIXELS = 2.0  # frustum and trajectory line width, screen pixels
TRAIN_COLOR = (40, 90, 220)
TRAJECTORY_COLOR = (220, 40, 40)
TEST_COLOR = (30, 170, 60)


@dataclass
class Args:
    run: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="RUN")]
    """run folder written by 'ebad reconstruct'"""
    capture: str | None = None
    """capture whose test views to show"""
    host: str = DEFAULT_HOST
    (
        "interface to listen on (127.0.0.1: this machine only; from another computer, forward the port with "
        "'ssh -L 8080:localhost:8080 HOST' and open http://localhost:8080 there; 0.0.0.0: every interface, anyone who "
        "can reach the port sees the scene)"
    )
    port: int = DEFAULT_PORT
    """port"""


def import_viser():
    """The ``viser`` module, or a UserError naming the install command."""
    try:
        import viser
    except ImportError:
        raise UserError(f"'ebad view' needs the viser package: {INSTALL_VIEW}") from None
    return viser


def splat_arrays(params, response=None) -> dict[str, np.ndarray]:
    """viser's Gaussian-splat inputs from model parameters: centres [N, 3], covariances
    [N, 3, 3] = R diag(s^2) R^T, colours [N, 3] in the capture's recorded domain (through the camera
    ``response``, None: the identity; the ``.splat``'s colours; grey repeated), opacities [N, 1]."""
    import torch

    from ..export import recorded_colors
    from ..gaussians import activate
    from ..lie import quat_to_rotmat

    with torch.no_grad():
        act = activate(params)
        R = quat_to_rotmat(act["quats"].double())
        cov = R @ torch.diag_embed(act["scales"].double() ** 2) @ R.transpose(-1, -2)
    colors = act["colors"].detach().double().numpy()
    if colors.shape[1] == 1:
        colors = np.repeat(colors, 3, axis=1)
    return {
        "centers": act["means"].detach().numpy().astype(np.float32),
        "covariances": cov.numpy().astype(np.float32),
        "rgbs": recorded_colors(colors, response).astype(np.float32),
        "opacities": act["opacities"].detach().numpy().astype(np.float32)[:, None],
    }


def _frustum(
    server,
    name: str,
    c2w: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    scale: float,
    color: tuple[int, int, int],
):
    from ..export import rotmat_to_quat

    fov = 2 * math.atan(0.5 * height / float(K[1, 1]))  # vertical
    return server.scene.add_camera_frustum(
        name,
        fov=fov,
        aspect=width / height,
        scale=scale,
        color=color,
        thickness=LINE_PIXELS,
        thickness_units="screen",
        wxyz=rotmat_to_quat(c2w[:3, :3]),
        position=c2w[:3, 3],
    )


def build_scene(server, run, test_views=()) -> dict:
    """Add the run's Gaussians, training cameras, exposure trajectories and ``test_views``
    (objects with ``name`` and ``c2w``) to a viser server; returns the scene handles."""
    mid = run.trajectories.mid_poses().numpy().astype(np.float64)  # [F, 4, 4]
    poses, _ = run.exposure_poses(TRAJECTORY_SAMPLES)  # [F, S, 4, 4]
    arrays = splat_arrays(run.params, run.response)
    centres = mid[:, :3, 3]
    target = np.median(arrays["centers"], axis=0).astype(np.float64) if len(arrays["centers"]) else centres.mean(0)
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) if len(centres) > 1 else 0.0
    reach = float(np.linalg.norm(centres.mean(0) - target))
    scale = FRUSTUM_FRACTION * max(spread, reach, 1e-3)

    up = -mid[:, :3, 1].mean(0)  # OpenCV: y points down in the image
    up = up / max(np.linalg.norm(up), 1e-12)
    server.scene.set_up_direction(up)
    handles = {"splats": server.scene.add_gaussian_splats("/gaussians", **arrays), "train": [], "test": []}
    for f, name in enumerate(run.names):
        handles["train"].append(
            _frustum(server, f"/train/{name}", mid[f], run.K, run.width, run.height, scale, TRAIN_COLOR)
        )
    segments = np.stack([poses[:, :-1, :3, 3], poses[:, 1:, :3, 3]], axis=2).reshape(-1, 2, 3)  # [F*(S-1), 2, 3]
    handles["trajectories"] = server.scene.add_line_segments(
        "/trajectories",
        points=segments.astype(np.float32),
        colors=TRAJECTORY_COLOR,
        thickness=LINE_PIXELS,
        thickness_units="screen",
    )
    for v in test_views:
        handles["test"].append(
            _frustum(
                server,
                f"/test/{v.name}",
                np.asarray(v.c2w, np.float64),
                run.K,
                run.width,
                run.height,
                scale,
                TEST_COLOR,
            )
        )
    # start behind the cameras, looking at the scene
    eye = centres.mean(0) + BACK_OFF * (centres.mean(0) - target)
    server.initial_camera.position = tuple(float(v) for v in eye)
    server.initial_camera.look_at = tuple(float(v) for v in target)
    server.initial_camera.up = tuple(float(v) for v in up)
    return handles


def serve(run, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, test_views=()):
    """A running viser server showing ``run`` and the scene handles of ``build_scene``
    (returns at once; ``server.stop()`` ends it)."""
    viser = import_viser()
    if not 0 < port < 65536:
        raise UserError(f"--port must be in 1..65535, got {port}")
    check_host(host)
    server = viser.ViserServer(host=host, port=port, label="ebad", verbose=False)
    disable_share(server)
    return server, build_scene(server, run, test_views)


def check_host(host: str) -> None:
    """Raise a UserError naming ``--host`` unless this machine can listen on ``host``: it must
    resolve (an IP address needs no lookup) and bind to a local interface (a bind fails locally,
    without traffic, on an address the machine does not have). viser itself would print
    "Server stopped" and wait forever."""
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise UserError(f"--host {host}: cannot resolve it ({reason}); give an address of this machine") from None
    problem = "no address"
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as sock:
            try:
                sock.bind((addr[0], 0, *addr[2:]))  # any free port: only the address is in question
                return
            except OSError as exc:
                problem = exc.strerror or str(exc)
    raise UserError(
        f"--host {host}: cannot listen on it ({problem}); give an address of this machine (127.0.0.1, 0.0.0.0)"
    )


def _refuse_share_url(verbose: bool = True) -> None:
    """Stands in for ``ViserServer.request_share_url``: no public tunnel, whoever asks."""
    return None


def disable_share(server) -> None:
    """No public share link: viser's Share button hidden, and a client's share request (any page
    can send one, button or not) answered with nothing instead of a tunnel to share.viser.studio."""
    server.gui.configure_theme(show_share_button=False)
    server.request_share_url = _refuse_share_url  # viser's ShareUrlRequest handler looks it up per request


def run(args: Args) -> int:
    from ..runfolder import load_run

    import_viser()  # fail before loading anything
    run_ = load_run(args.run)
    test_views = []
    if args.capture is not None:
        import scenes

        test_views = [v for v in scenes.load(args.capture).test_views if getattr(v, "c2w", None) is not None]
    server, _ = serve(run_, args.host, args.port, test_views)
    port = server.get_port()
    print(
        f"ebad view: {run_.num_gaussians} Gaussians, {len(run_.names)} training cameras, {len(test_views)} test views"
    )
    print(f"ebad view: open http://localhost:{port} (listening on {args.host}:{port}; Ctrl-C stops)")
    if args.host in ("127.0.0.1", "localhost"):
        print(
            f"ebad view: from another computer: ssh -L {port}:localhost:{port} THIS_HOST, "
            f"then open http://localhost:{port} there"
        )
    try:
        server.sleep_forever()
    finally:
        server.stop()
    return 0
