"""``ebad render``: 8-bit PNGs of the recorded values by default (read by Pillow), 16-bit on request."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from ebad.cli import main
from ebad.cli.render import smooth_path
from ebad.export import to_display8
from ebad.io import read_png16
from ebad.runfolder import load_run


def test_render_default_is_8bit_recorded_values_that_pillow_reads(tiny_run, tmp_path, capsys):
    out = tmp_path / "train8"
    assert main(["render", str(tiny_run.run), "--split", "train", "--out", str(out)]) == 0
    assert "8-bit, the capture's recorded values" in capsys.readouterr().out
    run = load_run(tiny_run.run)
    expect = to_display8(run.deblurred_frames())  # [F, H, W, 1]
    for name, e in zip(run.names, expect):
        with Image.open(out / f"{name}.png") as im:
            assert im.mode == "L" and im.size == (run.width, run.height)  # grey stays one channel
            got = np.asarray(im)
        np.testing.assert_array_equal(got, e[..., 0])
    # no second curve: the 8-bit value is round(255 v) of the render (an sRGB curve brightened mid-tones)
    rec = run.deblurred_frames()
    np.testing.assert_array_equal(expect, np.round(255 * rec.astype(np.float64)).astype(np.uint8))


def test_render_bits16_holds_the_recorded_values(tiny_run, tmp_path):
    out = tmp_path / "train16"
    assert main(["render", str(tiny_run.run), "--split", "train", "--bits", "16", "--out", str(out)]) == 0
    run = load_run(tiny_run.run)
    lin = run.deblurred_frames()
    for name, e in zip(run.names, lin):
        np.testing.assert_allclose(read_png16(out / f"{name}.png"), e, atol=0.5 / 65535 + 1e-7)


def test_render_test_views_and_path(tiny_run, tmp_path):
    out = tmp_path / "test"
    assert main(["render", str(tiny_run.run), "--capture", str(tiny_run.capture), "--out", str(out)]) == 0
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(v.name for v in tiny_run.scene.capture.test_views)
    assert main(["render", str(tiny_run.run), "--path", "4", "--out", str(tmp_path / "path")]) == 0
    with Image.open(tmp_path / "path" / "path_00003.png") as im:
        assert im.size == (64, 48) and im.mode == "L"


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--split", "test"], "--capture is required"),
        (["--path", "1"], "--path needs at least 2"),
    ],
)
def test_render_user_errors_exit_2_naming_the_option(tiny_run, tmp_path, capsys, argv, needle):
    assert main(["render", str(tiny_run.run), "--out", str(tmp_path / "x"), *argv]) == 2
    assert needle in capsys.readouterr().err


# --------------------------------------------------------------------------- the smooth camera path


def _cameras(F: int, seed: int = 0) -> np.ndarray:  # -> [F, 4, 4]
    rng = np.random.default_rng(seed)
    c2w = np.tile(np.eye(4), (F, 1, 1))
    c2w[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=0.6, size=(F, 3))).as_matrix()
    c2w[:, :3, 3] = rng.normal(size=(F, 3))
    return c2w


def test_smooth_path_passes_through_every_camera():
    c2w = _cameras(5)
    path = smooth_path(c2w, 4 * 4 + 1)  # s = 0, 0.25, ..., 4: camera k at sample 4 k
    np.testing.assert_allclose(path[::4], c2w, atol=1e-12)
    np.testing.assert_array_equal(path[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (len(path), 1)))
    R = path[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.tile(np.eye(3), (len(path), 1, 1)), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)


def test_smooth_path_rotations_are_the_geodesic_between_neighbours():
    # the same rotations as the hand-written slerp before (R_i exp(u log(R_i^T R_i+1)) at s = i + u)
    c2w = _cameras(4, seed=1)
    n = 23
    path = smooth_path(c2w, n)
    for j, s in enumerate(np.linspace(0, 3, n)):
        i = min(int(np.floor(s)), 2)
        R0, R1 = Rotation.from_matrix(c2w[i, :3, :3]), Rotation.from_matrix(c2w[i + 1, :3, :3])
        want = (R0 * Rotation.from_rotvec((s - i) * (R0.inv() * R1).as_rotvec())).as_matrix()
        np.testing.assert_allclose(path[j, :3, :3], want, atol=1e-10)


@pytest.mark.parametrize("F", [2, 3, 6])
def test_smooth_path_keeps_a_straight_constant_speed_track_straight(F):
    # cameras on a line at constant spacing: the path runs along it at constant speed, ends included
    c2w = _cameras(F, seed=2)
    a, d = np.array([0.3, -1.0, 2.0]), np.array([0.5, 0.25, -0.1])
    c2w[:, :3, 3] = a + np.arange(F)[:, None] * d
    n = 7 * (F - 1) + 1
    path = smooth_path(c2w, n)
    np.testing.assert_allclose(path[:, :3, 3], a + np.linspace(0, F - 1, n)[:, None] * d, atol=1e-12)


def test_smooth_path_of_one_camera_stays_there():
    c2w = _cameras(1)
    np.testing.assert_array_equal(smooth_path(c2w, 3), np.repeat(c2w, 3, 0))
