"""A camera on a tripod (issue 30, item 1): cameras that do not move start a visible scene, and a
run whose renders stay empty stops with an error instead of finishing with a black scene."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
import torch

import scenes
from ebad import reconstruct
from ebad.cli import main
from ebad.config import preset
from ebad.data import STATIC_DEPTH_RANGE, STILL_CHANGED, changed_fraction, prepare
from ebad.errors import UserError
from ebad.gaussians import render
from ebad.loop import EMPTY_ALPHA
from ebad.state import init_gaussians

STEPS = 4


@pytest.fixture(scope="module")
def tripod():
    """A tiny capture whose cameras all sit at the first frame's pose, seeing its sharp image: a
    static scene on a tripod, so no event either (the moving scene's events would fall between the
    exposures, which ``prepare`` refuses as a likely time-unit mistake)."""
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=4, n_test=1, shake=0, sensor="ideal")
    cap = sc.capture
    F = cap.num_frames
    return dataclasses.replace(
        cap,
        frames=np.repeat(cap.frames[:1], F, axis=0),
        c2w=np.repeat(np.asarray(cap.c2w)[:1], F, axis=0),
        events=cap.events[:0],
        pose_trust="exact",
    )


def _cfg(pose_source: str = "auto"):
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.progress, cfg.train.eval_every = STEPS, False, 0
    cfg.train.empty_render_steps = STEPS
    cfg.loss.contrast = (0.25, 0.25)  # the frames are all one image: nothing to estimate c from
    cfg.trajectory.pose_source = pose_source  # type: ignore[assignment]
    return cfg


@pytest.mark.parametrize("pose_source", ["static", "capture"])
def test_cameras_that_do_not_move_start_a_visible_scene(tripod, pose_source, caplog):
    cfg = _cfg(pose_source)
    data = prepare(tripod, cfg)
    assert data.depth_range == STATIC_DEPTH_RANGE and data.scale == pytest.approx(1.0)
    with caplog.at_level(logging.WARNING, logger="ebad.gaussians"):
        params = init_gaussians(data, cfg)
    assert "plane-sweep initialisation skipped" in caplog.text and "do not move" in caplog.text
    _, alphas, _ = render(params, data.c2w[:1], data.K, data.width, data.height)
    assert float(alphas.detach().max()) > 0.5


def test_a_tripod_run_renders_something_after_a_few_steps(tripod):
    torch.manual_seed(0)
    run = reconstruct(tripod, _cfg("static"))  # empty renders would raise UserError here
    assert run.metrics is not None and run.metrics.steps == STEPS
    assert all(h.alpha is not None and h.alpha > EMPTY_ALPHA for h in run.history)


def test_empty_renders_stop_the_run_with_an_error(tripod):
    cfg = _cfg("static")
    cfg.model.init_depth = (0.002, 0.005)  # every Gaussian in front of the rasteriser's 0.01 near plane
    with pytest.raises(UserError, match=r"every render of the first 4 steps is empty.*--model.init_depth"):
        reconstruct(tripod, cfg)
    cfg.train.empty_render_steps = 0  # the check off: the run finishes (black)
    assert reconstruct(tripod, cfg).metrics.steps == STEPS


def test_the_cli_exits_non_zero_on_empty_renders(tripod, tmp_path, capsys):
    scenes.save(tripod, tmp_path / "cap")
    rc = main(
        [
            "reconstruct",
            str(tmp_path / "cap"),
            "--out",
            str(tmp_path / "run"),
            "--no-progress",
            "--train.iters",
            "3",
            "--train.eval_every",
            "0",
            "--train.empty_render_steps",
            "2",
            "--model.init_depth",
            "0.002",
            "0.005",
            "--loss.contrast",
            "0.25",
            "0.25",
        ]
    )
    assert rc != 0
    err = capsys.readouterr().err
    assert "every render of the first 2 steps is empty" in err and len(err.strip().splitlines()) == 1


def test_a_tripod_capture_without_poses_is_posed_static_without_sfm(tripod, monkeypatch, caplog):
    """pose_source auto on frames that all look alike: no SfM (it cannot register a camera that did
    not move, and takes a minute to find so), every frame at one pose, said once; colmap still runs it."""
    import scenes.colmap
    from scenes.colmap import SfMError

    calls = []

    def sfm(capture, cfg=None):
        calls.append(capture.num_frames)
        raise SfMError("SfM registered no frames")

    monkeypatch.setattr(scenes.colmap, "estimate_poses", sfm)
    unposed = dataclasses.replace(tripod, c2w=None, pose_trust=None)
    with caplog.at_level(logging.WARNING, logger="ebad.data"):
        data = prepare(unposed, _cfg("auto"))
    assert calls == [] and data.report.pose_source == "static"
    assert np.array_equal(data.c2w.numpy(), np.repeat(np.eye(4, dtype=np.float32)[None], unposed.num_frames, 0))
    assert "the camera did not move: at most 0.0% of the pixels" in caplog.text
    assert "--trajectory.pose_source colmap runs SfM anyway" in caplog.text
    with pytest.raises(SfMError, match="use --trajectory.pose_source static"):
        prepare(unposed, _cfg("colmap"))
    assert calls == [unposed.num_frames]


def test_changed_fraction_tells_a_still_camera_from_a_moving_one():
    """Pinned on captures it was measured on: the frames of a moving camera change 0.60 of their
    pixels (boxes, tiny, seed 0) and 0.46 of a raw mosaic's 2 x 2 blocks; a smooth image under fresh
    noise of sigma 0.02 in each frame changes where |N(0, 0.0283)| > 3 x 0.0283 + 0.01, with
    probability 0.080% a pixel (the largest of five frames' fractions: about 0.1%)."""
    moving = scenes.make_scene("boxes", size="tiny", seed=0, poses="none").capture
    assert changed_fraction(moving.frames) == pytest.approx(0.602, abs=0.003)
    raw = scenes.make_scene("boxes", size="tiny", seed=0, poses="none", rgb=True, cfa="RGGB", raw_frames=True)
    assert raw.capture.frames.shape[-1] == 1
    assert changed_fraction(raw.capture.frames, mosaic=True) == pytest.approx(0.461, abs=0.003)
    rng = np.random.default_rng(0)
    ramp = np.linspace(0.2, 0.8, 200, dtype=np.float32)[None, :, None, None] * np.ones((1, 1, 200, 1), np.float32)
    still = ramp + rng.normal(0, 0.02, size=(6, 200, 200, 1)).astype(np.float32)  # 40,000 pixels a frame
    assert changed_fraction(still) == pytest.approx(0.001, abs=0.0003)
    assert changed_fraction(moving.frames[:1]) == 0.0
    assert STILL_CHANGED == 0.1
