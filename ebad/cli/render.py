"""``ebad render``: PNG renders of a run's test views, training frames or a smooth camera path.

PNGs hold the capture's own recorded values (the run's camera response applied, no other curve,
``ebad.export``): 8-bit ``round(255 v)`` by default, 16-bit ``round(65535 v)`` with ``--bits 16``
(``scenes.images.write_png16``): the encoding of the capture's frames and of ``ebad deblur``'s
outputs, so a render reads back with ``scenes.read_image`` next to its input frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

NAME = "render"
HELP = "render a run's test views, training frames or a smooth camera path as PNGs (the capture's recorded values)"


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
    """PNG bits: 8 (round(255 v)) or 16 (round(65535 v)); values in the capture's recorded domain, like its frames"""


def smooth_path(c2w: np.ndarray, n: int) -> np.ndarray:  # [F, 4, 4] -> [n, 4, 4]
    """n camera-to-world poses along a smooth path through the cameras ``c2w`` (in the order given),
    at uniform steps of the camera index s in [0, F - 1]; camera k is passed at s = k.

    Centres: a cubic spline (``scipy.interpolate.CubicSpline``, not-a-knot ends: twice continuously
    differentiable, and cameras on a line at constant spacing give a straight path at constant speed;
    two cameras: the straight line, three: a parabola). Rotations: slerp between neighbouring cameras
    (``scipy.spatial.transform.Slerp``: the geodesic, at constant angular speed within each step)."""
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, Slerp

    c2w = np.asarray(c2w, dtype=np.float64)
    F = len(c2w)
    if F == 1:
        return np.repeat(c2w, n, 0)
    knots = np.arange(F, dtype=np.float64)
    s = np.linspace(0, F - 1, n)
    out = np.zeros((n, 4, 4))
    out[:, :3, 3] = CubicSpline(knots, c2w[:, :3, 3], axis=0)(s)
    out[:, :3, :3] = Slerp(knots, Rotation.from_matrix(c2w[:, :3, :3]))(s).as_matrix()
    out[:, 3, 3] = 1
    return out


def run(args: Args) -> int:
    from scenes.capture import file_in  # output paths from names: never outside their folder

    from ..errors import UserError
    from ..export import write_render
    from ..runfolder import load_run

    run_ = load_run(args.run)
    out = Path(args.out)
    kind = f"{args.bits}-bit, the capture's recorded values"
    if args.path:
        if args.path < 2:
            raise UserError(f"--path needs at least 2 frames, got {args.path}")
        path_poses = smooth_path(run_.trajectories.mid_poses().numpy().astype(np.float64), args.path)
        imgs = run_.render(path_poses)
        for i, img in enumerate(imgs):
            write_render(out / f"path_{i:05d}.png", img, args.bits)
        print(f"ebad render: {len(imgs)} path frames ({kind} PNG) -> {out}")
        return 0
    if args.split == "train":
        files = [file_in(out, name, ".png") for name in run_.names]  # refused before any rendering
        imgs = run_.deblurred_frames()
        for file, img in zip(files, imgs):
            write_render(file, img, args.bits)
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
    files = [file_in(out, v.name, ".png") for v in views]
    imgs = run_.render(np.stack([poses[v.name] for v in views]))
    for file, img in zip(files, imgs):
        write_render(file, img, args.bits)
    print(f"ebad render: {len(imgs)} test views ({kind} PNG) -> {out}")
    return 0
