"""Camera initialisation: the alignment maths, and SfM on slider_depth (slow)."""
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scenes.colmap import ColmapConfig, SfMError, align_similarity, pose_errors

SLIDER = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "slider_depth"


def _poses(n, rng, straight=False):
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = (Rotation.from_rotvec(np.zeros((n, 3))) if straight else Rotation.random(n, random_state=1)).as_matrix()
    out[:, :3, 3] = (np.linspace(0, 1, n)[:, None] * [1.0, 0, 0]) if straight else rng.normal(size=(n, 3))
    return out


def _transform(c2w, s, r, t):
    out = c2w.copy()
    out[:, :3, :3] = r @ c2w[:, :3, :3]
    out[:, :3, 3] = s * c2w[:, :3, 3] @ r.T + t
    return out


@pytest.mark.parametrize("straight", [False, True])
def test_pose_errors_vanish_under_a_similarity(straight):
    rng = np.random.default_rng(0)
    est = _poses(12, rng, straight)
    r = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    gt = _transform(est, 3.7, r, np.array([1.0, -2.0, 0.5]))
    e = pose_errors(est, gt)
    assert e["ate_rmse"] < 1e-9 and e["rot_max_deg"] < 1e-5
    assert e["scale"] == pytest.approx(3.7)


def test_pose_errors_measure_a_known_perturbation():
    rng = np.random.default_rng(1)
    gt = _poses(10, rng)
    est = gt.copy()
    est[3, :3, 3] += [0.1, 0, 0]
    est[5, :3, :3] = Rotation.from_rotvec([0, 0, np.radians(2.0)]).as_matrix() @ est[5, :3, :3]
    e = pose_errors(est, gt)
    assert 0.02 < e["ate_rmse"] < 0.05 and 0.05 < e["ate_max"] < 0.11
    assert 1.5 < e["rot_max_deg"] < 2.1


def test_umeyama_recovers_similarity_and_checks_shapes():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(20, 3))
    r = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    s, rr, t = align_similarity(src, 2.5 * src @ r.T + [1, 2, 3])
    assert s == pytest.approx(2.5) and np.allclose(rr, r) and np.allclose(t, [1, 2, 3])
    with pytest.raises(ValueError, match="src, dst"):
        align_similarity(src[:2], src[:2])
    with pytest.raises(ValueError, match="est_c2w"):
        pose_errors(np.zeros((3, 4, 4)), np.zeros((2, 4, 4)))


def test_estimate_poses_bad_arguments():
    import scenes
    from scenes.colmap import estimate_poses

    cap = scenes.make_scene("boxes", "tiny", n_frames=3, n_test=0)
    cap = cap.capture
    with pytest.raises(ValueError, match="frames"):
        estimate_poses(cap, frames=[0])
    with pytest.raises(ValueError, match="matcher"):
        estimate_poses(cap, ColmapConfig(matcher="magic"))


@pytest.mark.slow
@pytest.mark.skipif(not SLIDER.is_dir(), reason=f"shared data not found at {SLIDER}")
def test_sfm_on_slider_depth_agrees_with_ground_truth():
    import scenes
    from scenes.colmap import estimate_poses

    cap = scenes.load(SLIDER)
    idx = list(range(0, 87, 2))  # 44 frames, about 2.3 cm apart (sequential matching)
    est = estimate_poses(cap, ColmapConfig(num_threads=1), frames=idx)  # one thread: deterministic
    assert est.registered.all()
    assert est.c2w.shape == (len(idx), 4, 4) and np.isfinite(est.c2w).all()
    assert len(est.points) > 300 and est.colors.shape == (len(est.points), 1)
    assert 0 <= est.colors.min() and est.colors.max() <= 1
    e = pose_errors(est.c2w, cap.c2w[idx])
    assert e["ate_rmse"] < 0.01 * e["trajectory_extent"]  # under 1 cm on a 1 m slide
    assert e["rot_max_deg"] < 1.0
    assert est.report["mean_reprojection_error_px"] < 1.0
    # too few frames to register half of them: a clear error
    with pytest.raises(SfMError, match="registered"):
        estimate_poses(cap, ColmapConfig(min_registered_fraction=1.0, min_registered=5,
                                         init_min_num_inliers=100000), frames=[0, 40, 80, 86, 20])


def test_sfm_on_a_tiny_blurry_scene_is_better_on_edi_deblurred_frames():
    import scenes
    from scenes.colmap import estimate_poses

    sc = scenes.make_scene("boxes", "tiny", n_frames=12, sigma_c=0.0)
    cap = sc.capture
    # one thread and a fixed seed: COLMAP's multi-threaded matching and bundle adjustment are
    # not deterministic, and on 64x48 frames an unlucky run can lose the track
    edi_est = estimate_poses(cap, ColmapConfig(num_threads=1))  # deblur=True by default
    assert edi_est.report["deblurred"] == 12 and edi_est.registered.all()
    e_edi = pose_errors(edi_est.c2w, cap.c2w)
    assert e_edi["ate_rmse"] < 0.03 * e_edi["trajectory_extent"]
    try:
        raw = estimate_poses(cap, ColmapConfig(deblur=False, num_threads=1))
    except SfMError:
        return  # SfM on the blurry frames failed outright: EDI did better
    e_raw = pose_errors(raw.c2w[raw.registered], cap.c2w[raw.registered])
    assert e_edi["ate_rmse"] < 0.6 * e_raw["ate_rmse"]
    assert len(edi_est.points) > len(raw.points)
