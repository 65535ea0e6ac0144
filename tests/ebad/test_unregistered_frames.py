"""Frames SfM did not register: ``prepare`` leaves them out and says so, and ``evaluate`` scores
the deblurred frames of the rest against their own ground truth, picked by name."""

from __future__ import annotations

import copy
import logging
from types import SimpleNamespace

import numpy as np
import pytest

import scenes
import scenes.colmap
from ebad.config import preset
from ebad.data import prepare
from ebad.errors import UserError
from ebad.evaluate import evaluate, run_truth, score_frames
from ebad.runfolder import load_run


def test_prepare_leaves_out_the_frames_sfm_did_not_register_and_says_which(monkeypatch, caplog):
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=5, n_test=1, poses="none")
    registered = np.array([True, True, False, True, False])

    def fake_sfm(capture, cfg=None):  # the true poses; frames 2 and 4 not registered
        return SimpleNamespace(c2w=sc.gt_c2w, registered=registered, points=[], colors=[], test_c2w={})

    monkeypatch.setattr(scenes.colmap, "estimate_poses", fake_sfm)
    cfg = preset("3dgs")
    cfg.train.progress = False
    with caplog.at_level(logging.WARNING, logger="ebad.data"):
        data = prepare(sc.capture, cfg)
    names = sc.capture.frame_names()
    assert data.names == [names[0], names[1], names[3]]
    assert data.report.unregistered_frames == [names[2], names[4]]
    assert data.report.train_frames == 3 and data.report.pose_source == "colmap"
    assert np.allclose(data.c2w.numpy(), sc.gt_c2w[[0, 1, 3]], atol=1e-6)
    assert "did not register 2 of 5 training frames" in caplog.text and names[4] in caplog.text

    registered[:] = True  # all registered: nothing said, nothing left out
    caplog.clear()
    data = prepare(sc.capture, cfg)
    assert data.report.unregistered_frames is None and data.names == names
    assert "did not register" not in caplog.text


def test_evaluate_scores_the_run_frames_against_their_own_truth_by_name(tiny_run):
    """A run whose frames 1 and 3 are missing (SfM left them out): ``gt_frames`` given per capture
    frame, as a synthetic scene holds them, are picked by the run's names."""
    full = load_run(tiny_run.run)
    cap = scenes.load(tiny_run.capture)
    names = cap.frame_names()
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.1, 0.9, size=(len(names), *full.deblurred_frames().shape[1:])).astype(np.float32)
    keep = [0, 2, 4, 5]
    run = copy.copy(full)
    run.names = [names[k] for k in keep]
    rendered = gt[keep] + 0.01 * np.arange(1, len(keep) + 1, dtype=np.float32)[:, None, None, None]
    run.deblurred_frames = lambda: rendered  # what the run's renders would be: truth plus a known offset per frame

    assert np.array_equal(run_truth(run, gt, cap), gt[keep])
    assert np.array_equal(run_truth(run, gt[keep], cap), gt[keep])  # already one per run frame
    res = evaluate(run, cap, gt_frames=gt)
    want = float(np.mean([-10 * np.log10((0.01 * k) ** 2) for k in range(1, 5)]))
    assert res["deblurred"].n == 4
    assert res["deblurred"].psnr == pytest.approx(want, abs=0.01)  # 34.0, 37.0 ... per frame, averaged
    assert res["deblurred"].psnr == pytest.approx(score_frames(rendered, gt[keep]).psnr, abs=1e-9)

    with pytest.raises(UserError, match="do not match the run's frames"):  # neither per run frame nor per capture frame
        evaluate(run, cap, gt_frames=gt[:3])
    stranger = copy.copy(run)
    stranger.names = ["frame_that_is_not_there"] + run.names[1:]
    with pytest.raises(UserError, match="frame_that_is_not_there"):
        run_truth(stranger, gt, cap)
