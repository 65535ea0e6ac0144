"""EBAD-NeRF / E2NeRF layouts: fixtures written here in each layout, loaded through scenes.load."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image
from scipy.spatial.transform import Rotation

import scenes
from scenes import CaptureError, load
from scenes.e2nerf import BIN_S, events_from_bins, nominal_exposures
from scenes.format import read_ground_truth
from scenes.readers import detect_layout

H, W, BINS = 6, 8, 4


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    c2w[:, :3, 3] = rng.normal(size=(n, 3))
    return c2w


def _counts(n, seed, shape=(H * W,)):
    rng = np.random.default_rng(seed)
    return rng.integers(-3, 4, (n, BINS) + shape) * (rng.uniform(size=(n, BINS) + shape) < 0.4)


def _save_png(path: Path, img: np.ndarray):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)


def write_ebad_nerf(
    root: Path, n=10, seed=0, novel=True, gt_blur=True, poses_name="poses_bounds.npy", counts_dtype=torch.float64
):
    """An EBAD-NeRF folder: images/, images_gt_blur/, images_gt_novel/, events.pt [V, B, H*W],
    poses_bounds.npy in LLFF axes (down, right, backwards) with hwf = (2H, 2W, 2f)."""
    rng = np.random.default_rng(seed)
    c2w = _poses(n, seed)
    focal = 7.5
    rows = []
    for i in range(n):
        r = np.stack([c2w[i, :3, 1], c2w[i, :3, 0], -c2w[i, :3, 2]], 1)
        m = np.concatenate([r, c2w[i, :3, 3:4], np.array([[2 * H], [2 * W], [2 * focal]])], 1)
        rows.append(np.concatenate([m.ravel(), [0.5 + i, 20.0]]))
    root.mkdir(parents=True)
    np.save(root / poses_name, np.array(rows))
    imgs = rng.integers(0, 256, (n, H, W, 3)).astype(np.uint8)
    for i in range(n):
        _save_png(root / "images" / f"{i:03d}.png", imgs[i])
    held = list(range(0, n, 8)) if novel else []
    train = [i for i in range(n) if i not in held]
    sharp = rng.integers(0, 256, (n, H, W, 3)).astype(np.uint8)
    if gt_blur:
        for i in train:
            _save_png(root / "images_gt_blur" / f"{i:03d}.png", sharp[i])
    if novel:
        for i in held:
            _save_png(root / "images_gt_novel" / f"{i:03d}.png", sharp[i])
    counts = _counts(n, seed)
    torch.save(torch.tensor(counts, dtype=counts_dtype), root / "events.pt")
    return dict(c2w=c2w, imgs=imgs, sharp=sharp, counts=counts, held=held, train=train, focal=focal)


def test_ebad_nerf_layout_loads(tmp_path):
    root = tmp_path / "scene"
    truth = write_ebad_nerf(root)
    assert detect_layout(root) == "ebad-nerf"
    cap = load(root)
    train, held = truth["train"], truth["held"]
    assert held == [0, 8] and cap.names == [f"{i:03d}" for i in train]
    np.testing.assert_array_equal(cap.frames, truth["imgs"][train].astype(np.float32) / np.float32(255))
    np.testing.assert_allclose(cap.c2w, truth["c2w"][train], atol=1e-12)
    np.testing.assert_allclose(cap.K, [[truth["focal"], 0, W / 2], [0, truth["focal"], H / 2], [0, 0, 1]])
    assert [tv.name for tv in cap.test_views] == ["000", "008"]
    for tv, i in zip(cap.test_views, held):
        np.testing.assert_allclose(tv.c2w, truth["c2w"][i], atol=1e-12)
        np.testing.assert_array_equal(tv.image, truth["sharp"][i].astype(np.float32) / np.float32(255))
    assert cap.meta["held_out_frames"] == ["000.png", "008.png"]
    assert cap.meta["events_binned"]["bins"] == BINS and cap.meta["exposure_known"] is False
    assert cap.meta["bounds"][0] == [1.5, 20.0]  # frame 001's bounds (frame 000 is held out)
    # exposures keep each view's slot; they do not overlap
    np.testing.assert_allclose(cap.exposures, nominal_exposures(10, BINS)[train])
    assert np.all(cap.exposures[1:, 0] > cap.exposures[:-1, 1])


def test_binned_events_reproduce_every_bin_and_nothing_else(tmp_path):
    root = tmp_path / "scene"
    truth = write_ebad_nerf(root, seed=3)
    cap = load(root)
    counts = truth["counts"][truth["train"]]
    total = 0
    for k in range(cap.num_frames):
        t0, t1 = cap.exposures[k]
        edges = np.linspace(t0, t1, BINS + 1)
        for b in range(BINS):
            ev = cap.events.slice_time(edges[b], edges[b + 1])  # between two bin edges
            np.testing.assert_array_equal(ev.count_image().reshape(-1), counts[k, b])
            total += len(ev)
        # the events of several bins are the sum of their counts (an L_ev pair spanning bins 1..3)
        np.testing.assert_array_equal(
            cap.events.slice_time(edges[1], edges[4]).count_image().reshape(-1), counts[k, 1:4].sum(0)
        )
    assert total == len(cap.events) == np.abs(counts).sum()


def test_events_from_bins_puts_events_at_bin_centres():
    counts = np.zeros((2, 4, 6), np.int64)
    counts[1, 2, 5] = -2
    counts[0, 0, 1] = 1
    exps = nominal_exposures(2, 4)
    ev = events_from_bins(counts, exps, 3, 2)
    bin_us = round(BIN_S * 1e6)
    centre_1_2 = round(exps[1, 0] * 1e6) + 2 * bin_us + bin_us // 2  # frame 1, bin 2
    np.testing.assert_array_equal(ev.t, [bin_us // 2, centre_1_2, centre_1_2])
    np.testing.assert_array_equal(ev.x, [1, 2, 2])
    np.testing.assert_array_equal(ev.y, [0, 1, 1])
    np.testing.assert_array_equal(ev.p, [1, -1, -1])


def test_four_dimensional_counts_training_views_only_and_pose_bounds_name(tmp_path):
    root = tmp_path / "scene"
    truth = write_ebad_nerf(root, poses_name="pose_bounds.npy", novel=False, gt_blur=False)
    counts = truth["counts"].reshape(10, BINS, H, W)
    torch.save(torch.tensor(counts, dtype=torch.int16), root / "events.pt")
    cap = load(root)
    assert cap.num_frames == 10 and cap.test_views == []
    assert len(cap.events) == np.abs(counts).sum()


def test_ground_truth_of_the_blurry_views(tmp_path):
    root = tmp_path / "scene"
    truth = write_ebad_nerf(root)
    cap = load(root)
    gt = read_ground_truth(root)
    np.testing.assert_array_equal(
        gt.frames(cap.names), truth["sharp"][truth["train"]].astype(np.float32) / np.float32(255)
    )


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda r: torch.save(torch.full((10, BINS, H * W), 0.5), r / "events.pt"), r"events\.pt.*whole numbers"),
        (lambda r: torch.save(torch.zeros(10, BINS, H * W + 1), r / "events.pt"), r"events\.pt.*49 pixels per bin"),
        (lambda r: torch.save(torch.zeros(7, BINS, H * W), r / "events.pt"), r"events\.pt.*7 views of counts for 10"),
        (lambda r: torch.save({"counts": torch.zeros(3)}, r / "events.pt"), r"events\.pt.*one tensor"),
        (lambda r: torch.save(torch.zeros(10, H * W), r / "events.pt"), r"events\.pt.*\[views, bins, H\*W\]"),
        (lambda r: (r / "events.pt").write_bytes(b"garbage"), r"events\.pt.*unreadable"),
        (lambda r: np.save(r / "poses_bounds.npy", np.zeros((10, 15))), r"poses_bounds\.npy.*\[F, 17\]"),
        (lambda r: (r / "images" / "003.png").unlink(), r"images.*9 images for 10 poses"),
        (lambda r: (r / "images_gt_novel" / "008.png").unlink(), r"images_gt_novel.*1 images"),
    ],
)
def test_ebad_nerf_errors_name_the_file(tmp_path, make, match):
    root = tmp_path / "scene"
    write_ebad_nerf(root)
    make(root)
    with pytest.raises(CaptureError, match=match):
        load(root)


def test_code_in_events_pt_does_not_run(tmp_path):
    root = tmp_path / "scene"
    write_ebad_nerf(root)
    marker = tmp_path / "ran"

    class Evil:
        def __reduce__(self):
            return (Path.touch, (marker,))

    torch.save(Evil(), root / "events.pt")
    with pytest.raises(CaptureError, match=r"events\.pt.*unreadable"):
        load(root)
    assert not marker.exists()


def test_scale_in_a_pose_is_refused(tmp_path):
    root = tmp_path / "scene"
    write_ebad_nerf(root)
    pb = np.load(root / "poses_bounds.npy")
    pb[4, :15] = (pb[4, :15].reshape(3, 5) * np.array([1.1, 1.1, 1.1, 1, 1])).ravel()
    np.save(root / "poses_bounds.npy", pb)
    with pytest.raises(CaptureError, match=r"poses_bounds\.npy.*poses_bounds\[4\].*scales"):
        load(root)


# ---------------------------------------------------------------- E2NeRF (transforms json)


def _gl(c2w_cv):
    return c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])


def write_e2nerf(root: Path, n=3, seed=0, poses_per_view=18, every_second=True, spelled="transforms"):
    """An E2NeRF synthetic folder: train/r_{0,2,..}.png, transforms_train.json listing 2n frames
    (every second one has an image) whose transform_matrix is a list of Blender poses over the
    exposure, events.pt [n, B, H*W], test/ + transforms_test.json."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True)
    starts, ends = _poses(n, seed), _poses(n, seed + 100)
    ends[:, :3, :3] = starts[:, :3, :3] @ Rotation.from_rotvec(rng.normal(scale=0.05, size=(n, 3))).as_matrix()
    frames, mids, imgs = [], [], []
    for k in range(n * (2 if every_second else 1)):
        i = k // 2 if every_second else k
        s = np.linspace(0, 1, poses_per_view)
        rots = Rotation.from_matrix(np.stack([starts[i, :3, :3], ends[i, :3, :3]]))
        from scipy.spatial.transform import Slerp

        lst = np.tile(np.eye(4), (poses_per_view, 1, 1))
        lst[:, :3, :3] = Slerp([0, 1], rots)(s).as_matrix()
        lst[:, :3, 3] = (1 - s)[:, None] * starts[i, :3, 3] + s[:, None] * ends[i, :3, 3]
        name = f"r_{k}"
        frames.append({"file_path": f"./train/{name}", "transform_matrix": _gl(lst).tolist()})
        if not every_second or k % 2 == 0:
            img = rng.integers(0, 256, (H, W, 4)).astype(np.uint8)
            _save_png(root / "train" / f"{name}.png", img)
            imgs.append(img)
            mid = np.eye(4)
            mid[:3, :3] = Slerp([0, 1], rots)([0.5]).as_matrix()[0]
            mid[:3, 3] = 0.5 * (starts[i, :3, 3] + ends[i, :3, 3])
            mids.append(mid)
    angle = 0.69
    (root / f"{spelled}_train.json").write_text(json.dumps({"camera_angle_x": angle, "frames": frames}))
    test_pose = _poses(2, seed + 7)
    tframes = []
    for j in range(2):
        _save_png(root / "test" / f"r_{j}.png", rng.integers(0, 256, (H, W, 3)).astype(np.uint8))
        tframes.append({"file_path": f"./test/r_{j}", "transform_matrix": [_gl(test_pose[j]).tolist()] * 3})
    (root / f"{spelled}_test.json").write_text(json.dumps({"camera_angle_x": angle, "frames": tframes}))
    counts = _counts(n, seed)
    torch.save(torch.tensor(counts), root / "events.pt")
    return dict(mids=np.stack(mids), imgs=np.stack(imgs), counts=counts, angle=angle, test_pose=test_pose)


@pytest.mark.parametrize("spelled", ["transforms", "transform"])
def test_e2nerf_layout_loads(tmp_path, spelled):
    root = tmp_path / "lego"
    truth = write_e2nerf(root, spelled=spelled)
    assert detect_layout(root) == "e2nerf"
    cap = load(root)
    assert cap.names == ["r_0", "r_2", "r_4"]
    np.testing.assert_array_equal(cap.frames, truth["imgs"][..., :3].astype(np.float32) / np.float32(255))
    np.testing.assert_allclose(cap.c2w, truth["mids"], atol=1e-9)  # mid-exposure of the 18 poses
    f = 0.5 * W / np.tan(0.5 * truth["angle"])
    np.testing.assert_allclose(cap.K, [[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
    assert len(cap.test_views) == 2
    np.testing.assert_allclose(cap.test_views[1].c2w, truth["test_pose"][1], atol=1e-12)
    assert len(cap.events) == np.abs(truth["counts"]).sum() and cap.meta["source_layout"] == "e2nerf"


def test_e2nerf_errors_name_file_and_field(tmp_path):
    root = tmp_path / "lego"
    write_e2nerf(root)
    doc = json.loads((root / "transforms_train.json").read_text())
    doc["frames"][2]["transform_matrix"][5][0][0] = 3.0
    (root / "transforms_train.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError, match=r"transforms_train\.json.*frames\[2\]\.transform_matrix\[5\]"):
        load(root)
    doc["frames"][2]["transform_matrix"] = doc["frames"][0]["transform_matrix"]
    doc.pop("camera_angle_x")
    (root / "transforms_train.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError, match=r"transforms_train\.json.*camera_angle_x"):
        load(root)


def test_e2nerf_capture_saves_and_loads_back(tmp_path):
    write_e2nerf(tmp_path / "lego")
    cap = load(tmp_path / "lego")
    scenes.save(cap, tmp_path / "cap")
    back = load(tmp_path / "cap")
    np.testing.assert_array_equal(back.events.t, cap.events.t)
    assert back.meta["events_binned"] == cap.meta["events_binned"]


def test_image_of_another_size_names_the_file(tmp_path):
    root = tmp_path / "scene"
    write_ebad_nerf(root)
    _save_png(root / "images" / "005.png", np.zeros((H + 1, W, 3), np.uint8))
    with pytest.raises(CaptureError, match=r"005\.png.*8x7x3, the first image 8x6x3"):
        load(root)
    write_e2nerf(tmp_path / "lego")
    _save_png(tmp_path / "lego" / "train" / "r_2.png", np.zeros((H, W + 2), np.uint8))
    with pytest.raises(CaptureError, match=r"r_2\.png.*10x6x1"):
        load(tmp_path / "lego")


@pytest.mark.parametrize("seed", range(4))
def test_edi_on_binned_events_is_exact_when_the_scene_steps_at_bin_centres(seed):
    """If the true log intensity jumps by c x count at each bin centre, the stand-in events are
    the true events, and EDI recovers the latent image at every bin edge."""
    import edi

    c = 0.2
    rng = np.random.default_rng(seed)
    counts = rng.integers(-1, 2, (1, BINS, H * W))
    exps = nominal_exposures(1, BINS)
    events = events_from_bins(counts, exps, W, H)
    t0, t1 = exps[0]
    T = t1 - t0
    L0 = rng.uniform(0.1, 0.3, H * W)  # below saturation after up to BINS steps of c
    eps = edi.LOG_EPS
    # pieces between bin centres: E = cumulative counts; durations T/2B, T/B, ..., T/B, T/2B
    E = np.concatenate([np.zeros((1, H * W)), np.cumsum(counts[0], 0)])  # [B + 1, P]
    L = (L0 + eps) * np.exp(c * E) - eps
    dur = np.array([0.5] + [1.0] * (BINS - 1) + [0.5]) * T / BINS
    blur = (dur[:, None] * L).sum(0) / T
    assert blur.max() < edi.SATURATION and L.min() > 0
    edges = np.linspace(t0, t1, BINS + 1)[:-1]  # bin b's start: the piece after centre b - 1
    lat = edi.deblur(blur.reshape(H, W), (t0, t1), events, times=list(edges), c=c)
    np.testing.assert_allclose(lat.reshape(BINS, -1), L[:BINS], rtol=1e-9, atol=1e-12)
