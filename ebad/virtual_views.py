"""How many virtual views each exposure needs, and the events between them.

"Skip what the scene does not need": a frame whose exposure is empty (t_start == t_end) or
that saw fewer than ``sharp_events_per_pixel`` events per pixel during it is sharp and gets
V = 1 (one render, no trajectory); every other frame gets the configured V.

L_ev windows (``loss.event_windows``): ``consecutive`` compares every pair of neighbouring
virtual instants with the events between them (``event_counts``); ``random`` draws one window
per step, a random pair of the V rendered instants (``random_window``), whose events are the
sum of the consecutive counts it spans (``window_counts``): the paper's random t_s restricted to
the virtual instants, at no extra render and no pass over the events.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from edi import EventStream, seconds_to_us

__all__ = [
    "events_per_pixel",
    "choose_num_views",
    "path_lengths_px",
    "views_from_blur",
    "event_counts",
    "random_window",
    "window_counts",
]


def events_per_pixel(events: EventStream, exposures: np.ndarray) -> np.ndarray:  # [F, 2] -> [F]
    """Events fired during each exposure divided by the sensor's pixel count."""
    exposures = np.asarray(exposures, dtype=np.float64)
    if exposures.ndim != 2 or exposures.shape[1] != 2:
        raise ValueError(f"exposures must be [F, 2], got {exposures.shape}")
    npix = float(events.width * events.height)
    out = np.zeros(len(exposures))
    for f, (t0, t1) in enumerate(exposures):
        i0, i1 = events.index_range(seconds_to_us(t0), seconds_to_us(t1))
        out[f] = (i1 - i0) / npix
    return out


def choose_num_views(
    exposures: np.ndarray,  # [F, 2] seconds
    events: EventStream | None,
    num_views: int,
    adaptive: bool = True,
    sharp_events_per_pixel: float = 0.05,
) -> np.ndarray:  # [F] int
    """V per frame: 1 for sharp exposures, ``num_views`` otherwise (see module docstring).

    With ``adaptive`` the event activity decides; without events (None or an empty stream)
    only zero-length exposures are sharp, since nothing else tells blur apart.
    """
    if num_views < 1:
        raise ValueError(f"num_views must be >= 1, got {num_views}")
    exposures = np.asarray(exposures, dtype=np.float64)
    V = np.full(len(exposures), int(num_views), dtype=np.int64)
    V[exposures[:, 1] <= exposures[:, 0]] = 1
    if adaptive and events is not None and len(events) > 0:
        V[events_per_pixel(events, exposures) < sharp_events_per_pixel] = 1
    elif adaptive and events is not None and len(events) == 0:
        V[:] = 1  # a capture with an event sensor that saw nothing did not move
    return V


def path_lengths_px(
    poses: Tensor,  # [F, U, 4, 4] camera-to-world at U >= 2 instants spanning each exposure
    points: Tensor,  # [P, 3] world points (the Gaussians' centres)
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    quantile: float = 0.9,
) -> np.ndarray:  # [F] pixels, nan where no point is in view
    """Per frame, the ``quantile`` over the points in view at mid-exposure (in front of the
    camera at every instant, inside the image at u = 0.5) of each point's image path: the sum of
    its pixel displacements between consecutive instants."""
    if poses.ndim != 4 or poses.shape[1] < 2 or poses.shape[2:] != (4, 4):
        raise ValueError(f"poses must be [F, U >= 2, 4, 4], got {tuple(poses.shape)}")
    poses, points, K = poses.double(), points.double(), K.double()
    R, t = poses[..., :3, :3], poses[..., :3, 3]  # camera to world
    cam = torch.einsum("fuji,fupj->fupi", R, points[None, None] - t[:, :, None])  # R^T (p - t): [F, U, P, 3]
    z = cam[..., 2]
    uv = torch.stack([K[0, 0] * cam[..., 0] / z + K[0, 2], K[1, 1] * cam[..., 1] / z + K[1, 2]], -1)
    path = (uv[:, 1:] - uv[:, :-1]).norm(dim=-1).sum(1)  # [F, P]
    mid = uv[:, poses.shape[1] // 2]
    seen = (z > 1e-6).all(1) & (mid[..., 0] >= 0) & (mid[..., 0] < width) & (mid[..., 1] >= 0) & (mid[..., 1] < height)
    out = np.full(poses.shape[0], np.nan)
    for f in range(poses.shape[0]):
        if bool(seen[f].any()):
            out[f] = float(torch.quantile(path[f][seen[f]], quantile))
    return out


def views_from_blur(
    lengths_px: np.ndarray,  # [F] image path length over each exposure (path_lengths_px)
    V: np.ndarray,  # [F] current V (frames with V = 1 are sharp and stay so)
    spacing: float,  # pixels of path per virtual view
    max_views: int,
) -> np.ndarray:  # [F] int
    """ceil(length / spacing) views within [2, max_views] for each blurry frame (V > 1); sharp
    frames and frames whose length is unknown (nan) keep their V."""
    if spacing <= 0:
        raise ValueError(f"spacing must be > 0 pixels, got {spacing}")
    if max_views < 2:
        raise ValueError(f"max_views must be >= 2, got {max_views}")
    lengths = np.asarray(lengths_px, dtype=np.float64)
    out = np.asarray(V, dtype=np.int64).copy()
    pick = (out > 1) & np.isfinite(lengths)
    out[pick] = np.clip(np.ceil(lengths[pick] / spacing), 2, max_views).astype(np.int64)
    return out


def event_counts(
    events: EventStream,
    exposure: tuple[float, float],
    V: int,
) -> Tensor:  # [V - 1, 2, H, W] float32
    """ON and OFF event counts (both >= 0) between consecutive virtual instants
    t_k = t0 + (k + 0.5)/V (t1 - t0); the window rule is ``EventStream.index_range`` (t_k <= t < t_k+1)."""
    t0, t1 = float(exposure[0]), float(exposure[1])
    H, W = events.height, events.width
    if V < 2:
        return torch.zeros(0, 2, H, W)
    inst = t0 + (np.arange(V) + 0.5) / V * (t1 - t0)
    out = np.zeros((V - 1, 2, H * W), dtype=np.float64)
    for k in range(V - 1):
        i0, i1 = events.index_range(seconds_to_us(inst[k]), seconds_to_us(inst[k + 1]))
        if i1 > i0:
            idx = events.y[i0:i1].astype(np.int64) * W + events.x[i0:i1]
            on = events.p[i0:i1] > 0
            out[k, 0] = np.bincount(idx[on], minlength=H * W)
            out[k, 1] = np.bincount(idx[~on], minlength=H * W)
    return torch.from_numpy(out.reshape(V - 1, 2, H, W).astype(np.float32))


def random_window(V: int, generator: torch.Generator | None = None) -> tuple[int, int]:
    """A window (i, j), 0 <= i < j < V, of two virtual instants, uniform over the V (V - 1) / 2 pairs."""
    if V < 2:
        raise ValueError(f"a window needs V >= 2 virtual instants, got {V}")
    pair = int(torch.randint(V * (V - 1) // 2, (1,), generator=generator))
    i = 0
    while pair >= V - 1 - i:  # row i of the upper triangle holds the V - 1 - i pairs (i, i + 1 .. V - 1)
        pair -= V - 1 - i
        i += 1
    return i, i + 1 + pair


def window_counts(
    counts: Tensor,  # [V - 1, 2, H, W] counts between consecutive instants (event_counts)
    i: int,
    j: int,
) -> Tensor:  # [1, 2, H, W]
    """ON and OFF counts between virtual instants i < j: the consecutive counts of the windows they span."""
    if not 0 <= i < j <= counts.shape[0]:
        raise ValueError(f"window ({i}, {j}) must satisfy 0 <= i < j <= V - 1 = {counts.shape[0]}")
    return counts[i:j].sum(0, keepdim=True)
