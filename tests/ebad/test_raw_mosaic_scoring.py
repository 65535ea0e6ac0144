"""A colour-DAVIS capture given as raw Bayer mosaics trains, evaluates (with test-pose refinement)
and scores its renders through their mosaic against the raw test images."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from ebad import reconstruct
from ebad.config import preset
from ebad.evaluate import evaluate
from ebad.metrics import psnr
from edi.cfa import mosaic


@pytest.fixture(scope="module")
def raw_run():
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=2, cfa="RGGB", raw_frames=True)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = 4, False, 2
    return sc, reconstruct(sc.capture, cfg)


def test_raw_frames_train_in_colour_and_score_through_the_mosaic(raw_run):
    sc, run = raw_run
    assert sc.capture.raw_mosaic and run.channels == 3
    out = evaluate(run, sc.capture, refine=True, refine_iters=3)
    views = [v for v in sc.capture.test_views if v.image is not None]
    assert views and views[0].image.shape[-1] == 1
    renders = run.render(np.stack([out_pose for out_pose in (run.test_c2w.get(v.name, v.c2w) for v in views)]))
    want = np.mean([psnr(mosaic(r, "RGGB")[..., None], v.image) for r, v in zip(renders, views)])
    assert out["test"].psnr == pytest.approx(want, abs=1e-4)
    assert np.isfinite(out["test_refined"].psnr)
    assert run.metrics is not None and run.metrics.test is not None  # the training-time evaluator scored too
