"""The run folder: what ``ebad reconstruct`` leaves behind, and how ``render``/``eval`` read it.

Layout::

    RUN/config.json            resolved Config
    RUN/metrics.json           Run.metrics (+ per-step history in history.json)
    RUN/checkpoints/last.pt    resumable state (every train.checkpoint_every steps)
    RUN/point_cloud.ply        standard 3DGS layout (see ebad.io)
    RUN/model.json             K, image size, frame names, exposures, V per frame
    RUN/trajectories.json      camera-to-world poses sampled over every exposure
    RUN/trajectories.png       their plot
    RUN/deblurred/NAME.png     every training frame rendered sharp at mid-exposure (16-bit)
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .config import load_config, save_config
from .errors import UserError
from .export import write_exports
from .io import plot_trajectories, read_ply, write_png16, write_ply, write_trajectories
from .trajectory import ExposureTrajectories

__all__ = ["write_run", "load_run", "json_safe"]


def json_safe(x):
    """Numbers, lists and dicts only (numpy scalars and arrays converted)."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def write_run(run, out: str | Path, gt_trajectories: np.ndarray | None = None) -> Path:
    """Write every file of the run folder except the checkpoint (written while training)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_config(run.config, out / "config.json")
    (out / "metrics.json").write_text(json.dumps(json_safe(run.metrics), indent=2) + "\n")
    (out / "history.json").write_text(json.dumps(json_safe(run.history)) + "\n")
    write_ply(out / "point_cloud.ply", run.params)
    model = {"K": run.K.tolist(), "width": run.width, "height": run.height, "names": run.names,
             "exposures": run.exposures.tolist(), "views": run.V.tolist(), "kind": run.trajectories.kind,
             "anchored": run.trajectories.anchored, "scale": run.trajectories.scale,
             "c2w_mid": run.trajectories.c2w_mid.tolist(), "knots": run.trajectories.knots.detach().tolist(),
             "moving": run.trajectories.moving.tolist(), "channels": run.channels}
    (out / "model.json").write_text(json.dumps(model) + "\n")
    poses, u = run.exposure_poses()
    write_trajectories(out / "trajectories.json", run.names, run.exposures, poses, u)
    plot_trajectories(out / "trajectories.png", poses, gt_trajectories)
    write_exports(run, out)  # cameras.json, point_cloud.splat, trajectories_tum.txt
    for name, img in zip(run.names, run.deblurred_frames()):
        write_png16(out / "deblurred" / f"{name}.png", img)
    return out


def load_run(path: str | Path):
    """A ``Run`` from a run folder (for rendering and evaluation)."""
    from .trainer import Run

    path = Path(path)
    for name in ("config.json", "model.json", "point_cloud.ply"):
        if not (path / name).exists():
            raise UserError(f"{path} is not a run folder: {name} is missing (run 'ebad reconstruct' first)")
    cfg = load_config(path / "config.json")
    model = json.loads((path / "model.json").read_text())
    params = {k: nn.Parameter(v) for k, v in read_ply(path / "point_cloud.ply").items()}
    if params["colors"].shape[1] != model["channels"]:
        params["colors"] = nn.Parameter(params["colors"][:, :model["channels"]].contiguous())
    traj = ExposureTrajectories(torch.tensor(model["c2w_mid"]), model["kind"], torch.tensor(model["moving"]),
                                scale=model["scale"], anchored=model["anchored"])
    with torch.no_grad():
        traj.knots.data = torch.tensor(model["knots"]).reshape(traj.knots.shape)
    metrics = json.loads((path / "metrics.json").read_text()) if (path / "metrics.json").exists() else {}
    return Run(params=params, trajectories=traj, config=cfg, K=np.array(model["K"]), width=model["width"],
               height=model["height"], names=model["names"], exposures=np.array(model["exposures"]),
               V=np.array(model["views"]), metrics=metrics, step=int(metrics.get("steps", 0)))
