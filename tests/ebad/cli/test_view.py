"""``ebad view``: the viser scene, checked in a real browser (headless Chromium)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys

import numpy as np
import pytest

from ebad.cli import main
from ebad.cli.view import serve, splat_arrays
from ebad.runfolder import load_run

WINDOW = (1024, 768)  # width, height of the headless browser window
# a part of the page where viser draws only its 3D canvas (its control panel sits at the top
# right, a notice at the top left, the axes gizmo at the bottom left): rows, columns
CANVAS_ONLY = (slice(160, 700), slice(70, 680))
MIN_CANVAS_STD = 8.0  # grey levels: a blank (uniform) canvas has 0
MIN_SPLAT_EFFECT = 2.0  # mean |difference| in grey levels between the scene with and without Gaussians
MIN_FIRST_VIEW_CORRELATION = 0.5  # the first view against ebad's render of the first training camera
MIN_SCENE_FRACTION = 0.5  # of the canvas region that must differ from the (dark) background
BACKGROUND_TOLERANCE = 12.0  # grey levels
VIRTUAL_TIME_MS = 6000  # page time for the client to connect and draw (doubled on each retry)
ATTEMPTS = 4  # a loaded machine can take longer to send the scene over the websocket: wait longer
BROWSER_TIMEOUT_S = 120
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


def _drawn(browser: str, url: str, out, profile) -> np.ndarray:  # -> [H, W] grey float
    """A screenshot once the canvas shows something (retried with a longer page time), else the
    last one. A headless Chromium that hangs (seen once in a CI run; the same test passed alone
    in 13 s) is killed after ``BROWSER_TIMEOUT_S`` and counts as a failed attempt."""
    img, hung = None, 0
    for attempt in range(ATTEMPTS):
        shot = _screenshot(browser, url, out, profile, VIRTUAL_TIME_MS * 2**attempt)
        if shot is None:
            hung += 1
            continue
        img = shot
        if img[CANVAS_ONLY].std() > MIN_CANVAS_STD:
            break
    assert img is not None, f"Chromium hung in all {hung} attempts (killed after {BROWSER_TIMEOUT_S} s each)"
    return img


def _screenshot(browser: str, url: str, out, profile, budget_ms: int = VIRTUAL_TIME_MS) -> np.ndarray | None:
    """The page as a grey image, or None when the browser did not exit within ``BROWSER_TIMEOUT_S``."""
    from PIL import Image

    cmd = [
        browser,
        *CHROMIUM_FLAGS,
        f"--user-data-dir={profile}",
        f"--screenshot={out}",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
        f"--virtual-time-budget={budget_ms}",
        url,
    ]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return None
    assert res.returncode == 0 and out.exists(), res.stderr[-2000:]
    print(f"browser screenshot: {out}")
    with Image.open(out) as im:
        return np.asarray(im.convert("L"), dtype=np.float64)


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
    pytest.importorskip("viser", reason="the 'view' extra (viser) is not installed")
    browser = _chromium()
    if browser is None:
        pytest.skip("no Chromium: apt-get install -y chromium (Debian) to run the browser test")
    import scenes

    run = load_run(tiny_run.run)
    views = scenes.load(tiny_run.capture).test_views
    server, handles = serve(run, host="127.0.0.1", port=_free_loopback_port(), test_views=views)
    try:
        assert server.get_host() == "127.0.0.1"  # loopback only
        assert len(handles["train"]) == len(run.names) and len(handles["test"]) == len(views)
        url = f"http://127.0.0.1:{server.get_port()}/"
        full = _drawn(browser, url, tmp_path / "view_scene.png", tmp_path / "profile1")
        region = full[CANVAS_ONLY]
        assert region.std() > MIN_CANVAS_STD, (
            f"blank canvas (std {region.std():.2f}); see {tmp_path / 'view_scene.png'}"
        )
        # the first view is the first training camera's, as ebad renders it
        ours = _first_view_render(run)
        shot = full.reshape(WINDOW[1] // 2, 2, WINDOW[0] // 2, 2).mean((1, 3))
        rows, cols = (
            slice(CANVAS_ONLY[0].start // 2, CANVAS_ONLY[0].stop // 2),
            slice(CANVAS_ONLY[1].start // 2, CANVAS_ONLY[1].stop // 2),
        )
        corr = float(np.corrcoef(shot[rows, cols].ravel(), ours[rows, cols].ravel())[0, 1])
        print(f"first view: correlation with ebad's render of the first training camera {corr:.3f}")
        assert corr > MIN_FIRST_VIEW_CORRELATION, f"the first view does not match the first camera's (r = {corr:.3f})"
        handles["splats"].visible = False
        bare = _drawn(
            browser, url, tmp_path / "view_no_gaussians.png", tmp_path / "profile2"
        )  # boxes and cameras still draw
        effect = np.abs(region - bare[CANVAS_ONLY]).mean()
        background = float(np.median(bare[CANVAS_ONLY]))  # the canvas without Gaussians: background and lines
        assert background < 64, f"background grey {background:.0f}: not dark"
        scene_fraction = float((np.abs(region - background) > BACKGROUND_TOLERANCE).mean())
        assert scene_fraction > MIN_SCENE_FRACTION, f"only {scene_fraction:.0%} of the canvas shows the scene"
        assert effect > MIN_SPLAT_EFFECT, f"the Gaussians changed the canvas by only {effect:.2f} grey levels"
        print(
            f"canvas std {region.std():.1f}, Gaussians' effect {effect:.1f} grey levels, {scene_fraction:.0%} of the "
            f"canvas differs from the background (grey {background:.0f})"
        )
    finally:
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
