"""One colour domain from the input to every output (issue 29 section 4): renders, PNGs, the PLY, the
``.splat`` and the viewer are in the capture's recorded domain, the run's response applied once."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import scenes
from ebad.cli import main
from ebad.export import (
    SPLAT_FILE,
    TUM_FILE,
    from_recorded_params,
    model_colors,
    read_splat,
    read_tum,
    recorded_colors,
    srgb_encode,
    to_recorded_params,
    write_exports,
    write_render,
)
from ebad.gaussians import SH_C0
from ebad.io import read_ply
from ebad.response import Response
from ebad.runfolder import load_run, write_run

GAMMA_RAW = [-1.5, 0.2, -0.35]  # black 0.5 sigmoid(-1.5) = 0.091, gain exp(0.2) = 1.22, gamma exp(-0.35) = 0.70


def _gamma_response() -> Response:
    r = Response("gamma")
    with torch.no_grad():
        r.raw.copy_(torch.tensor(GAMMA_RAW))
    return r


@pytest.fixture(scope="module")
def gamma_run(tiny_run, tmp_path_factory):
    """The tiny run with a non-identity camera response, written as a run folder: (in-memory run, folder)."""
    run = load_run(tiny_run.run)
    run.response = _gamma_response()
    out = tmp_path_factory.mktemp("gamma_run") / "run"
    write_run(run, out)
    return run, out


def _tone(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:  # mean |a - b|, mean(a - b), PSNR
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    return float(np.abs(d).mean()), float(d.mean()), float(-10 * np.log10((d**2).mean()))


def test_a_training_view_render_has_the_tone_of_its_input_frame(tiny_run, tmp_path):
    """The tiny run (3 steps): each training frame rendered at its recovered mid-exposure pose and written
    by ``ebad render`` reads back near its blurry input frame; with the old sRGB curve on top it was far
    brighter (mean +0.15)."""
    out = tmp_path / "train"
    assert main(["render", str(tiny_run.run), "--split", "train", "--out", str(out)]) == 0
    run = load_run(tiny_run.run)
    cap = scenes.load(tiny_run.capture)
    frames = np.stack([cap.frames[cap.names.index(n)] for n in run.names])
    back = np.stack([scenes.read_image(out / f"{n}.png") for n in run.names])
    mad, bias, psnr = _tone(back, frames)
    assert mad == pytest.approx(0.10, abs=0.03) and abs(bias) < 0.08 and psnr > 15.0
    old = np.round(255 * srgb_encode(run.deblurred_frames())) / 255  # the encoding before this change
    mad_old, bias_old, psnr_old = _tone(old, frames)
    assert mad_old > 0.15 and bias_old > 0.12 and psnr_old < 14.5


@pytest.mark.slow
def test_a_trained_render_matches_its_input_frames_tone():
    """100 steps on the tiny boxes scene: render vs input frame 26.2 dB, mean level within 0.002 (the sRGB
    curve on top: 14.3 dB, +0.178)."""
    from ebad import reconstruct
    from ebad.config import preset

    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=6, n_test=1)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 100, False, 0
    torch.manual_seed(0)
    run = reconstruct(sc.capture, cfg)
    db = run.deblurred_frames()
    frames = np.asarray(sc.capture.frames)
    mad, bias, psnr = _tone(np.round(255 * db.astype(np.float64)) / 255, frames)
    assert psnr > 24.5 and abs(bias) < 0.01 and mad < 0.045
    _, bias_old, psnr_old = _tone(np.round(255 * srgb_encode(db)) / 255, frames)
    assert psnr_old < 16.0 and bias_old > 0.15


def test_recorded_colors_is_the_response_and_model_colors_inverts_it():
    r = _gamma_response()
    c = np.linspace(0.01, 0.8, 50)[:, None].repeat(3, 1)  # below saturation (gain * c < 1)
    want = r(torch.from_numpy(c)).detach().numpy()
    np.testing.assert_allclose(recorded_colors(c, r), want, rtol=1e-5, atol=1e-6)
    big = np.linspace(0.0, 3.0, 40)[:, None]
    np.testing.assert_allclose(model_colors(recorded_colors(big, r, saturate=False), r), big, atol=1e-9)
    assert recorded_colors(big, r).max() == 1.0  # saturated for display
    np.testing.assert_array_equal(recorded_colors(big, Response("linear")), np.clip(big, 0, 1))
    # the identity response leaves the parameters untouched (bit-exact PLY, as before)
    p = {"colors": torch.randn(5, 3), "means": torch.randn(5, 3)}
    assert to_recorded_params(p, Response("linear")) is p and from_recorded_params(p, None) is p
    back = from_recorded_params(to_recorded_params(p, r), r)
    act = (0.5 + SH_C0 * p["colors"]).clamp_min(0)
    torch.testing.assert_close((0.5 + SH_C0 * back["colors"]).clamp_min(0), act, atol=1e-5, rtol=1e-5)


def test_ply_and_splat_show_the_same_colours(gamma_run):
    run, out = gamma_run
    ply = read_ply(out / "point_cloud.ply")
    splat = read_splat(out / SPLAT_FILE)
    rgb = np.clip(0.5 + SH_C0 * ply["colors"].double().numpy(), 0, 1)  # what a 3DGS viewer shows
    rgb = np.repeat(rgb, 3, 1) if rgb.shape[1] == 1 else rgb
    # match the Gaussians by their centres (the .splat is sorted by size * opacity)
    order = [int(np.argmin(np.abs(ply["means"].numpy() - m).sum(1))) for m in splat["means"]]
    assert np.abs(splat["colors"] - rgb[order]).max() <= 0.5 / 255 + 1e-6
    # and they are the response's colours, not the model's irradiance
    irr = (0.5 + SH_C0 * run.params["colors"].detach().double()).clamp_min(0).numpy()
    irr = np.repeat(irr, 3 // irr.shape[1], 1)
    np.testing.assert_allclose(rgb, np.clip(recorded_colors(irr, run.response), 0, 1), atol=1e-5)
    assert np.abs(rgb - np.clip(irr, 0, 1)).mean() > 0.05


def test_viewer_colours_are_the_splat_colours(gamma_run):
    from ebad.cli.view import splat_arrays

    run, _ = gamma_run
    arrays = splat_arrays(run.params, run.response)
    irr = (0.5 + SH_C0 * run.params["colors"].detach().double()).clamp_min(0).numpy()
    want = np.repeat(recorded_colors(irr, run.response), 3 // irr.shape[1], 1)
    np.testing.assert_allclose(arrays["rgbs"], want, atol=1e-6)


def test_render_output_reads_back_as_the_response_of_the_render(gamma_run, tmp_path):
    """``ebad render`` of a run with a learnt response: the PNG read back with ``scenes.read_image`` equals
    the in-memory response(render) to half an 8-bit step; the run folder round-trips its colours."""
    run, folder = gamma_run
    want = run.deblurred_frames()  # Run.render: the response applied
    for bits, tol in ((8, 0.5 / 255), (16, 0.5 / 65535)):
        out = tmp_path / f"r{bits}"
        assert main(["render", str(folder), "--split", "train", "--bits", str(bits), "--out", str(out)]) == 0
        back = np.stack([scenes.read_image(out / f"{n}.png") for n in run.names])
        assert np.abs(back - want).max() <= tol + 2e-5  # 2e-5: the PLY's float32 colours through the curve
    assert json.loads((folder / "model.json").read_text())["response"]["kind"] == "gamma"


def test_deblur_and_render_write_the_same_encoding(tmp_path):
    from ebad.cli.deblur import _save

    img = np.random.default_rng(3).uniform(0, 1, (6, 7, 3)).astype(np.float32)
    for bits in (8, 16):
        _save(tmp_path / f"d{bits}.png", img, bits)
        write_render(tmp_path / f"r{bits}.png", img, bits)
        a, b = scenes.read_image(tmp_path / f"d{bits}.png"), scenes.read_image(tmp_path / f"r{bits}.png")
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(a, img, atol=0.5 / (2**bits - 1) + 1e-7)


def test_tum_has_one_line_per_timestamp(tiny_run, tmp_path):
    """A sharp frame (t_start == t_end) gives one TUM line, not nine repeats of its timestamp."""
    run = load_run(tiny_run.run)
    t0 = float(run.exposures[0, 0])
    run.exposures = run.exposures.copy()
    run.exposures[0] = [t0, t0]
    write_exports(run, tmp_path)
    t, c2w = read_tum(tmp_path / TUM_FILE)
    assert len(np.unique(t)) == len(t) == 1 + 9 * (len(run.names) - 1)
    assert np.all(np.diff(t) > 0) and t[0] == t0


def test_a_run_folder_fits_the_sh_colours_through_the_response_once(tiny_run, tmp_path, monkeypatch):
    """With view-dependent colour and a learnt response the PLY's SH are a least-squares fit through the
    curve; the ``.splat`` shows that fit's DC, taken from the same fit (not a second one)."""
    import ebad.export as export

    run = load_run(tiny_run.run)
    run.response = _gamma_response()
    n, d = run.params["colors"].shape
    run.params["sh_rest"] = 0.05 * torch.randn(n, 15, d, generator=torch.Generator().manual_seed(0))
    fits = []
    real = export._refit_sh
    monkeypatch.setattr(export, "_refit_sh", lambda *a, **k: fits.append(1) or real(*a, **k))
    write_run(run, tmp_path / "run")
    assert len(fits) == 1
    ply, splat = read_ply(tmp_path / "run" / "point_cloud.ply"), read_splat(tmp_path / "run" / SPLAT_FILE)
    rgb = np.clip(0.5 + SH_C0 * ply["colors"].double().numpy(), 0, 1)
    rgb = np.repeat(rgb, 3, 1) if rgb.shape[1] == 1 else rgb
    order = [int(np.argmin(np.abs(ply["means"].numpy() - m).sum(1))) for m in splat["means"]]
    assert np.abs(splat["colors"] - rgb[order]).max() <= 0.5 / 255 + 1e-6
