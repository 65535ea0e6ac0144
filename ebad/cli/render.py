"""``ebad render``: PNG renders of a run's test views, training frames or a smooth camera path.

PNGs are 8-bit sRGB-encoded by default (what image viewers and browsers expect: the linear
renders go through the sRGB transfer curve), or 16-bit linear intensity ``round(v * 65535)``
with ``--bits 16`` (for measurements; written by ``scenes.images.write_png16``)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

NAME = "render"
HELP = "render a run's test views, training frames or a smooth camera path as PNGs (8-bit sRGB or 16-bit linear)"


@dataclass
class Args:
    run: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="RUN")]
    """run folder written by 'ebad reconstruct'"""
    out: str
    """folder for the PNGs"""
    capture: str | None = None
    """capture whose views to render (needed for --split test)"""
    split: Literal["test", "train"] = "test"
    """test: the capture's test views; train: the training frames at mid-exposure"""
    path: Annotated[int, tyro.conf.arg(metavar="N")] = 0
    """instead, N frames along a smooth path through the training cameras"""
    bits: Literal[8, 16] = 8
    """8: sRGB-encoded 8-bit PNG, shows correctly in any viewer; 16: linear intensity round(v * 65535) to measure"""


def smooth_path(c2w: np.ndarray, n: int) -> np.ndarray:  # [F, 4, 4] -> [n, 4, 4]
    """Catmull-Rom through the camera centres (ordered as given); rotations slerped between
    neighbours through so(3)."""
    import torch

    from ..lie import so3_exp, so3_log

    F = len(c2w)
    if F == 1:
        return np.repeat(c2w, n, 0)
    s = np.linspace(0, F - 1, n)
    out = np.zeros((n, 4, 4))
    P = c2w[:, :3, 3]
    for j, sj in enumerate(s):
        i = min(int(np.floor(sj)), F - 2)
        u = sj - i
        p0, p1, p2, p3 = P[max(i - 1, 0)], P[i], P[i + 1], P[min(i + 2, F - 1)]
        pos = 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u ** 2 + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)
        R0 = torch.tensor(c2w[i, :3, :3])
        R1 = torch.tensor(c2w[i + 1, :3, :3])
        R = (R0 @ so3_exp(u * so3_log(R0.T @ R1))).numpy()
        out[j, :3, :3] = R
        out[j, :3, 3] = pos
        out[j, 3, 3] = 1
    return out


def run(args: Args) -> int:
    from ..errors import UserError
    from ..export import write_render
    from ..runfolder import load_run

    run_ = load_run(args.run)
    out = Path(args.out)
    kind = "8-bit sRGB" if args.bits == 8 else "16-bit linear"
    if args.path:
        if args.path < 2:
            raise UserError(f"--path needs at least 2 frames, got {args.path}")
        poses = smooth_path(run_.trajectories.mid_poses().numpy().astype(np.float64), args.path)
        imgs = run_.render(poses)
        for i, img in enumerate(imgs):
            write_render(out / f"path_{i:04d}.png", img, args.bits)
        print(f"ebad render: {len(imgs)} path frames ({kind} PNG) -> {out}")
        return 0
    if args.split == "train":
        imgs = run_.deblurred_frames()
        for name, img in zip(run_.names, imgs):
            write_render(out / f"{name}.png", img, args.bits)
        print(f"ebad render: {len(imgs)} training frames (mid-exposure, {kind} PNG) -> {out}")
        return 0
    if args.capture is None:
        raise UserError("--capture is required for --split test (the test views live in the capture)")
    import scenes

    from ..evaluate import eval_poses

    cap = scenes.load(args.capture)
    if not cap.test_views:
        raise UserError(f"capture {args.capture} has no test_views to render")
    poses, _ = eval_poses(run_, cap)  # in the run's frame: registered by its SfM, given, or aligned
    for v in cap.test_views:  # a view without an image: its given pose, when the run is in the capture's frame
        if v.name not in poses and v.c2w is not None and run_.pose_source in ("capture", "static"):
            poses[v.name] = np.asarray(v.c2w, np.float64)
    views = [v for v in cap.test_views if v.name in poses]
    if not views:
        raise UserError(f"no test view of {args.capture} has a pose in the run's frame")
    imgs = run_.render(np.stack([poses[v.name] for v in views]))
    for v, img in zip(views, imgs):
        write_render(out / f"{v.name}.png", img, args.bits)
    print(f"ebad render: {len(imgs)} test views ({kind} PNG) -> {out}")
    return 0
