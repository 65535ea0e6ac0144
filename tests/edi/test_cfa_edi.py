"""EDI, mEDI and the contrast estimate on a colour DAVIS (issue 29 section 2): per pixel of the Bayer mosaic.

The figures pinned here come from ``moving_texture(cfa="RGGB")`` (each pixel's events fire on its own
channel, the frames are the bilinear demosaic of the blurry mosaic), 32 x 40 px, 3 frames, c = 0.2.
"""

from __future__ import annotations

import hashlib
import logging

import numpy as np
import pytest
import torch

import edi
from edi import InputError, deblur, deblur_with_report, estimate_contrast, medi, moving_texture
from edi.cfa import demosaic, mosaic

CFA = "RGGB"


@pytest.fixture(autouse=True)
def _latents_mode(monkeypatch):
    """These tests pin the "latents" colour (the demosaic of the per-pixel latents) on moving_texture,
    whose channels are independent textures; the default, "pixel", is pinned in test_cfa_pixel_colour."""
    import sys

    monkeypatch.setattr(sys.modules["edi.deblur"], "COLOUR_FROM_MOSAIC", "latents")


def psnr(a, b) -> float:
    return float(10 * np.log10(1.0 / np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def sha(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(np.asarray(a, np.float64)).tobytes()).hexdigest()[:16]


@pytest.fixture(scope="module")
def seq():
    return moving_texture(height=32, width=40, num_frames=3, channels=3, cfa=CFA, c=0.2, lead=0.05, step_us=100, seed=0)


@pytest.fixture(autouse=True)
def _quiet():
    logging.getLogger("edi.contrast").setLevel(logging.ERROR)  # the luminance estimates warn, by design
    yield
    logging.getLogger("edi.contrast").setLevel(logging.NOTSET)


# --- the simulator --------------------------------------------------------------------------------


def test_moving_texture_cfa_fires_each_pixel_on_its_own_channel(seq):
    """Events of a pixel sum to the log change of its own channel (within one threshold), and the
    frames are the demosaic of the blurry mosaic (its own channel exact)."""
    ex = seq.exposures
    t0, t1 = ex[0, 0], ex[2, 1]
    i0, i1 = edi.events_in_window(seq.events, t0, t1)
    win = seq.events[i0:i1]
    n = win.count_image(1).astype(np.float64) - win.count_image(-1)
    d = np.log(seq.sharp_mosaic(t1 - 100e-6) + edi.LOG_EPS) - np.log(seq.sharp_mosaic(t0 - 100e-6) + edi.LOG_EPS)
    assert np.abs(d - 0.2 * n).max() < 2 * 0.2 + 1e-9  # each end within c of its reference level
    d_grey = np.log(seq.sharp(t1 - 100e-6).mean(-1) + edi.LOG_EPS) - np.log(
        seq.sharp(t0 - 100e-6).mean(-1) + edi.LOG_EPS
    )
    assert np.abs(d_grey - 0.2 * n).max() > 0.5  # not the grey level's events
    raw = mosaic(seq.frames, CFA)
    np.testing.assert_array_equal(seq.frames, np.clip(demosaic(raw, CFA), 0, 1))
    assert seq.cfa == CFA


def test_moving_texture_cfa_needs_three_channels_and_a_pattern():
    with pytest.raises(InputError, match="channels=3"):
        moving_texture(cfa=CFA)
    with pytest.raises(InputError, match="cfa"):
        moving_texture(channels=3, cfa="RGBG")
    with pytest.raises(InputError, match="no cfa"):
        moving_texture(num_frames=1, exposure=0.001).sharp_mosaic(0.0)


# --- without a cfa nothing changed ------------------------------------------------------------------

# taken on the code before the cfa argument existed (same machine, same seeds)
_BEFORE = {
    "frames": "48c7df2017e488ec",
    "events_t": "7657280bcab72a25",
    "deblur": "c959f0a7fc0507aa",
    "deblur_est": "cbecfaef89390533",
    "medi": "f24f0e9e6c632397",
    # the consistency estimate as retaken when the quantisation residual became one pass over the stream
    # (edi._kernels.mean_residual: each interval summed on its own, where prefix sums' differences rounded
    # differently): before, (0.19216205800982217, 0.19274460519324432), 1e-15 away
    "est": (0.19216205800982236, 0.19274460519324454),
    "est1": 0.19707658346755713,
}


def _frames_as_before(s, step_us: int = 50) -> np.ndarray:
    """``s``'s frames as moving_texture made them when the hashes above were taken: each step's image
    rendered alone, a sine per wave and pixel, summed over the waves by einsum. moving_texture now
    renders the waves as products (the same events; frames within rounding of these, 1e-15:
    tests/edi/test_moving_texture.py), so the pins below are kept on the frames they were taken on."""
    tex = s.texture
    yy, xx = np.mgrid[0 : tex.height, 0 : tex.width].astype(np.float64)

    def render(t: float) -> np.ndarray:
        u = xx + 0.5 - tex.velocity[0] * t
        v = yy + 0.5 - tex.velocity[1] * t
        arg = 2 * np.pi * (tex.freqs[:, 0, None, None] * u[None] + tex.freqs[:, 1, None, None] * v[None])
        f = np.einsum("k,khwd->hwd", tex.amps, np.sin(arg[..., None] + tex.phases[:, None, None, :]))
        return tex.lo + (tex.hi - tex.lo) / (1.0 + np.exp(-tex.gain * f))

    frames = []
    for t0, t1 in s.exposures:
        a, b = edi.seconds_to_us(t0), edi.seconds_to_us(t1)
        frames.append(np.mean([render(tj * 1e-6) for tj in range(0, b, step_us) if a <= tj], axis=0))
    return np.stack(frames)


def test_without_cfa_everything_is_bit_identical_to_before():
    s = moving_texture(height=24, width=32, num_frames=3, channels=3, seed=3, lead=0.1)
    assert sha(s.events.t) == _BEFORE["events_t"]
    before = _frames_as_before(s)
    np.testing.assert_allclose(s.frames, before, rtol=0, atol=1e-14)
    s.frames = before
    assert sha(s.frames) == _BEFORE["frames"]
    assert sha(deblur(s.frames[1], s.exposures[1], s.events, c=0.2)) == _BEFORE["deblur"]
    assert sha(deblur(s.frames[1], s.exposures[1], s.events, c=0.2, cfa=None)) == _BEFORE["deblur"]
    assert sha(deblur(s.frames[1], s.exposures[1], s.events)) == _BEFORE["deblur_est"]
    assert tuple(estimate_contrast(s.frames, s.exposures, s.events, pair=True).c) == _BEFORE["est"]
    assert estimate_contrast(s.frames[0], s.exposures[0], s.events).c.pos == _BEFORE["est1"]
    assert sha(medi(s.frames, s.exposures, s.events, c=(0.2, 0.2))) == _BEFORE["medi"]


# --- EDI per pixel of the mosaic --------------------------------------------------------------------


def test_per_pixel_edi_recovers_the_sharp_mosaic_and_colour(seq):
    """With the true c: the mosaic of the latent against the sharp mosaic, and the colour latent
    against the true sharp RGB; events as luminance (no cfa) apply each pixel's own-channel events to
    all three channels and come out worse than the blurry frame in RGB."""
    f = 1
    B, ex = seq.frames[f], seq.exposures[f]
    mid = float(ex.mean())
    L = deblur(B, ex, seq.events, c=0.2, cfa=CFA)
    assert L.shape == B.shape and L.dtype == np.float64
    lum = deblur(B, ex, seq.events, c=0.2)
    gt, gt_m = seq.sharp(mid), seq.sharp_mosaic(mid)
    assert psnr(mosaic(B, CFA), gt_m) == pytest.approx(13.99, abs=0.01)  # the blurry mosaic
    assert psnr(mosaic(L, CFA), gt_m) == pytest.approx(26.99, abs=0.01)
    assert psnr(L, gt) == pytest.approx(21.13, abs=0.01)  # the bilinear demosaic of the truth: 22.51
    assert psnr(demosaic(gt_m, CFA), gt) == pytest.approx(22.51, abs=0.01)
    assert psnr(B, gt) == pytest.approx(13.75, abs=0.01)
    assert psnr(lum, gt) == pytest.approx(11.56, abs=0.01)
    # the colour latent is the demosaic of the per-pixel latents
    np.testing.assert_allclose(L, np.clip(demosaic(mosaic(L, CFA), CFA), 0, 1), atol=1e-12)


def test_with_estimated_c_the_cfa_path_beats_events_as_luminance_on_the_mosaic(seq):
    f = 1
    B, ex = seq.frames[f], seq.exposures[f]
    gt_m = seq.sharp_mosaic(float(ex.mean()))
    L, rep = deblur_with_report(B, ex, seq.events, cfa=CFA)
    lum, rep_l = deblur_with_report(B, ex, seq.events)
    assert rep.c.mean == pytest.approx(0.2232, abs=5e-4) and rep.c_report is not None
    assert rep_l.c.mean == pytest.approx(0.3368, abs=5e-4)  # the Bayer pattern read as texture
    assert psnr(mosaic(L, CFA), gt_m) == pytest.approx(26.78, abs=0.01)
    assert psnr(mosaic(lum, CFA), gt_m) == pytest.approx(21.45, abs=0.01)


def test_raw_frames_in_give_raw_latents_out(seq):
    f = 1
    B, ex = seq.frames[f], seq.exposures[f]
    raw = mosaic(B, CFA)
    L = deblur(B, ex, seq.events, c=0.2, cfa=CFA)
    for r in (raw, raw[..., None]):
        out = deblur(r, ex, seq.events, c=0.2, cfa=CFA)
        assert out.shape == r.shape
        np.testing.assert_allclose(out.reshape(raw.shape), mosaic(L, CFA), atol=1e-12)
    # times: [F, H, W]; torch in, torch out
    out = deblur(torch.from_numpy(raw), ex, seq.events, times=[ex[0], ex.mean()], c=0.2, cfa=CFA)
    assert isinstance(out, torch.Tensor) and tuple(out.shape) == (2,) + raw.shape
    # the estimate sees the same mosaic either way
    a = estimate_contrast(raw, ex, seq.events, cfa=CFA).c
    b = estimate_contrast(B, ex, seq.events, cfa=CFA).c
    assert a == b


def test_with_a_response_the_colour_latent_is_demosaiced_in_recorded_units(seq):
    g = 0.8
    B, ex = seq.frames[1] ** g, seq.exposures[1]  # recorded = irradiance ** g
    raw = mosaic(B, CFA)
    lat_raw = deblur(raw, ex, seq.events, c=0.2, gamma=g, cfa=CFA)
    np.testing.assert_allclose(lat_raw, (deblur(raw ** (1 / g), ex, seq.events, c=0.2, cfa=CFA)) ** g, atol=1e-12)
    lat = deblur(B, ex, seq.events, c=0.2, gamma=g, cfa=CFA)
    np.testing.assert_allclose(lat, np.clip(demosaic(lat_raw, CFA), 0, 1), atol=1e-12)


def test_a_bad_cfa_or_frame_names_it(seq):
    B, ex = seq.frames[1], seq.exposures[1]
    with pytest.raises(InputError, match="cfa"):
        deblur(B, ex, seq.events, c=0.2, cfa="RGBB")
    with pytest.raises(InputError, match="blur: with a cfa.*2 channels"):
        deblur(B[..., :2], ex, seq.events, c=0.2, cfa=CFA)
    with pytest.raises(InputError, match="frames: with a cfa"):
        estimate_contrast(np.stack([B[..., :2]] * 2), seq.exposures[:2], seq.events, cfa=CFA)


# --- the contrast threshold: one c shared by the channels -------------------------------------------


def test_shared_c_estimate_on_the_mosaic_is_near_the_truth(seq):
    """Three frames (consistency, same-filter neighbours as instruments) and one frame (flow energy
    on the four sub-grids); events as luminance read the Bayer pattern as texture."""
    shared = estimate_contrast(seq.frames, seq.exposures, seq.events, pair=True, cfa=CFA)
    assert shared.method == "consistency" and shared.reliable
    assert shared.c.mean == pytest.approx(0.2018, abs=5e-4)
    one = estimate_contrast(seq.frames[1], seq.exposures[1], seq.events, cfa=CFA)
    assert one.method == "single" and one.reliable
    assert one.c.mean == pytest.approx(0.2232, abs=5e-4)  # 16 x 16 patches of the sub-grids: 0.2345
    lum = estimate_contrast(seq.frames, seq.exposures, seq.events, pair=True)
    assert lum.c.mean == pytest.approx(0.2534, abs=5e-4)
    assert edi.estimate_c(seq.frames, seq.exposures, seq.events, pair=True, cfa=CFA) == shared.c


# --- mEDI ----------------------------------------------------------------------------------------------


def test_medi_per_pixel_of_the_mosaic(seq):
    lat = medi(seq.frames, seq.exposures, seq.events, c=0.2, cfa=CFA)
    assert lat.shape == seq.frames.shape
    gt_m = [seq.sharp_mosaic(float(e.mean())) for e in seq.exposures]
    gt = [seq.sharp(float(e.mean())) for e in seq.exposures]
    p_m = np.mean([psnr(mosaic(lat[i], CFA), gt_m[i]) for i in range(3)])
    p_rgb = np.mean([psnr(lat[i], gt[i]) for i in range(3)])
    lum = medi(seq.frames, seq.exposures, seq.events, c=0.2)
    p_lum = np.mean([psnr(lum[i], gt[i]) for i in range(3)])
    assert p_m == pytest.approx(26.41, abs=0.01)
    assert p_rgb == pytest.approx(20.91, abs=0.01)
    assert p_lum == pytest.approx(10.37, abs=0.01)  # the blurry frames: 13.64
    raw = mosaic(seq.frames, CFA)
    lat_raw = medi(raw, seq.exposures, seq.events, c=0.2, cfa=CFA)
    assert lat_raw.shape == raw.shape
    np.testing.assert_allclose(lat_raw, mosaic(lat, CFA), atol=1e-12)


# --- the measurements behind the choices (shared c; colour from the demosaiced latents) ----------------


@pytest.mark.slow
def test_shared_c_and_colour_latents_measured_on_five_seeds():
    """moving_texture(cfa="RGGB") 40 x 56, 3 frames, c = 0.2, seeds 0-4: the shared estimate against one
    c per filter's sub-grid (same estimator, same patch area), and the two colour latents of
    ``model.colour_latents`` against the true sharp RGB (true c)."""
    from edi.contrast import FLOW_SUB_PATCH, FLOW_SUBINTERVALS, _flow_setup, _subgrids
    from edi.model import colour_latents, edi_log_ratio, latent_from_ratio

    err: dict[str, list[float]] = {"shared1": [], "sharedm": [], "per1": [], "perm": []}
    dbs: dict[str, list[float]] = {"latents": [], "ratio": []}
    for seed in range(5):
        s = moving_texture(height=40, width=56, num_frames=3, channels=3, cfa=CFA, lead=0.05, step_us=100, seed=seed)
        B, ex = s.frames[1], s.exposures[1]
        err["shared1"].append(abs(estimate_contrast(B, ex, s.events, cfa=CFA).c.mean - 0.2))
        err["sharedm"].append(abs(estimate_contrast(s.frames, s.exposures, s.events, pair=True, cfa=CFA).c.mean - 0.2))
        subs = [_subgrids(mosaic(f, CFA)[..., None], s.events) for f in s.frames]
        defaults = _flow_setup.__defaults__
        try:
            _flow_setup.__defaults__ = (FLOW_SUB_PATCH, FLOW_SUBINTERVALS)  # per channel: the shared path's patches
            for k in range(4):
                ev_k = subs[0][k][1]
                fr_k = np.stack([sub[k][0] for sub in subs])
                err["per1"].append(abs(estimate_contrast(fr_k[1], ex, ev_k).c.mean - 0.2))
                err["perm"].append(abs(estimate_contrast(fr_k, s.exposures, ev_k, pair=True).c.mean - 0.2))
        finally:
            _flow_setup.__defaults__ = defaults
        mid = float(ex.mean())
        r, _ = edi_log_ratio(s.events, (float(ex[0]), float(ex[1])), np.array([mid]), (0.2, 0.2))
        lat_raw, _ = latent_from_ratio(mosaic(B, CFA)[..., None], r)
        for how in dbs:
            lat, _ = colour_latents(B, r, lat_raw, CFA, 1.0, edi.SATURATION, how)
            dbs[how].append(psnr(lat[0], s.sharp(mid)))
    m = {k: float(np.mean(v)) for k, v in err.items()}
    assert m["shared1"] == pytest.approx(0.0053, abs=1e-4) and m["per1"] == pytest.approx(0.0129, abs=1e-4)
    assert m["sharedm"] == pytest.approx(0.0018, abs=1e-4) and m["perm"] == pytest.approx(0.0021, abs=1e-4)
    assert np.mean(dbs["latents"]) == pytest.approx(21.69, abs=0.01)
    assert np.mean(dbs["ratio"]) == pytest.approx(21.78, abs=0.01)  # a tie across setups (edi.deblur)
