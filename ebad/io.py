"""Run-folder files: 16-bit PNGs, the 3DGS ``point_cloud.ply``, trajectories (JSON and plot).

PNG: ``scenes.images.write_png16`` (a tiny encoder: Pillow cannot write 16-bit colour);
values are linear intensity, ``round(v * 65535)``.

PLY (through ``plyfile``): the standard 3DGS layout (binary little-endian float32): ``x y z nx ny nz f_dc_0 f_dc_1
f_dc_2 f_rest_0 .. f_rest_44 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3``, opacity as a logit, scales
as logs, rotation (w, x, y, z). ``f_rest_*`` are the SH coefficients of degrees 1..3 in INRIA's layout: channel-major
(the 15 of R, then G, then B), always 45 of them, zero above the model's degree, so that INRIA's ``load_ply`` at its
default degree 3 (and viewers reading degree 3) open every model; ``comment ebad sh_degree D`` records the model's
own degree so it reads back as it was. A grey model writes its single value into all three f_dc (and its
coefficients into each channel's f_rest) so viewers show grey, and records ``comment ebad channels 1`` so it reads
back as grey.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyParseError

# one 16-bit PNG codec for the project (frames in captures, renders in runs)
from scenes.images import read_png16, write_png16

__all__ = ["write_png16", "read_png16", "write_ply", "read_ply", "write_trajectories", "plot_trajectories"]


# --------------------------------------------------------------------------- PLY

PLY_SH_DEGREE = 3  # the degree of the f_rest_* layout written (INRIA's default max_sh_degree)
_REST_PER_CHANNEL = (PLY_SH_DEGREE + 1) ** 2 - 1  # 15
_REST_FIELDS = [f"f_rest_{i}" for i in range(3 * _REST_PER_CHANNEL)]
_PLY_FIELDS = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    + [f"scale_{i}" for i in range(3)]
    + [f"rot_{i}" for i in range(4)]
)
_WRITE_FIELDS = _PLY_FIELDS[:9] + _REST_FIELDS + _PLY_FIELDS[9:]  # INRIA's order: f_rest after f_dc


def write_ply(path: str | Path, params: dict[str, torch.Tensor]) -> Path:
    """Write the model in the standard 3DGS layout (see module docstring) with ``plyfile``."""
    means = params["means"].detach().float().cpu().numpy()
    N = means.shape[0]
    colors = params["colors"].detach().float().cpu().numpy()
    D = colors.shape[1]
    if D == 1:
        f_dc = np.repeat(colors, 3, axis=1)
    elif D == 3:
        f_dc = colors
    else:
        raise ValueError(f"write_ply supports D = 1 or 3 colour channels, got {D}")
    rest = np.zeros((N, _REST_PER_CHANNEL, 3), np.float32)  # [N, 15, 3], zero above the model's degree
    degree = 0
    if params.get("sh_rest") is not None:
        sh = params["sh_rest"].detach().float().cpu().numpy()  # [N, K - 1, D]
        degree = int(round((sh.shape[1] + 1) ** 0.5)) - 1
        if sh.shape[1] > _REST_PER_CHANNEL:
            raise ValueError(f"write_ply supports SH degrees up to {PLY_SH_DEGREE}, got {degree}")
        rest[:, : sh.shape[1]] = sh  # a grey model's one channel broadcast to the three
    f_rest = rest.transpose(0, 2, 1).reshape(N, 3 * _REST_PER_CHANNEL)  # channel-major (INRIA): R, G, B
    cols = [
        means,
        np.zeros((N, 3), np.float32),
        f_dc,
        f_rest,
        params["opacities"].detach().float().cpu().numpy()[:, None],
        params["scales"].detach().float().cpu().numpy(),
        params["quats"].detach().float().cpu().numpy(),
    ]
    data = np.concatenate(cols, axis=1).astype("<f4")
    vertex = np.empty(N, dtype=[(name, "<f4") for name in _WRITE_FIELDS])
    for k, name in enumerate(_WRITE_FIELDS):
        vertex[name] = data[:, k]
    comments = [f"ebad channels {D}", f"ebad sh_degree {degree}"]
    ply = PlyData([PlyElement.describe(vertex, "vertex")], text=False, byte_order="<", comments=comments)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ply.write(str(path))
    return path


def read_ply(path: str | Path) -> dict[str, torch.Tensor]:
    """Read a 3DGS ``point_cloud.ply`` (float32 properties; the layout of ``write_ply``) with ``plyfile``.

    ``f_rest_*`` (INRIA's layout), when present, become ``sh_rest`` [N, K - 1, D] of the degree ``comment ebad
    sh_degree`` records, else of the degree their count says; no ``sh_rest`` at degree 0.

    Raises:
        ValueError: not a binary little-endian PLY, no ``vertex`` element or one of no vertices, a
            property that is not float32, a missing property; names the file.
    """
    path = Path(path)
    try:
        ply = PlyData.read(str(path))
    except PlyParseError as exc:
        raise ValueError(f"{path}: not a PLY file ({exc})") from None
    if ply.text or ply.byte_order != "<":
        raise ValueError(f"{path}: only binary_little_endian PLY is supported")
    if "vertex" not in ply:
        raise ValueError(f"{path}: no 'element vertex' in the header")
    vertex = ply["vertex"]
    if vertex.count == 0:
        raise ValueError(f"{path}: holds no Gaussians (element vertex 0): a model cannot be empty")
    for prop in vertex.properties:
        if getattr(prop, "val_dtype", None) != "f4":
            raise ValueError(f"{path}: property {prop.name} must be float, got {prop}")
    names = [prop.name for prop in vertex.properties]
    missing = [n for n in _PLY_FIELDS if n not in names and not n.startswith("n")]
    if missing:
        raise ValueError(f"{path}: missing properties {missing}")
    D = 3
    degree: int | None = None
    for comment in ply.comments:
        parts = comment.split()
        if parts[:2] == ["ebad", "channels"]:
            D = int(parts[2])
        if parts[:2] == ["ebad", "sh_degree"]:
            degree = int(parts[2])
    col = {n: np.asarray(vertex[n]) for n in names}

    def stack(keys: list[str]) -> torch.Tensor:
        return torch.from_numpy(np.stack([col[k] for k in keys], 1).astype(np.float32))

    out = {
        "means": stack(["x", "y", "z"]),
        "colors": stack([f"f_dc_{i}" for i in range(D)]),
        "opacities": torch.from_numpy(col["opacity"].astype(np.float32).copy()),
        "scales": stack([f"scale_{i}" for i in range(3)]),
        "quats": stack([f"rot_{i}" for i in range(4)]),
    }
    rest_names = sorted((n for n in names if n.startswith("f_rest_")), key=lambda n: int(n.split("_")[-1]))
    if rest_names:
        per_channel = len(rest_names) // 3
        have = int(round((per_channel + 1) ** 0.5)) - 1
        if 3 * ((have + 1) ** 2 - 1) != len(rest_names) or rest_names != [
            f"f_rest_{i}" for i in range(len(rest_names))
        ]:
            raise ValueError(f"{path}: {len(rest_names)} f_rest properties are not the SH coefficients of a degree")
        degree = have if degree is None else min(degree, have)
        rest = stack(rest_names).reshape(-1, 3, per_channel).transpose(1, 2)  # [N, per_channel, 3]
        if degree > 0:
            out["sh_rest"] = rest[:, : (degree + 1) ** 2 - 1, :D].contiguous()
    return out


# --------------------------------------------------------------------------- trajectories


def write_trajectories(
    path: str | Path, names: list[str], exposures: np.ndarray, poses: np.ndarray, u: np.ndarray
) -> Path:  # poses [F, S, 4, 4], u [S]
    """JSON: per frame its name, exposure and the camera-to-world pose at each sampled instant."""
    out = []
    for f, name in enumerate(names):
        t0, t1 = float(exposures[f, 0]), float(exposures[f, 1])
        out.append(
            {
                "name": name,
                "t_start": t0,
                "t_end": t1,
                "samples": [{"t": t0 + float(uu) * (t1 - t0), "c2w": poses[f, s].tolist()} for s, uu in enumerate(u)],
            }
        )
    path = Path(path)
    path.write_text(json.dumps({"frames": out}, indent=1) + "\n")
    return path


def plot_trajectories(path: str | Path, poses: np.ndarray, gt: np.ndarray | None = None) -> Path:  # [F, S, 4, 4]
    """Top view (x, z) of the camera centres along every exposure; ground truth dashed if given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, (i, j, lab) in zip(axes, [(0, 2, "x-z (top)"), (0, 1, "x-y (front)")]):
        for f in range(poses.shape[0]):
            c = poses[f, :, :3, 3]
            ax.plot(c[:, i], c[:, j], "-", lw=1.5, color="C0", label="recovered" if f == 0 else None)
            ax.plot(c[0, i], c[0, j], "o", ms=3, color="C0")
            if gt is not None:
                g = gt[f, :, :3, 3]
                ax.plot(g[:, i], g[:, j], "--", lw=1, color="C3", label="ground truth" if f == 0 else None)
        ax.set_title(f"camera centres during each exposure, {lab}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
