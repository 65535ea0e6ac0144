"""``ebad render``: 8-bit sRGB PNGs by default (read by Pillow), 16-bit linear on request."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from ebad.cli import main
from ebad.export import to_display8
from ebad.io import read_png16
from ebad.runfolder import load_run


def test_render_default_is_8bit_srgb_that_pillow_reads(tiny_run, tmp_path, capsys):
    out = tmp_path / "train8"
    assert main(["render", str(tiny_run.run), "--split", "train", "--out", str(out)]) == 0
    assert "8-bit sRGB" in capsys.readouterr().out
    run = load_run(tiny_run.run)
    expect = to_display8(run.deblurred_frames())  # [F, H, W, 1]
    for name, e in zip(run.names, expect):
        with Image.open(out / f"{name}.png") as im:
            assert im.mode == "L" and im.size == (run.width, run.height)  # grey stays one channel
            got = np.asarray(im)
        np.testing.assert_array_equal(got, e[..., 0])
    # the display encoding brightens mid-tones: the 8-bit value exceeds 255 * linear there
    lin = run.deblurred_frames()[0, ..., 0]
    mid = (lin > 0.05) & (lin < 0.6)
    assert mid.any() and np.all(expect[0, ..., 0][mid] > np.round(255 * lin[mid]))


def test_render_bits16_is_linear(tiny_run, tmp_path):
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
    with Image.open(tmp_path / "path" / "path_0003.png") as im:
        assert im.size == (64, 48) and im.mode == "L"


@pytest.mark.parametrize("argv, needle", [
    (["--split", "test"], "--capture is required"),
    (["--path", "1"], "--path needs at least 2"),
])
def test_render_user_errors_exit_2_naming_the_option(tiny_run, tmp_path, capsys, argv, needle):
    assert main(["render", str(tiny_run.run), "--out", str(tmp_path / "x"), *argv]) == 2
    assert needle in capsys.readouterr().err
