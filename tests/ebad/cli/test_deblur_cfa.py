"""``ebad deblur`` on a colour DAVIS capture (issue 29 section 2): the capture's cfa (or --cfa) is used and said."""

from __future__ import annotations

import json

import numpy as np
import pytest

import edi
import scenes
from ebad.cli import main
from edi.cfa import mosaic

CFA = "RGGB"


@pytest.fixture(autouse=True)
def _latents_mode(monkeypatch):
    """With a given c the default colour latent ("pixel") equals the luminance path's on RGB frames;
    these tests check that the cfa reaches edi, so they use the "latents" colour, where it shows."""
    import sys

    monkeypatch.setattr(sys.modules["edi.deblur"], "COLOUR_FROM_MOSAIC", "latents")


@pytest.fixture(scope="module")
def seq():
    return edi.moving_texture(
        height=16, width=20, num_frames=2, channels=3, cfa=CFA, c=0.2, lead=0.02, step_us=100, seed=0
    )


@pytest.fixture()
def capture_dir(tmp_path, seq):
    K = np.array([[20.0, 0, 10], [0, 20.0, 8], [0, 0, 1]])
    cap = scenes.Capture(seq.frames.astype(np.float32), seq.exposures, seq.events, K, cfa=CFA)
    scenes.save(cap, tmp_path / "cap")
    return tmp_path / "cap"


def _png16(path):
    from scenes.images import read_image

    return np.asarray(read_image(path, "png"), np.float64)


def test_deblur_a_capture_with_a_cfa_says_so_and_deblurs_per_pixel(tmp_path, capture_dir, seq, capsys):
    out = tmp_path / "o"
    assert main(["deblur", str(capture_dir), "--c", "0.2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "ebad deblur: the capture has a colour filter array (cfa RGGB) per-pixel EDI on the Bayer mosaic" in text
    last = text.strip().splitlines()[-1]
    assert "written to" in last and "colour DAVIS (cfa RGGB): per-pixel EDI on the Bayer mosaic, RGB latents" in last
    assert json.loads((out / "c.json").read_text())["cfa"] == CFA
    cap = scenes.load(capture_dir)
    got = _png16(out / "sharp" / f"{cap.names[1]}.png" if cap.names else out / "sharp" / "0001.png")
    want = edi.deblur(cap.frames[1], cap.exposures[1], cap.events, c=0.2, cfa=CFA)
    lum = edi.deblur(cap.frames[1], cap.exposures[1], cap.events, c=0.2)
    assert np.abs(got - want).max() < 1e-4 and np.abs(got - lum).max() > 0.1
    # mEDI: per pixel of the mosaic too
    assert main(["deblur", str(capture_dir), "--c", "0.2", "--medi", "--out", str(tmp_path / "m")]) == 0
    got = _png16(
        tmp_path / "m" / "sharp" / f"{cap.names[1]}.png" if cap.names else tmp_path / "m" / "sharp" / "0001.png"
    )
    want = edi.medi(cap.frames, cap.exposures, cap.events, c=0.2, cfa=CFA)[1]
    assert np.abs(got - want).max() < 1e-4


def test_deblur_cfa_argument_for_a_frame_image_and_its_errors(tmp_path, capture_dir, seq, capsys):
    from PIL import Image

    png = tmp_path / "raw.png"
    raw8 = np.round(mosaic(seq.frames[1], CFA) * 255).astype(np.uint8)  # a raw mosaic, one channel
    Image.fromarray(raw8).save(png)
    ev = seq.events
    npz = tmp_path / "ev.npz"
    np.savez(npz, t=ev.t, x=ev.x, y=ev.y, p=ev.p, width=ev.width, height=ev.height)
    ex = [str(v) for v in seq.exposures[1]]
    args = ["deblur", str(png), "--events", str(npz), "--exposure", *ex, "--c", "0.2"]
    assert main([*args, "--cfa", "rggb", "--out", str(tmp_path / "o")]) == 0
    text = capsys.readouterr().out
    assert "(cfa RGGB)" in text and text.strip().splitlines()[-1].endswith("Bayer mosaic, raw latents")
    got = _png16(tmp_path / "o" / "sharp" / "raw.png")
    want = edi.deblur(raw8, seq.exposures[1], ev, c=0.2, cfa=CFA)
    assert got.shape == raw8.shape + (1,) and np.abs(got[..., 0] - want).max() < 1e-4
    # a bad pattern, and one that disagrees with the capture's: one line each, exit 2
    assert main([*args, "--cfa", "RGBG", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "--cfa: 'RGBG' is not a Bayer pattern" in err and len(err.strip().splitlines()) == 1
    assert main(["deblur", str(capture_dir), "--cfa", "BGGR", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "--cfa BGGR disagrees with" in err and "records cfa RGGB" in err and len(err.strip().splitlines()) == 1
