"""``benchmarks.ablation``: the step-only budget and the colour diagnostics (issue 29)."""

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks import ablation as A


def test_wall_budget_zero_means_steps_only():
    assert A.wall_budget(None) == 60.0
    assert A.wall_budget(None, quick=True) == 15.0
    assert A.wall_budget(40) == 40.0
    assert A.wall_budget(0) is None
    assert A.make_config("ebad", 600, A.wall_budget(0), 1).train.max_seconds is None
    with pytest.raises(ValueError, match="--seconds must be >= 0"):
        A.wall_budget(-1)
    with pytest.raises(SystemExit):
        A.main(["--seconds", "-1", "--presets", "ebad"])


def test_colour_split_parts_add_up_and_pin_values():
    truth = np.zeros((2, 4, 6, 3))
    grey_cast = truth + 0.1  # the same error in every channel: all achromatic
    s = A.colour_split(grey_cast, truth)
    assert s["mse"] == pytest.approx(0.01)
    assert s["mse_luma"] == pytest.approx(0.01)
    assert s["mse_chroma"] == pytest.approx(0.0, abs=1e-15)
    assert s["psnr_luma"] == pytest.approx(20.0)
    assert (s["psnr_r"], s["psnr_g"], s["psnr_b"]) == pytest.approx((20.0, 20.0, 20.0))
    tint = truth + np.array([0.1, -0.1, 0.0])  # channel mean exact: all chromatic (-0.1 clamps to 0)
    s = A.colour_split(tint, truth)
    assert s["mse"] == pytest.approx(0.01 / 3)
    assert s["mse_luma"] == pytest.approx(0.01 / 9)
    assert s["mse_chroma"] == pytest.approx(0.01 / 3 - 0.01 / 9)
    assert (s["psnr_r"], s["psnr_g"], s["psnr_b"]) == pytest.approx((20.0, 100.0, 100.0))
    grey = A.colour_split(np.full((1, 3, 3, 1), 0.5), np.full((1, 3, 3, 1), 0.4))
    assert grey["mse_chroma"] == pytest.approx(0.0, abs=1e-15) and grey["psnr_luma"] == pytest.approx(20.0)
    assert "psnr_r" not in grey
    with pytest.raises(ValueError, match="one shape"):
        A.colour_split(truth, truth[..., :1])


def _scene(images, frames, cfa="RGGB"):
    views = [SimpleNamespace(image=im) for im in images] + [SimpleNamespace(image=None)]
    return SimpleNamespace(capture=SimpleNamespace(cfa=cfa, test_views=views), gt_frames=frames)


def test_demosaic_ceiling_is_exact_on_flat_colour_and_pins_an_edge():
    flat = np.ones((1, 6, 8, 3)) * np.array([0.2, 0.5, 0.7])
    c = A.demosaic_ceiling(_scene(flat, flat))
    assert c["test"]["psnr_luma"] == 100.0 and c["frames"]["mse"] == pytest.approx(0.0, abs=1e-20)
    edge = flat.copy()
    edge[:, :, 4:] = [0.7, 0.5, 0.2]  # a vertical colour edge: bilinear demosaic blurs R and B across it
    c = A.demosaic_ceiling(_scene(edge, flat))
    assert c["frames"]["mse"] == pytest.approx(0.0, abs=1e-20)
    assert c["test"]["psnr_g"] == 100.0  # G is the same on both sides
    # R misses by 0.25 on the column left of the edge, B on the column right of it (6 rows each)
    assert c["test"]["mse"] == pytest.approx(12 * 0.25**2 / (6 * 8 * 3))
    assert c["test"]["mse_luma"] == pytest.approx(12 * (0.25 / 3) ** 2 / (6 * 8))
    assert c["test"]["psnr_r"] == pytest.approx(c["test"]["psnr_b"]) == pytest.approx(-10 * np.log10(6 * 0.25**2 / 48))
    assert A.demosaic_ceiling(_scene(flat, flat, cfa=None)) is None


def test_baselines_with_options_count_in_the_starred_margins():
    """``3dgs*``/``bad*`` take the strongest variant in each seed, options included (a baseline
    comparing through the mosaic is a baseline too); plain ``bad`` stays the plain preset."""
    rows = [
        {"setting": "sfm/cfa", "seed": s, "preset": p, "test_refined_psnr": v}
        for s, vals in enumerate(
            [
                {
                    "3dgs": 20.0,
                    "3dgs-po": 19.0,
                    "3dgs-po+loss.cfa_frames=mosaic": 21.5,
                    "bad": 21.0,
                    "bad+loss.cfa_frames=mosaic": 22.0,
                    "ebad": 24.0,
                },
                {
                    "3dgs": 20.5,
                    "3dgs-po": 19.5,
                    "3dgs-po+loss.cfa_frames=mosaic": 20.0,
                    "bad": 21.0,
                    "bad+loss.cfa_frames=mosaic": 20.5,
                    "ebad": 24.5,
                },
            ]
        )
        for p, v in vals.items()
    ]
    m = A.margins(rows)["sfm/cfa"]
    assert m["3dgs*"][2] == [2.5, 4.0]
    assert m["bad*"][2] == [2.0, 3.5]
    assert m["bad"][2] == [3.0, 3.5]


def test_make_config_keeps_the_baseline_pose_rule_with_options():
    po = A.make_config("3dgs-po+loss.cfa_frames=mosaic", 10, None, 0)
    held = A.make_config("3dgs+loss.cfa_frames=mosaic", 10, None, 0)
    assert (po.trajectory.anchor_mid, po.loss.cfa_frames, po.name) == ("no", "mosaic", "3dgs-po+loss.cfa_frames=mosaic")
    assert (held.trajectory.anchor_mid, held.loss.cfa_frames) == ("yes", "mosaic")
    assert A.make_config("3dgs-po", 10, None, 0).trajectory.anchor_mid == "no"
