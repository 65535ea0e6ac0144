"""ebad.virtual_views: V per frame, event sums."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebad.virtual_views import (
    choose_num_views,
    event_counts,
    path_lengths_px,
    random_window,
    views_from_blur,
    window_counts,
)
from edi import EventStream


def _stream(n_per_frame, W=8, H=6, exposures=((0.0, 0.04), (0.1, 0.14))):
    ts, xs, ys, ps = [], [], [], []
    rng = np.random.default_rng(0)
    for (t0, t1), n in zip(exposures, n_per_frame):
        ts.append(np.sort(rng.uniform(t0, t1, n)) * 1e6)
        xs.append(rng.integers(0, W, n))
        ys.append(rng.integers(0, H, n))
        ps.append(rng.choice([-1, 1], n))
    return EventStream(
        np.concatenate(ts).astype(np.int64), np.concatenate(xs), np.concatenate(ys), np.concatenate(ps), W, H
    )


def test_views_sharp_frames_get_one_view():
    ex = np.array([[0.0, 0.04], [0.1, 0.14], [0.2, 0.2]])
    ev = _stream([200, 0])
    V = choose_num_views(ex, ev, 5, adaptive=True, sharp_events_per_pixel=0.05)
    assert V.tolist() == [5, 1, 1]  # busy / no events in exposure / zero-length exposure
    assert choose_num_views(ex, None, 5).tolist() == [5, 5, 1]  # no events: only t0 == t1 is sharp
    assert choose_num_views(ex, EventStream.empty(8, 6), 5).tolist() == [1, 1, 1]  # sensor saw nothing
    with pytest.raises(ValueError, match="num_views"):
        choose_num_views(ex, ev, 0)


def test_event_counts_match_bruteforce():
    ev = _stream([300, 50])
    s = event_counts(ev, (0.0, 0.04), 5)
    assert s.shape == (4, 2, 6, 8)
    inst = (np.arange(5) + 0.5) / 5 * 0.04 * 1e6
    for k in range(4):
        m = (ev.t >= round(inst[k])) & (ev.t < round(inst[k + 1]))
        for j, pol in enumerate((1, -1)):
            ref = np.zeros((6, 8))
            np.add.at(ref, (ev.y[m & (ev.p == pol)], ev.x[m & (ev.p == pol)]), 1)
            assert np.array_equal(s[k, j].numpy(), ref)
    assert s.sum() == ((ev.t >= round(inst[0])) & (ev.t < round(inst[-1]))).sum()
    assert event_counts(ev, (0.0, 0.04), 1).shape == (0, 2, 6, 8)


@pytest.mark.parametrize("V", [2, 3, 5, 7])
def test_random_window_draws_every_pair_of_instants_and_only_those(V):
    g = torch.Generator().manual_seed(V)
    n = 400 * V * V
    seen = {}
    for _ in range(n):
        i, j = random_window(V, g)
        assert 0 <= i < j < V
        seen[(i, j)] = seen.get((i, j), 0) + 1
    pairs = V * (V - 1) // 2
    assert len(seen) == pairs
    expected = n / pairs  # uniform over the pairs: each count within 5 binomial standard deviations
    assert all(abs(k - expected) < 5 * np.sqrt(expected) for k in seen.values())
    with pytest.raises(ValueError, match="V >= 2"):
        random_window(1, g)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_window_counts_are_the_events_between_the_chosen_instants(seed):
    ev = _stream([400, 30])
    V = 7
    counts = event_counts(ev, (0.0, 0.04), V)
    inst = (np.arange(V) + 0.5) / V * 0.04 * 1e6
    g = torch.Generator().manual_seed(seed)
    for _ in range(10):
        i, j = random_window(V, g)
        w = window_counts(counts, i, j)
        assert w.shape == (1, 2, 6, 8)
        m = (ev.t >= round(inst[i])) & (ev.t < round(inst[j]))
        for k, pol in enumerate((1, -1)):
            ref = np.zeros((6, 8))
            np.add.at(ref, (ev.y[m & (ev.p == pol)], ev.x[m & (ev.p == pol)]), 1)
            assert np.array_equal(w[0, k].numpy(), ref)
    with pytest.raises(ValueError, match="window"):
        window_counts(counts, 3, 3)
    with pytest.raises(ValueError, match="window"):
        window_counts(counts, 0, V)


def _sliding_camera(b: float, U: int = 9) -> torch.Tensor:  # [1, U, 4, 4]: camera at the origin sliding b along x
    poses = torch.eye(4, dtype=torch.float64).repeat(1, U, 1, 1)
    poses[0, :, 0, 3] = torch.linspace(-b / 2, b / 2, U, dtype=torch.float64)
    return poses


def test_path_lengths_are_the_pixels_a_point_travels_over_the_exposure():
    """A camera sliding b sideways moves every point at depth Z by fx b / Z pixels (pinhole);
    points behind the camera or outside the image at mid-exposure do not count."""
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]])
    g = torch.Generator().manual_seed(0)
    Z = 4.0
    inside = torch.cat([(torch.rand(50, 2, generator=g) - 0.5) * torch.tensor([2.0, 1.5]), torch.full((50, 1), Z)], 1)
    behind = inside * torch.tensor([1.0, 1.0, -1.0])
    outside = inside + torch.tensor([50.0, 0.0, 0.0])
    for pts in (inside, torch.cat([inside, behind, outside])):
        got = path_lengths_px(_sliding_camera(0.2), pts, K, 64, 48)
        assert got.shape == (1,) and abs(got[0] - 100.0 * 0.2 / Z) < 1e-9
    near = torch.cat([inside, inside * 0.5])  # the same pixels at Z / 2: twice the path for half the points
    assert abs(path_lengths_px(_sliding_camera(0.2), near, K, 64, 48, quantile=0.9)[0] - 100.0 * 0.2 / (Z / 2)) < 1e-9
    assert np.isnan(path_lengths_px(_sliding_camera(0.2), behind, K, 64, 48)[0])  # nothing in view
    with pytest.raises(ValueError, match="poses"):
        path_lengths_px(_sliding_camera(0.2)[:, :1], inside, K, 64, 48)


def test_views_from_blur_spaces_the_instants_at_most_spacing_apart():
    lengths = np.array([0.5, 7.0, 100.0, np.nan, 30.0, 9.0])
    V = np.array([5, 5, 5, 5, 1, 5])
    assert views_from_blur(lengths, V, 3.0, 9).tolist() == [2, 3, 9, 5, 1, 3]  # 9 / 3 = 3 views exactly
    got = views_from_blur(lengths, V, 3.0, 9)
    ok = (V > 1) & np.isfinite(lengths) & (got < 9) & (got > 2)
    assert (lengths[ok] / got[ok] <= 3.0).all()
    with pytest.raises(ValueError, match="spacing"):
        views_from_blur(lengths, V, 0.0, 9)
    with pytest.raises(ValueError, match="max_views"):
        views_from_blur(lengths, V, 3.0, 1)
