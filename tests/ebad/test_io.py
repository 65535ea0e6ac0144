"""ebad.io: PLY and PNG round trips."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebad.gaussians import init_params
from ebad.io import read_ply, read_png16, write_ply, write_png16


def _params(n=10, D=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    return init_params(torch.randn(n, 3, generator=g), torch.rand(n, D, generator=g), opacity=0.5)


@pytest.mark.parametrize("D", [1, 3])
def test_ply_roundtrip(tmp_path, D):
    p = _params(7, D=D)
    path = write_ply(tmp_path / "point_cloud.ply", p)
    header = path.read_bytes().split(b"end_header")[0].decode()
    for name in ["x", "nx", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "rot_3"]:
        assert f"property float {name}\n" in header
    back = read_ply(path)
    for k in p:
        assert torch.equal(back[k], p[k].detach()), k
    if D == 1:  # viewers see grey: the DC value in all three f_dc
        raw = np.frombuffer(path.read_bytes().split(b"end_header\n", 1)[1], "<f4").reshape(7, 17 + 45)
        assert np.array_equal(raw[:, 6], raw[:, 7]) and np.array_equal(raw[:, 6], raw[:, 8])


@pytest.mark.parametrize("D", [1, 3])
def test_ply_bytes_are_the_inria_layout(tmp_path, D):
    """The file byte for byte: the 3DGS header (with ebad's channel and SH degree comments; the 45 f_rest of
    degree 3, zero for a model without view-dependent colour) and float32 rows."""
    n = 5
    p = _params(n, D=D)
    blob = write_ply(tmp_path / "point_cloud.ply", p).read_bytes()
    names = (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(45)]
        + ["opacity"]
        + [f"scale_{i}" for i in range(3)]
        + [f"rot_{i}" for i in range(4)]
    )
    header = (
        f"ply\nformat binary_little_endian 1.0\ncomment ebad channels {D}\ncomment ebad sh_degree 0\n"
        f"element vertex {n}\n" + "".join(f"property float {name}\n" for name in names) + "end_header\n"
    ).encode("ascii")
    assert blob[: len(header)] == header
    colors = p["colors"].detach().numpy()
    rows = np.concatenate(
        [
            p["means"].detach().numpy(),
            np.zeros((n, 3)),
            np.repeat(colors, 3 // D, axis=1),
            np.zeros((n, 45)),
            p["opacities"].detach().numpy()[:, None],
            p["scales"].detach().numpy(),
            p["quats"].detach().numpy(),
        ],
        axis=1,
    ).astype("<f4")
    assert blob[len(header) :] == rows.tobytes()


@pytest.mark.parametrize("D", [1, 3])
def test_png16_roundtrip(tmp_path, D):
    img = np.random.default_rng(0).random((5, 7, D))
    back = read_png16(write_png16(tmp_path / "a.png", img))
    assert back.shape == (5, 7, D)
    assert np.abs(back - img).max() <= 0.5 / 65535 + 1e-7
    from PIL import Image

    if D == 1:
        assert np.array(Image.open(tmp_path / "a.png")).dtype == np.uint16 or Image.open(
            tmp_path / "a.png"
        ).mode.startswith("I")
    with pytest.raises(ValueError, match="non-finite"):
        write_png16(tmp_path / "b.png", np.full((2, 2, 1), np.nan))
