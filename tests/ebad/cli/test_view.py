"""``ebad view``: the viser scene, checked in a real browser (headless Chromium driven over the DevTools
protocol: the test waits until the page has the scene and its picture has settled, then takes screenshots)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from ebad.cli import main
from ebad.cli.view import serve, splat_arrays
from ebad.runfolder import load_run

WINDOW = (1024, 768)  # width, height of the headless browser's page
# a part of the page where viser draws only its 3D canvas (its control panel sits at the top
# right, a notice at the top left, the axes gizmo at the bottom left): rows, columns
CANVAS_ONLY = (slice(160, 700), slice(70, 680))
MIN_CANVAS_STD = 8.0  # grey levels: a blank (uniform) canvas has 0
MIN_SPLAT_EFFECT = 2.0  # mean |difference| in grey levels between the scene with and without Gaussians
MIN_FIRST_VIEW_CORRELATION = 0.9  # the first view against ebad's render of the first training camera
# viser's own panels (a notice at the top left, the control panel at the top right, the axes gizmo at the
# bottom left): rows, columns
PANELS = ((slice(0, 160), slice(0, 320)), (slice(0, 135), slice(680, None)), (slice(700, None), slice(0, 70)))
LINE_SATURATION = 10  # max - min of a pixel's R, G, B: a grey scene draws 0 (lossless PNG screenshots)
MAX_LINE_FRACTION = 0.001  # of the page outside PANELS coloured by frustum or trajectory lines in the first view
MAX_MEAN_GREY_DIFF = 12.0  # mean grey of the first view's canvas region against ebad's render of it
MIN_SCENE_FRACTION = 0.5  # of the canvas region that must differ from the (dark) background
BACKGROUND_TOLERANCE = 12.0  # grey levels
SETTLED_GREY = 0.25  # mean |change| (grey levels) between two screenshots of a page that stopped changing
SETTLE_SHOTS = 10  # screenshots to wait for that
BROWSER_TIMEOUT_S = 120  # for the page to connect, answer a render request or a DevTools command
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
]  # software WebGL for this trusted local page


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Chromium:
    """A headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``: it reads
    commands on fd 3 and writes replies on fd 4, NUL-terminated JSON), so a test waits on the page's state
    instead of guessing a time budget. A command unanswered within ``BROWSER_TIMEOUT_S`` fails the test."""

    def __init__(self, browser: str, profile):
        import fcntl

        cmd_r, self._cmd_w = os.pipe()
        self._out_r, out_w = os.pipe()
        # the child's ends above fd 4 (so moving them onto 3 and 4 overwrites neither); bash moves them there
        # and execs Chromium (no preexec_fn: this process runs the server's threads; dash takes fds 0-9 only)
        fd3, fd4 = (fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (cmd_r, out_w))
        os.close(cmd_r)
        os.close(out_w)
        args = [*CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"]
        self.proc = subprocess.Popen(
            ["bash", "-c", f'exec "$0" "$@" 3<&{fd3} 4>&{fd4} {fd3}<&- {fd4}>&-', browser, *args],
            pass_fds=(fd3, fd4),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        os.close(fd3)
        os.close(fd4)
        self._buf, self._id, self._session = b"", 0, None

    def send(self, method: str, params: dict | None = None, page: bool = True) -> dict:
        """One DevTools command (to the page once ``open`` attached it); its result."""
        import json
        import select

        self._id += 1
        msg: dict = {"id": self._id, "method": method, "params": params or {}}
        if page and self._session is not None:
            msg["sessionId"] = self._session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + BROWSER_TIMEOUT_S
        while True:
            while b"\0" not in self._buf:
                if not select.select([self._out_r], [], [], max(deadline - time.monotonic(), 0))[0]:
                    raise TimeoutError(f"Chromium did not answer {method} within {BROWSER_TIMEOUT_S} s")
                chunk = os.read(self._out_r, 1 << 20)
                assert chunk, f"Chromium exited (code {self.proc.poll()}) during {method}"
                self._buf += chunk
            line, self._buf = self._buf.split(b"\0", 1)
            reply = json.loads(line)
            if reply.get("id") == self._id:
                assert "error" not in reply, f"{method}: {reply['error']}"
                return reply["result"]

    def open(self, url: str) -> None:
        """Load ``url`` in the browser's page, its viewport ``WINDOW`` at one device pixel per CSS pixel."""
        page = next(t for t in self.send("Target.getTargets", page=False)["targetInfos"] if t["type"] == "page")
        attached = self.send("Target.attachToTarget", {"targetId": page["targetId"], "flatten": True}, page=False)
        self._session = attached["sessionId"]
        metrics = {"width": WINDOW[0], "height": WINDOW[1], "deviceScaleFactor": 1, "mobile": False}
        self.send("Emulation.setDeviceMetricsOverride", metrics)
        self.send("Page.navigate", {"url": url})

    def screenshot(self, out) -> np.ndarray:  # -> [H, W, 3] uint8, also written to ``out`` (PNG)
        import base64
        import io

        from PIL import Image

        data = base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])
        out.write_bytes(data)
        with Image.open(io.BytesIO(data)) as im:
            return np.asarray(im.convert("RGB"))

    def close(self) -> None:
        try:
            self.send("Browser.close", page=False)
            self.proc.wait(10)
        except (AssertionError, OSError, TimeoutError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        finally:
            os.close(self._cmd_w)
            os.close(self._out_r)


def _synced(server) -> None:
    """Wait until a browser is connected and has applied everything the server sent before this call: viser
    applies a client's messages in order, and answers a render request (``ClientHandle.get_render``) only by
    drawing a frame after the messages before it."""
    deadline = time.monotonic() + BROWSER_TIMEOUT_S
    while not server.get_clients():
        assert time.monotonic() < deadline, f"no browser connected within {BROWSER_TIMEOUT_S} s"
        time.sleep(0.1)
    client = next(iter(server.get_clients().values()))
    client.get_render(48, 64, timeout=BROWSER_TIMEOUT_S)


def _settled(chrome: Chromium, server, out) -> np.ndarray:  # -> [H, W, 3] uint8
    """The page's screenshot once the browser has the scene (``_synced``) and its picture stopped changing
    (viser fades splats in, then sorts them for the view): two screenshots in a row within ``SETTLED_GREY``
    grey levels of each other on average. ``out`` keeps the last one."""
    _synced(server)
    prev = chrome.screenshot(out).astype(np.float64)
    change = np.inf
    for _ in range(SETTLE_SHOTS):
        img = chrome.screenshot(out)
        change = float(np.abs(img - prev).mean())
        if change < SETTLED_GREY:
            print(f"browser screenshot: {out}")
            return img
        prev = img.astype(np.float64)
    raise AssertionError(f"the page still changes ({change:.2f} grey levels) after {SETTLE_SHOTS} screenshots: {out}")


def first_view(browser: str, server, out, profile) -> np.ndarray:  # -> [H, W, 3] uint8
    """What a browser opening ``server``'s page shows once it has drawn the scene (``out``: the screenshot)."""
    chrome = Chromium(browser, profile)
    try:
        chrome.open(f"http://127.0.0.1:{server.get_port()}/")
        return _settled(chrome, server, out)
    finally:
        chrome.close()


def line_fraction(rgb: np.ndarray) -> float:  # [H, W, 3] uint8 -> fraction of the pixels outside viser's panels
    """How much of a grey scene's picture is coloured: frustums (blue, green) and exposure trajectories (red)
    drawn over it. Whole page but viser's notice, control panel and axes gizmo (``PANELS``)."""
    c = rgb.astype(np.int16)
    outside = np.ones(c.shape[:2], bool)
    for rows, cols in PANELS:
        outside[rows, cols] = False
    return float(((c.max(-1) - c.min(-1)) > LINE_SATURATION)[outside].mean())


def first_view_correlation(rgb: np.ndarray, run) -> float:
    """Correlation of a screenshot's canvas region (grey, 2x2 means) with ebad's render of the first training
    camera (``_first_view_render``)."""
    grey = rgb.astype(np.float64).mean(-1)
    shot = grey.reshape(WINDOW[1] // 2, 2, WINDOW[0] // 2, 2).mean((1, 3))
    ours = _first_view_render(run)
    rows, cols = (slice(s.start // 2, s.stop // 2) for s in CANVAS_ONLY)
    return float(np.corrcoef(shot[rows, cols].ravel(), ours[rows, cols].ravel())[0, 1])


def _first_view_render(run, shrink: int = 2) -> np.ndarray:  # [H, W] grey in 0..255, the window's size / shrink
    """ebad's render of the first training camera at mid-exposure as the browser window shows it:
    the capture's vertical field of view over the window's height, square pixels, centred."""
    from ebad.cli.view import exposure_poses

    W, H = WINDOW[0] // shrink, WINDOW[1] // shrink
    f = float(run.K[1, 1]) * H / run.height
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    img = run.render(exposure_poses(run.trajectories)[0][0], K, W, H)
    return 255.0 * img.mean(-1)


def test_splat_arrays_match_the_model(tiny_run):
    import torch

    from ebad.gaussians import activate
    from ebad.lie import quat_to_rotmat

    run = load_run(tiny_run.run)
    a = splat_arrays(run.params)
    N = run.num_gaussians
    assert a["centers"].shape == (N, 3) and a["covariances"].shape == (N, 3, 3)
    assert a["rgbs"].shape == (N, 3) and a["opacities"].shape == (N, 1)
    act = activate(run.params)
    # covariance = R diag(s^2) R^T: symmetric, eigenvalues the squared scales
    np.testing.assert_allclose(a["covariances"], np.swapaxes(a["covariances"], 1, 2), atol=1e-9)
    ev = np.sort(np.linalg.eigvalsh(a["covariances"].astype(np.float64)), 1)
    np.testing.assert_allclose(
        ev, np.sort(act["scales"].detach().numpy().astype(np.float64) ** 2, 1), rtol=1e-3, atol=1e-9
    )
    R = quat_to_rotmat(act["quats"][:1].detach().double())[0].numpy()
    axis_var = R[:, 0] @ a["covariances"][0].astype(np.float64) @ R[:, 0]
    assert axis_var == pytest.approx(float(act["scales"][0, 0].detach()) ** 2, rel=1e-3)
    assert np.all((a["opacities"] > 0) & (a["opacities"] < 1)) and np.all((a["rgbs"] >= 0) & (a["rgbs"] <= 1))
    assert torch.equal(torch.from_numpy(a["centers"]), run.params["means"].detach())


def test_view_without_viser_names_the_install(tiny_run, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "viser", None)  # import fails as if not installed
    assert main(["view", str(tiny_run.run)]) == 2
    assert "pip install viser" in capsys.readouterr().err


@pytest.mark.slow
def test_view_draws_the_scene_in_a_real_browser(tiny_run, tmp_path):
    """The first view shows what ebad renders for the first training camera, with no camera lines across
    it; the Gaussians make the picture (hidden, the canvas is the dark background)."""
    pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium: apt-get install -y chromium (Debian) to run the browser test")
    import scenes

    run = load_run(tiny_run.run)
    views = scenes.load(tiny_run.capture).test_views
    server, handles = serve(run, host="127.0.0.1", port=_free_loopback_port(), test_views=views)
    chrome = Chromium(browser, tmp_path / "profile")
    try:
        assert server.get_host() == "127.0.0.1"  # loopback only
        assert len(handles["train"]) == len(run.names) and len(handles["test"]) == len(views)
        chrome.open(f"http://127.0.0.1:{server.get_port()}/")
        full = _settled(chrome, server, tmp_path / "view_scene.png")
        region = full[CANVAS_ONLY].astype(np.float64).mean(-1)
        assert region.std() > MIN_CANVAS_STD, (
            f"blank canvas (std {region.std():.2f}); see {tmp_path / 'view_scene.png'}"
        )
        corr, lines = first_view_correlation(full, run), line_fraction(full)
        ours = _first_view_render(run)[tuple(slice(s.start // 2, s.stop // 2) for s in CANVAS_ONLY)]
        grey_diff = float(region.mean() - ours.mean())
        print(
            f"first view: correlation with ebad's render of the first camera {corr:.4f}, mean grey "
            f"{region.mean():.1f} against {ours.mean():.1f}, {lines:.3%} of the page coloured by lines"
        )
        assert lines < MAX_LINE_FRACTION, f"camera lines cover {lines:.2%} of the first view"
        assert corr > MIN_FIRST_VIEW_CORRELATION, f"the first view does not match the first camera's (r = {corr:.3f})"
        assert abs(grey_diff) < MAX_MEAN_GREY_DIFF, f"the first view is {grey_diff:+.1f} grey levels off ebad's render"
        handles["splats"].visible = False
        bare = _settled(chrome, server, tmp_path / "view_no_gaussians.png").astype(np.float64).mean(-1)[CANVAS_ONLY]
        effect = np.abs(region - bare).mean()
        background = float(np.median(bare))  # the canvas without Gaussians: background and lines
        assert background < 64, f"background grey {background:.0f}: not dark"
        scene_fraction = float((np.abs(region - background) > BACKGROUND_TOLERANCE).mean())
        assert scene_fraction > MIN_SCENE_FRACTION, f"only {scene_fraction:.0%} of the canvas shows the scene"
        assert effect > MIN_SPLAT_EFFECT, f"the Gaussians changed the canvas by only {effect:.2f} grey levels"
        print(
            f"canvas std {region.std():.1f}, Gaussians' effect {effect:.1f} grey levels, {scene_fraction:.0%} of the "
            f"canvas differs from the background (grey {background:.0f})"
        )
    finally:
        chrome.close()
        server.stop()


def test_view_cli_serves_on_loopback_and_prints_the_ssh_line(tiny_run, monkeypatch, capsys):
    viser = pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    hosts = []
    monkeypatch.setattr(viser.ViserServer, "sleep_forever", lambda self: hosts.append(self.get_host()))
    port = _free_loopback_port()
    assert main(["view", str(tiny_run.run), "--capture", str(tiny_run.capture), "--port", str(port)]) == 0
    out = capsys.readouterr().out
    assert hosts == ["127.0.0.1"]  # the default listens on loopback only
    assert f"http://localhost:{port}" in out and f"ssh -L {port}:localhost:{port}" in out
    assert "2 test views" in out
    assert main(["view", str(tiny_run.run), "--port", "70000"]) == 2
    assert "--port" in capsys.readouterr().err
