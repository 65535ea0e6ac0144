"""``ebad.data.EdiTables``: what L_EDI's targets need to follow a learnt camera response (``ebad.response``)."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from ebad.config import preset
from ebad.data import EDI_SCALES, downscale, prepare
from ebad.response import Response


@pytest.fixture(scope="module")
def data_and_cfg():
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1)
    cfg = preset("ebad")
    cfg.model.response = "gamma"
    cfg.loss.contrast = (0.2, 0.2)  # the events' own units: one scale (s = 1)
    return prepare(sc.capture, cfg), cfg, sc


def test_tables_follow_the_frames_targets_and_reproduce_edi_at_the_identity(data_and_cfg):
    data, _, _ = data_and_cfg
    tab = data.edi_tables
    assert tab is not None and tab.scales.tolist() == [1.0]  # a configured c: no scale to follow
    r = Response("gamma")  # starts at the identity
    for f in range(data.num_frames):
        views = data.view_latents[f] if data.view_latents is not None else None
        want = views if views is not None else data.latents[f][None]
        assert tab.e_at[f].shape == (want.shape[0], data.height, data.width)
        got = tab.targets(f, data.frames[f], r, data.c_recorded)
        assert not got.requires_grad  # the targets do not pull on the curve
        # EDI's own latents, up to its eps: L = (B + eps) e^r - eps there, B e^r here (eps 1e-3; max 2.6e-3)
        np.testing.assert_allclose(got.numpy(), want.numpy(), atol=3e-3)
        assert float((got - want).abs().mean()) < 3e-4  # 1.6e-4 on frame 0


def test_tables_with_an_estimated_c_hold_every_scale_and_follow_downscale_and_a_new_v(data_and_cfg):
    _, _, sc = data_and_cfg
    cfg = preset("ebad")
    cfg.model.response = "gamma"
    data = prepare(sc.capture, cfg)
    tab = data.edi_tables
    assert tab is not None and data.c_recorded and tuple(tab.scales.tolist()) == pytest.approx(EDI_SCALES)
    assert tab.logmean[0].shape == (len(EDI_SCALES), data.height, data.width)
    small = downscale(data, 2)
    assert small.edi_tables is not None and small.edi_tables.logmean[0].shape[-2:] == (
        data.height // 2,
        data.width // 2,
    )
    blurry = [f for f in range(data.num_frames) if data.V[f] > 1]
    V = data.V.copy()
    V[blurry[0]] += 2
    data.set_views(V)
    assert tab.e_at[blurry[0]].shape[0] == V[blurry[0]] == data.view_latents[blurry[0]].shape[0]
    # no tables without a learnt response
    cfg.model.response = "linear"
    assert prepare(sc.capture, cfg).edi_tables is None
