"""``ebad view RUN``: an interactive 3D viewer of a run in the web browser (viser).

Shows the Gaussians (drawn by the browser with WebGL, so the server needs no GPU), every
training camera as a frustum at its mid-exposure pose (blue) with its recovered exposure
trajectory as a polyline of camera centres (red, start to end), and, with ``--capture``,
the capture's test views (green frustums), on a dark background. A model with view-dependent
colour (spherical harmonics above degree 0) is recoloured for the browser's camera as it moves
(``ViewColours``: a few times a second at most, the response applied as in every output).

The first view is the first training camera's: its mid-exposure pose and the capture's vertical
field of view, so the browser opens on what that camera saw. The frustums of the cameras near the
browser's camera (within ``NEARBY_DEPTHS`` frustum depths) are hidden, and shown again when it moves
away: beside it on a slider or a row of photos, they start in its own image plane and would cross the
whole view as long lines (one scene is shared: the browser that moved last decides). A click on a
training camera's frustum flies there; the "trajectory" choice and the "exposure instant" slider
(0: exposure start, 8: end) move the view along that frame's recovered exposure trajectory. (The browser console's
"THREE.BufferGeometry.computeBoundingSphere(): Computed radius is NaN" comes from viser's own splat
mesh, whose quad "position" attribute has two components; ebad's arrays are finite, and viser draws
the splats all the same.)

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
LINE_PIXELS = 2.0  # frustum and trajectory line width, screen pixels
TRAIN_COLOR = (40, 90, 220)
TRAJECTORY_COLOR = (220, 40, 40)
TEST_COLOR = (30, 170, 60)
VIEW_COLOUR_INTERVAL = 0.25  # seconds: view-dependent colours follow the browser's camera at most 4 times a second
VIEW_COLOUR_MOVE = 1e-6  # a camera that moved less than this (scene units, any axis) did not move
NEARBY_DEPTHS = 2.0  # frustums of cameras within this many frustum depths of the browser's camera are hidden


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


def view_colors(params, centre, response=None) -> np.ndarray:  # centre [3] -> [N, 3] float32
    """Each Gaussian's colour as a camera at ``centre`` (world position [3]) sees it: its spherical harmonics
    evaluated toward the camera (``splat_cpu.sh_colors``, the rasteriser's convention: the direction from
    the camera centre to the mean; max(SH(d) . coeffs + 0.5, 0)), through the camera ``response`` as every
    output (``ebad.export.recorded_colors``), grey repeated. Without ``sh_rest`` the DC colours."""
    import torch

    from splat_cpu import sh_colors

    from ..export import recorded_colors
    from ..gaussians import activate, sh_degree_of

    degree = sh_degree_of(params)
    with torch.no_grad():
        if degree == 0:
            colors = activate(params)["colors"]
        else:
            viewmat = torch.eye(4, dtype=torch.float64)  # any rotation: only the centre -R^T t counts
            viewmat[:3, 3] = -torch.as_tensor(np.asarray(centre, np.float64).reshape(3))
            coeffs = torch.cat([params["colors"][:, None, :], params["sh_rest"]], dim=1)
            colors = sh_colors(params["means"], coeffs, viewmat[None], degree)[0]
    c = colors.detach().double().numpy()
    if c.shape[1] == 1:
        c = np.repeat(c, 3, axis=1)
    return recorded_colors(c, response).astype(np.float32)


class ViewColours:
    """View-dependent colour in the viewer: the splats recoloured (``view_colors``) for the camera of the
    browser that moved last, at most once every ``interval`` seconds and only when a camera moved.
    ``request(position)`` is called from the browsers' camera callbacks; ``step()`` from a timer thread
    (``start``), so a burst of camera messages costs one recolouring per interval and the last position of
    a move is always shown. One scene is shared by every browser: each sees the colours of the last move."""

    def __init__(self, handles: dict, run, interval: float = VIEW_COLOUR_INTERVAL, clock=None):
        import threading
        import time

        self.handles, self.run, self.interval = handles, run, float(interval)
        self.clock = time.monotonic if clock is None else clock
        self.updates = 0  # recolourings sent
        self._pending: np.ndarray | None = None
        self._shown: np.ndarray | None = None
        self._last = -math.inf
        self._lock = threading.Lock()
        self._stop = threading.Event()

    def request(self, position) -> None:
        """A browser camera is at ``position`` (world [3]) now."""
        with self._lock:
            self._pending = np.asarray(position, np.float64).reshape(3).copy()

    def step(self) -> bool:
        """Recolour for the latest requested position if a camera moved and ``interval`` has passed."""
        with self._lock:
            pos = self._pending
            if pos is None:
                return False
            if self._shown is not None and np.abs(pos - self._shown).max() <= VIEW_COLOUR_MOVE:
                self._pending = None
                return False
            now = self.clock()
            if now - self._last < self.interval:
                return False  # kept pending: shown when the interval has passed
            self._pending = None
        self.handles["splats"].rgbs = view_colors(self.run.params, pos, getattr(self.run, "response", None))
        self._shown, self._last = pos, now
        self.updates += 1
        return True

    def start(self):
        """Run ``step`` on a daemon thread every half interval until ``stop``; returns the thread."""
        import threading

        def loop() -> None:
            while not self._stop.wait(0.5 * self.interval):
                self.step()

        thread = threading.Thread(target=loop, name="ebad-view-colours", daemon=True)
        thread.start()
        return thread

    def stop(self) -> None:
        self._stop.set()


def follow_view_colours(server, handles: dict, run) -> ViewColours | None:
    """With view-dependent colour (a model with ``sh_rest``), recolour the splats as the browsers' cameras
    move (``ViewColours``, started); None for a model of DC colours only."""
    from ..gaussians import sh_degree_of

    if sh_degree_of(run.params) == 0:
        return None
    colours = ViewColours(handles, run)

    def on_connect(client) -> None:
        client.camera.on_update(lambda camera: colours.request(camera.position))

    server.on_client_connect(on_connect)
    colours.start()
    return colours


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


def frustum_depth(scale: float, fov: float, aspect: float) -> float:
    """How far ahead of its centre viser draws a camera frustum of ``scale``, vertical field of view ``fov``
    (radians) and ``aspect`` (width / height): its pyramid (tan(fov/2) aspect, tan(fov/2), 1) is divided by
    cbrt(its volume x 3) before the scale, so its depth is scale / cbrt(tan^2(fov/2) aspect / 3)."""
    return float(scale) / (math.tan(0.5 * fov) ** 2 * aspect / 3.0) ** (1.0 / 3.0)


def camera_view(c2w: np.ndarray, K: np.ndarray, height: int, depth: float) -> dict:
    """The browser camera that sees what a camera at ``c2w`` (OpenCV axes) with intrinsics ``K``
    sees: its centre, a look-at point ``depth`` ahead on its optical axis, its up (-y) and its
    vertical field of view (radians; the window's own aspect decides the horizontal one)."""
    c2w = np.asarray(c2w, np.float64)
    eye = c2w[:3, 3]
    return {
        "position": eye,
        "look_at": eye + max(float(depth), 1e-6) * c2w[:3, 2],
        "up": -c2w[:3, 1],
        "fov": 2 * math.atan(0.5 * height / float(K[1, 1])),
    }


def fly_to(client, view: dict) -> None:
    """Move one browser's camera (a viser ``ClientHandle``) to a ``camera_view``."""
    cam = client.camera
    with client.atomic():
        cam.fov = view["fov"]
        cam.up_direction = view["up"]
        cam.position = view["position"]  # keeps the orientation: the look-at point follows
        cam.look_at = view["look_at"]


def _look_depth(c2w: np.ndarray, target: np.ndarray, fallback: float) -> float:
    """How far ahead of a camera the scene's middle ``target`` lies on its optical axis."""
    depth = float((target - c2w[:3, 3]) @ c2w[:3, 2])
    return depth if np.isfinite(depth) and depth > 1e-6 else fallback


def exposure_poses(trajectories, samples: int = TRAJECTORY_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """([F, 4, 4] mid-exposure poses, [F, samples, 4, 4] poses at evenly spaced exposure instants)."""
    import torch

    with torch.no_grad():
        mid = trajectories.mid_poses().detach().double().numpy()
        u = torch.linspace(0, 1, samples)
        poses = trajectories(torch.arange(trajectories.num_frames), u).detach().double().numpy()
    return mid, poses


def _geometry(run) -> dict:
    """The poses and scene middle the cameras and the browser's views are placed by."""
    mid, poses = exposure_poses(run.trajectories)  # [F, 4, 4], [F, S, 4, 4]
    arrays = splat_arrays(run.params, getattr(run, "response", None))
    centres = mid[:, :3, 3]
    target = np.median(arrays["centers"], axis=0).astype(np.float64) if len(arrays["centers"]) else centres.mean(0)
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) if len(centres) > 1 else 0.0
    reach = float(np.linalg.norm(centres.mean(0) - target))
    return {
        "arrays": arrays,
        "mid": mid,
        "poses": poses,
        "target": target,
        "scale": FRUSTUM_FRACTION * max(spread, reach, 1e-3),
        "depth": max(reach, spread, 1e-3),  # the look-at distance when the scene is not ahead of a camera
    }


def _segments(poses: np.ndarray) -> np.ndarray:  # [F, S, 4, 4] -> [F*(S-1), 2, 3] camera-centre polylines
    return np.stack([poses[:, :-1, :3, 3], poses[:, 1:, :3, 3]], axis=2).reshape(-1, 2, 3).astype(np.float32)


def _add_trajectories(server, poses: np.ndarray):
    return server.scene.add_line_segments(
        "/trajectories",
        points=_segments(poses),
        colors=TRAJECTORY_COLOR,
        thickness=LINE_PIXELS,
        thickness_units="screen",
    )


def build_scene(server, run, test_views=()) -> dict:
    """Add the run's Gaussians, training cameras, exposure trajectories and ``test_views``
    (objects with ``name`` and ``c2w``) to a viser server, with the browser's first view at the first
    training camera's mid-exposure pose and field of view, the frustums near the browser's camera hidden
    (``hide_nearby``, as it moves), a click on a training camera flying there, and a "trajectory" choice
    with an "exposure instant" slider moving the view along a recovered exposure trajectory. ``run`` needs
    ``params``, ``trajectories``, ``names``, ``K``, ``width`` and ``height`` (a ``Run``, or a training
    state's: ``update_scene`` follows it). Returns the scene handles."""
    geo = _geometry(run)
    mid, scale = geo["mid"], geo["scale"]
    up = -mid[:, :3, 1].mean(0)  # OpenCV: y points down in the image
    up = up / max(np.linalg.norm(up), 1e-12)
    server.scene.set_up_direction(up)
    handles: dict = {"splats": server.scene.add_gaussian_splats("/gaussians", **geo["arrays"]), "train": [], "test": []}
    handles["geometry"] = geo

    def view_at(f: int, s: int | None = None) -> dict:
        g = handles["geometry"]  # the latest (update_scene replaces it)
        c2w = g["mid"][f] if s is None else g["poses"][f, s]
        return camera_view(c2w, run.K, run.height, _look_depth(c2w, g["target"], g["depth"]))

    handles["view_at"] = view_at
    for f, name in enumerate(run.names):
        frustum = _frustum(server, f"/train/{name}", mid[f], run.K, run.width, run.height, scale, TRAIN_COLOR)
        frustum.on_click(_flier(f, view_at))
        handles["train"].append(frustum)
    handles["trajectories"] = _add_trajectories(server, geo["poses"])
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
    handles.update(_trajectory_controls(server, list(run.names), geo["poses"].shape[1], view_at))
    # the first view: the first training camera at mid-exposure, as it saw the scene
    first = view_at(0)
    server.initial_camera.position = tuple(float(v) for v in first["position"])
    server.initial_camera.look_at = tuple(float(v) for v in first["look_at"])
    server.initial_camera.up = tuple(float(v) for v in first["up"])
    server.initial_camera.fov = first["fov"]
    handles["nearby"] = NEARBY_DEPTHS * frustum_depth(scale, first["fov"], run.width / run.height)
    hide_nearby(handles, first["position"])
    server.on_client_connect(lambda client: client.camera.on_update(lambda cam: hide_nearby(handles, cam.position)))
    return handles


def hide_nearby(handles: dict, eye) -> None:
    """Hide the frustums (training and test) of the cameras within ``handles["nearby"]`` of ``eye`` (the
    browser camera's position, world [3]) and show the others: seen from among them, they cross the view."""
    eye = np.asarray(eye, np.float64).reshape(3)
    for frustum in handles["train"] + handles["test"]:
        visible = bool(np.linalg.norm(np.asarray(frustum.position, np.float64) - eye) >= handles["nearby"])
        if frustum.visible != visible:
            frustum.visible = visible


def update_scene(server, handles: dict, run) -> None:
    """Show ``run``'s current Gaussians, camera poses and trajectories in a scene made by ``build_scene``
    (the browsers' cameras and controls stay as they are)."""
    from ..export import rotmat_to_quat

    geo = _geometry(run)
    with server.atomic():
        handles["splats"] = server.scene.add_gaussian_splats("/gaussians", **geo["arrays"])  # same name: replaced
        for frustum, c2w in zip(handles["train"], geo["mid"]):
            frustum.wxyz = rotmat_to_quat(c2w[:3, :3])
            frustum.position = c2w[:3, 3]
        handles["trajectories"].points = _segments(geo["poses"])
    handles["geometry"] = geo


def _flier(f: int, view_at):
    """A frustum's click callback: the clicking browser flies to camera ``f``'s mid-exposure pose."""

    def on_click(event) -> None:
        fly_to(event.client, view_at(f))

    return on_click


def _trajectory_controls(server, names: list[str], samples: int, view_at) -> dict:
    """The GUI: a choice of training frame and a slider over its exposure instants (0: exposure start,
    ``samples - 1``: end); changing either moves the browser that changed it (every browser when the
    server changes it) to that instant's pose on the recovered trajectory."""
    frame = server.gui.add_dropdown("trajectory", options=names, initial_value=names[0])
    instant = server.gui.add_slider("exposure instant", min=0, max=samples - 1, step=1, initial_value=samples // 2)

    def move(event) -> None:
        view = view_at(names.index(frame.value), int(instant.value))
        clients = [event.client] if event.client is not None else list(server.get_clients().values())
        for client in clients:
            fly_to(client, view)

    frame.on_update(move)
    instant.on_update(move)
    return {"frame": frame, "instant": instant}


def serve(run, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, test_views=()):
    """A running viser server showing ``run`` and the scene handles of ``build_scene``
    (returns at once; ``server.stop()`` ends it)."""
    viser = import_viser()
    if not 0 < port < 65536:
        raise UserError(f"--port must be in 1..65535, got {port}")
    check_host(host)
    server = viser.ViserServer(host=host, port=port, label="ebad", verbose=False)
    disable_share(server)
    handles = build_scene(server, run, test_views)
    handles["view_colours"] = follow_view_colours(server, handles, run)
    return server, handles


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
    server.gui.configure_theme(show_share_button=False, dark_mode=True)  # dark: the scene's own background
    server.request_share_url = _refuse_share_url  # viser's ShareUrlRequest handler looks it up per request


def run(args: Args) -> int:
    from ..runfolder import load_run

    import_viser()  # fail before loading anything
    run_ = load_run(args.run)
    test_views = []
    if args.capture is not None:
        import scenes

        test_views = [v for v in scenes.load(args.capture).test_views if getattr(v, "c2w", None) is not None]
    server, handles = serve(run_, args.host, args.port, test_views)
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
        if handles.get("view_colours") is not None:
            handles["view_colours"].stop()
        server.stop()
    return 0
