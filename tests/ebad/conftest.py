"""A tiny written run folder shared by the export, render, video and view tests."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

import scenes
from ebad import reconstruct
from ebad.config import preset
from ebad.runfolder import write_run

TINY_RUN_ITERS = 3  # the viewers and writers need a run, not a good one


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """``SimpleNamespace(scene, capture, run)``: the tiny boxes scene written as a capture
    folder, and a run folder reconstructed from it with a few iterations."""
    root = tmp_path_factory.mktemp("tiny_run")
    sc = scenes.make_scene("boxes", size="tiny", seed=0, n_frames=6, n_test=2)
    scenes.write_scene(sc, root / "scene")
    cfg = preset("ebad")
    cfg.train.iters = TINY_RUN_ITERS
    cfg.train.progress = False
    cfg.train.eval_every = 0
    torch.manual_seed(0)
    write_run(reconstruct(sc.capture, cfg), root / "run")
    return SimpleNamespace(scene=sc, capture=root / "scene" / "capture", run=root / "run")
