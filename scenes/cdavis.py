"""Ev-DeblurNeRF's CDAVIS layout (a colour DAVIS346): rectified colour events back on their filter.

What the layout stores (uzh-rpg/EvDeblurNeRF: README and ``data/loader_events.py``), beside the
EvDeblurNeRF files ``scenes.readers.load_evdeblurnerf`` reads:

    images_1/*.png       demosaiced RGB frames, already undistorted
    events.h5            x, y, t, p; x, y are the *rectified* (undistorted) float coordinates of
                         each event's sensor pixel, in pixel-index space (centres at integers)
    ev_map.npz           inv_mapx, inv_mapy [H, W]: the rectified coordinates of each sensor
                         pixel (present only for colour events)

Ev-DeblurNeRF's loader gives the event at ``(inv_mapx[j, i], inv_mapy[j, i])`` the colour of
sensor pixel (i, j) under an RGGB filter (``color_map[0::2, 0::2]`` red, ``[1::2, 1::2]`` blue),
hard-coded for its DAVIS346. So here: each event is matched (exactly, as that loader does) to
its sensor pixel through ``ev_map.npz``, takes that pixel's channel of ``CDAVIS_CFA``, and is
placed on the pixel *of that channel* of the undistorted grid nearest to its rectified position
(``snap_to_channel``), so that ``Capture.cfa`` holds on the frames' grid as for any capture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from edi import EventStream
from edi.cfa import channel_map

from .errors import CaptureError

EPOCH_US = 10**12  # converted times above this (~11.6 days) are raw epoch readings (edi.io)

__all__ = ["CDAVIS_CFA", "EV_MAP", "read_cdavis_events", "snap_to_channel"]

CDAVIS_CFA = "RGGB"  # the filter Ev-DeblurNeRF's loader assumes over the sensor grid
EV_MAP = "ev_map.npz"


def snap_to_channel(
    pu: np.ndarray,  # [N] continuous pixel coordinates (pixel j covers [j, j + 1))
    pv: np.ndarray,  # [N]
    own: np.ndarray,  # [N] the channel (0 R, 1 G, 2 B) each point's event fired on
    chan: np.ndarray,  # [H, W] the channel of each pixel of the target grid (edi.cfa.channel_map)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # -> tx [N], ty [N], ok [N] bool
    """The pixel of channel ``own`` nearest to each point, among the 3 x 3 pixels around the one
    containing it (within sqrt(2) px of the point, sqrt(5) at the grid's border); ``ok`` False
    where the containing pixel is off the grid or no such pixel is on it."""
    h, w = chan.shape
    fu, fv = np.floor(pu).astype(np.int64), np.floor(pv).astype(np.int64)
    inside = (fu >= 0) & (fu < w) & (fv >= 0) & (fv < h)
    best = np.full(pu.shape, np.inf)
    tx, ty = np.zeros(pu.shape, np.int64), np.zeros(pu.shape, np.int64)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            cx, cy = fu + dx, fv + dy
            ok = inside & (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
            ok[ok] &= chan[cy[ok], cx[ok]] == own[ok]
            dist = np.where(ok, (cx + 0.5 - pu) ** 2 + (cy + 0.5 - pv) ** 2, np.inf)
            closer = dist < best
            best[closer], tx[closer], ty[closer] = dist[closer], cx[closer], cy[closer]
    return tx, ty, np.isfinite(best)


def _float_key(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # [N] uint64: the float32 bits of (x, y)
    xb = np.ascontiguousarray(x, dtype=np.float32).view(np.uint32).astype(np.uint64)
    yb = np.ascontiguousarray(y, dtype=np.float32).view(np.uint32).astype(np.uint64)
    return (xb << np.uint64(32)) | yb


def _event_arrays(path: Path) -> dict[str, np.ndarray]:
    try:
        if path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as z:
                arrs = {k: z[k] for k in z.files}
        else:
            import h5py

            with h5py.File(path, "r") as f:
                g = f["events"] if "events" in f and hasattr(f["events"], "keys") else f
                arrs = {k: g[k][:] for k in g.keys() if hasattr(g[k], "shape")}
    except (OSError, ValueError, KeyError) as exc:
        raise CaptureError(str(path), "events", f"unreadable ({type(exc).__name__}: {exc})") from None
    missing = [k for k in "xytp" if k not in arrs]
    if missing:
        raise CaptureError(str(path), missing[0], f"missing (CDAVIS events have x, y, t, p; found {sorted(arrs)})")
    return {k: np.asarray(arrs[k]).reshape(-1) for k in "xytp"}


def read_cdavis_events(ev_file: Path, ev_map: Path, width: int, height: int) -> tuple[EventStream, dict]:
    """The CDAVIS events on the ``width`` x ``height`` undistorted grid with ``CDAVIS_CFA`` true
    (module docstring), and what was done (for ``Capture.meta``).

    Raises:
        CaptureError: naming the file and field: unreadable files, maps of another size, an
            event whose coordinates no sensor pixel maps to, bad times or polarities.
    """
    from edi.io import infer_time_unit, to_us

    try:
        with np.load(ev_map, allow_pickle=False) as z:
            inv_x, inv_y = np.asarray(z["inv_mapx"]), np.asarray(z["inv_mapy"])
    except KeyError as exc:
        raise CaptureError(str(ev_map), str(exc).strip("'\""), "missing (expected inv_mapx, inv_mapy)") from None
    except (OSError, ValueError) as exc:
        raise CaptureError(str(ev_map), None, f"unreadable ({type(exc).__name__}: {exc})") from None
    if inv_x.shape != (height, width) or inv_y.shape != (height, width):
        raise CaptureError(
            str(ev_map), "inv_mapx", f"shape {inv_x.shape}, {inv_y.shape}; the frames are {height}x{width} (HxW)"
        )
    a = _event_arrays(ev_file)
    map_keys = _float_key(inv_x.ravel(), inv_y.ravel())
    order = np.argsort(map_keys, kind="stable")
    sorted_keys = map_keys[order]
    ev_keys = _float_key(a["x"], a["y"])
    pos = np.minimum(np.searchsorted(sorted_keys, ev_keys), len(sorted_keys) - 1)
    found = sorted_keys[pos] == ev_keys
    if not found.all():
        i = int(np.flatnonzero(~found)[0])
        raise CaptureError(
            str(ev_file),
            "x",
            f"{int((~found).sum())} events sit where no sensor pixel of {EV_MAP} maps to (first: index {i}, "
            f"({a['x'][i]}, {a['y'][i]})): their filter cannot be told",
        )
    src = order[pos]  # the sensor pixel (flat index) of each event
    own = channel_map(CDAVIS_CFA, height, width).ravel()[src]
    pu = np.asarray(a["x"], np.float64) + 0.5  # pixel-index coordinates -> our continuous ones
    pv = np.asarray(a["y"], np.float64) + 0.5
    tx, ty, ok = snap_to_channel(pu, pv, own, channel_map(CDAVIS_CFA, height, width))
    try:
        unit, _ = infer_time_unit(a["t"])
        t_us = to_us(np.asarray(a["t"]), unit, str(ev_file))
        t0 = int(t_us.min()) if len(t_us) and int(t_us.min()) > EPOCH_US else 0  # an epoch clock
        events = EventStream(t_us[ok], tx[ok], ty[ok], a["p"][ok], width, height, t0=t0)
    except ValueError as exc:
        raise CaptureError(str(ev_file), "events", str(exc).replace(f"{ev_file}: ", "")) from None
    meta = {
        "cfa_source": f"Ev-DeblurNeRF CDAVIS layout ({EV_MAP}): the {CDAVIS_CFA} filter its loader assumes",
        "events_rectified": "each event mapped to its sensor pixel through ev_map.npz for its channel, "
        "then to the nearest pixel of that channel on the undistorted grid",
        "events_dropped_rectified": int((~ok).sum()),
        "events_time_unit": unit,
    }
    return events, meta
