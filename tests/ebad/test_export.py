"""Files other tools open (ebad.export): display PNGs, cameras.json, .splat, TUM trajectories."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from ebad.errors import EbadError
from ebad.export import (
    SPLAT_BYTES,
    exposure_samples,
    read_cameras_json,
    read_splat,
    read_tum,
    rotmat_to_quat,
    srgb_decode,
    srgb_encode,
    to_display8,
    write_cameras_json,
    write_render,
    write_splat,
    write_tum,
)
from ebad.io import read_png16
from ebad.lie import quat_to_rotmat, so3_exp

SEEDS = range(4)


def _random_c2w(C: int, seed: int) -> np.ndarray:  # [C, 4, 4]
    g = torch.Generator().manual_seed(seed)
    w = torch.randn(C, 3, generator=g, dtype=torch.float64) * 1.2
    T = np.tile(np.eye(4), (C, 1, 1))
    T[:, :3, :3] = so3_exp(w).numpy()
    T[:, :3, 3] = torch.randn(C, 3, generator=g, dtype=torch.float64).numpy() * 3
    return T


def _params(N: int, D: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.randn(N, 3, generator=g),
        "scales": torch.randn(N, 3, generator=g) - 3,
        "quats": torch.randn(N, 4, generator=g),
        "opacities": torch.randn(N, generator=g) * 2,
        "colors": torch.randn(N, D, generator=g),
    }


def test_srgb_known_values_and_inverse():
    # IEC 61966-2-1: 18% grey encodes to about 0.4614; the linear segment below 0.0031308
    assert srgb_encode(np.array(0.18)) == pytest.approx(0.46135, abs=1e-4)
    assert srgb_encode(np.array(0.002)) == pytest.approx(0.002 * 12.92)
    assert float(srgb_encode(np.array(1.0))) == pytest.approx(1.0)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    assert np.all(np.diff(srgb_encode(x)) > 0)


@pytest.mark.parametrize("D", [1, 3])
def test_render_png_8bit_holds_the_recorded_values_and_opens_in_pillow(tmp_path, D):
    """No transfer curve on top of the recorded values: 8-bit round(255 v), read back by scenes.read_image
    within half a step (the encoding of a capture's frames)."""
    import scenes

    rng = np.random.default_rng(D)
    img = rng.uniform(0, 1, (7, 9, D)).astype(np.float32)
    path = write_render(tmp_path / "r.png", img)
    with Image.open(path) as im:
        assert im.mode == ("L" if D == 1 else "RGB") and im.size == (9, 7)
        got = np.asarray(im)
    got = got[..., None] if D == 1 else got
    np.testing.assert_array_equal(got, np.round(255 * img.astype(np.float64)).astype(np.uint8))
    np.testing.assert_allclose(scenes.read_image(path), img, atol=0.5 / 255 + 1e-7)
    # mid grey stays mid grey (an sRGB curve made 0.18 into 118)
    assert to_display8(np.full((1, 1, 1), 0.18))[0, 0, 0] == 46
    assert to_display8(np.array([[[-0.2], [1.3]]]))[0, :, 0].tolist() == [0, 255]


@pytest.mark.parametrize("D", [1, 3])
def test_render_png_16bit_is_linear(tmp_path, D):
    img = np.random.default_rng(5).uniform(0, 1, (6, 5, D)).astype(np.float32)
    path = write_render(tmp_path / "r16.png", img, bits=16)
    back = read_png16(path)
    np.testing.assert_allclose(back, img, atol=0.5 / 65535 + 1e-7)
    with pytest.raises(ValueError, match="bits"):
        write_render(tmp_path / "x.png", img, bits=12)


@pytest.mark.parametrize("seed", SEEDS)
def test_rotmat_to_quat_inverts_quat_to_rotmat(seed):
    R = _random_c2w(50, seed)[:, :3, :3]
    q = rotmat_to_quat(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotmat(torch.from_numpy(q)).numpy(), R, atol=1e-10)
    # the branches for x, y, z largest: rotations by pi about each axis
    for axis in range(3):
        w = np.zeros(3)
        w[axis] = np.pi - 1e-3
        Rk = so3_exp(torch.from_numpy(w)).numpy()
        np.testing.assert_allclose(quat_to_rotmat(torch.from_numpy(rotmat_to_quat(Rk))).numpy(), Rk, atol=1e-10)


@pytest.mark.parametrize("seed", SEEDS)
def test_cameras_json_roundtrip_and_layout(tmp_path, seed):
    c2w = _random_c2w(5, seed)
    K = np.array([[300.0, 0, 170.0], [0, 310.0, 128.0], [0, 0, 1]])
    names = [f"f{i:03d}" for i in range(5)]
    path = write_cameras_json(tmp_path / "cameras.json", names, c2w, K, 346, 260)
    raw = json.loads(path.read_text())
    assert [c["id"] for c in raw] == list(range(5))
    for key in ("id", "img_name", "width", "height", "position", "rotation", "fx", "fy"):
        assert key in raw[0]
    assert np.asarray(raw[2]["rotation"]).shape == (3, 3)  # rows of the c2w rotation, as 3DGS writes
    back = read_cameras_json(path)
    assert back["names"] == names
    np.testing.assert_allclose(back["c2w"], c2w, atol=1e-12)
    np.testing.assert_allclose(back["K"], np.broadcast_to(K, (5, 3, 3)))
    assert back["width"].tolist() == [346] * 5 and back["height"].tolist() == [260] * 5


def test_cameras_json_errors_name_file_and_field(tmp_path):
    p = tmp_path / "cameras.json"
    p.write_text(json.dumps([{"img_name": "a", "width": 4, "height": 3, "position": [0, 0, 0], "fx": 1, "fy": 1}]))
    with pytest.raises(EbadError, match=r"cameras\.json.*camera 0.*rotation"):
        read_cameras_json(p)
    p.write_text("{not json")
    with pytest.raises(EbadError, match="cameras.json"):
        read_cameras_json(p)


@pytest.mark.parametrize("D", [1, 3])
@pytest.mark.parametrize("seed", SEEDS)
def test_splat_roundtrip(tmp_path, seed, D):
    from ebad.gaussians import activate

    p = _params(300, D, seed)
    path = write_splat(tmp_path / "m.splat", p)
    assert path.stat().st_size == 300 * SPLAT_BYTES
    back = read_splat(path)
    act = {k: v.double().numpy() for k, v in activate(p).items()}
    importance = act["scales"].prod(1) * act["opacities"]
    order = np.argsort(-importance, kind="stable")
    # the file is in the order of decreasing size * opacity (the means identify each Gaussian)
    np.testing.assert_allclose(back["means"], act["means"][order], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(back["scales"], act["scales"][order], rtol=1e-6)
    assert np.abs(back["opacities"] - act["opacities"][order]).max() <= 0.5 / 255 + 1e-9
    cols = np.repeat(act["colors"], 3, 1) if D == 1 else act["colors"]
    # the colour bytes are round(255 v) of the colours (identity response), clipped to [0, 1]
    assert np.abs(back["colors"] - np.clip(cols[order], 0, 1)).max() <= 0.5 / 255 + 1e-9
    q = act["quats"][order] / np.linalg.norm(act["quats"][order], axis=1, keepdims=True)
    dots = np.abs((back["quats"] * q).sum(1))
    assert dots.min() > 0.999  # byte quantisation (1/128 per component) keeps the rotation


def test_splat_rejects_a_truncated_file(tmp_path):
    p = tmp_path / "bad.splat"
    p.write_bytes(b"\0" * 33)
    with pytest.raises(EbadError, match=r"bad\.splat.*multiple of 32"):
        read_splat(p)


@pytest.mark.parametrize("seed", SEEDS)
def test_tum_roundtrip(tmp_path, seed):
    c2w = _random_c2w(12, seed)
    t = np.sort(np.random.default_rng(seed).uniform(0, 3, 12))
    path = write_tum(tmp_path / "traj.txt", t, c2w)
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert len(lines) == 12 and all(len(ln.split()) == 8 for ln in lines)
    # real part last: the identity rotation reads "0 0 0 1"
    ident = write_tum(tmp_path / "id.txt", np.zeros(1), np.eye(4)[None])
    assert ident.read_text().splitlines()[1].split()[4:] == ["0.000000000"] * 3 + ["1.000000000"]
    tb, cb = read_tum(path)
    np.testing.assert_allclose(tb, t, atol=1e-9)
    np.testing.assert_allclose(cb, c2w, atol=1e-8)


def test_tum_errors_name_file_and_line(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("# header\n0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 1\n")
    with pytest.raises(EbadError, match=r"t\.txt:3.*8 numbers"):
        read_tum(p)


def test_exposure_samples_are_timed_and_sorted():
    ex = np.array([[1.0, 1.5], [0.0, 0.4]])
    poses = np.tile(np.eye(4), (2, 3, 1, 1))
    poses[0, :, 0, 3] = [10, 11, 12]
    poses[1, :, 0, 3] = [0, 1, 2]
    t, c = exposure_samples(ex, poses, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(t, [0.0, 0.2, 0.4, 1.0, 1.25, 1.5])
    np.testing.assert_allclose(c[:, 0, 3], [0, 1, 2, 10, 11, 12])


def test_write_run_writes_the_exports(tiny_run):
    """cameras.json, point_cloud.splat and the TUM file beside point_cloud.ply, matching the run."""
    from ebad.export import CAMERAS_JSON, SPLAT_FILE, TUM_FILE
    from ebad.runfolder import load_run

    run = load_run(tiny_run.run)
    cams = read_cameras_json(tiny_run.run / CAMERAS_JSON)
    assert cams["names"] == run.names
    np.testing.assert_allclose(cams["c2w"], run.trajectories.mid_poses().numpy(), atol=1e-6)
    np.testing.assert_allclose(cams["K"][0], run.K, atol=1e-6)
    splat = read_splat(tiny_run.run / SPLAT_FILE)
    assert len(splat["means"]) == run.num_gaussians
    t, c2w = read_tum(tiny_run.run / TUM_FILE)
    poses, u = run.exposure_poses()
    et, ec = exposure_samples(run.exposures, poses, u)
    assert np.all(np.diff(t) >= 0) and t[0] == pytest.approx(run.exposures[0, 0])
    np.testing.assert_allclose(t, et, atol=1e-8)
    np.testing.assert_allclose(c2w, ec, atol=1e-5)
