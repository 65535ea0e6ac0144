"""SfM at 30-50 views (issue 31): the matcher by size, the registration rate, the unregistered views named."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from scenes.colmap import ColmapConfig, SfMError, choose_matcher


def test_auto_matches_exhaustively_only_small_captures():
    cfg = ColmapConfig()
    assert cfg.exhaustive_max == 40
    assert choose_matcher(cfg, 40) == "exhaustive" and choose_matcher(cfg, 41) == "sequential"
    assert choose_matcher(cfg, 87) == "sequential"  # every slider_depth frame
    assert choose_matcher(ColmapConfig(matcher="exhaustive"), 50) == "exhaustive"
    assert choose_matcher(ColmapConfig(matcher="sequential"), 4) == "sequential"


@pytest.fixture(scope="module")
def small_capture():
    import scenes

    return scenes.make_scene("boxes", "tiny", seed=0, poses="none", n_frames=8, n_test=0).capture


def test_unregistered_views_are_named_and_the_rate_reported(small_capture, monkeypatch, caplog):
    import scenes.colmap as sc

    real = sc._registered_poses

    def drop_two(rec, name_to_i, name_to_test):  # frames 2 and 5 "fail to register"
        c2w, reg, test = real(rec, name_to_i, name_to_test)
        reg[[2, 5]] = False
        return c2w, reg, test

    monkeypatch.setattr(sc, "_registered_poses", drop_two)
    with caplog.at_level(logging.INFO, logger="scenes.colmap"):
        est = sc.estimate_poses(small_capture, ColmapConfig(num_threads=1))
    names = small_capture.names or []
    assert "SfM: registered 6 of 8 frames and 0 of 0 test views" in caplog.text  # on the progress log, every run
    assert est.report["registration_rate"] == pytest.approx(6 / 8)
    assert est.report["unregistered_names"] == [names[2], names[5]]
    assert f"not registered (poses interpolated in time): {names[2]}, {names[5]}" in caplog.text
    with pytest.raises(SfMError, match=rf"registered only 6 of 8 frames .*not registered: {names[2]}, {names[5]}"):
        sc.estimate_poses(small_capture, ColmapConfig(num_threads=1, min_registered_fraction=1.0))


@pytest.mark.slow  # 53 s on a loaded 2-core machine (58 s to simulate, 35 s of SfM alone before)
def test_sfm_registers_every_view_of_a_30_view_capture():
    import scenes
    from scenes.colmap import estimate_poses, pose_errors

    sc = scenes.make_scene("boxes", "tiny", seed=0, poses="none", n_frames=33, n_test=3)
    est = estimate_poses(sc.capture, ColmapConfig(num_threads=1, matcher="sequential"))  # what 41+ images get
    assert est.report["matcher"] == "sequential"
    assert est.registered.all() and est.report["registration_rate"] == 1.0
    assert len(est.test_c2w) == 3
    e = pose_errors(est.c2w, sc.gt_c2w)
    assert e["ate_rmse"] < 0.05 * e["trajectory_extent"]
    assert np.isfinite(est.report["mean_reprojection_error_px"])
