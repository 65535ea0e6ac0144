"""``python -m scenes.convert INPUT --out FOLDER``: any layout ``scenes.load`` reads, written as an
``ebad-capture/1`` folder, with a summary of what was found and what was assumed.

Layouts: an ``ebad-capture/1`` folder, an ``.aedat4`` file, a ROS1 ``.bag`` (rpg_dvs_ros), an
Event Camera Dataset folder, an EvDeblurNeRF folder, an EBAD-NeRF or E2NeRF folder. Options
that only some layouts need: ``--exposure-us`` (a bag without ``/dvs/exposure``),
``--intrinsics FX FY CX CY`` (AEDAT4 or a bag without camera_info), ``--llffhold`` (EBAD-NeRF).

Exit status: 0 written; 2 for a user mistake (one line naming the file and field, or the path
of an OSError); anything else is a bug and shows its traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from edi import EbadError

from .capture import Capture
from .e2nerf import LLFF_HOLD
from .format import save
from .readers import load
from .synth import check_replaceable

__all__ = ["main", "summary"]

USER_ERROR_EXIT = 2
CAPTURE_CONTENTS = {"capture.json", "events.npz", "frames", "test"}  # what scenes.save writes in a capture folder


def summary(cap: Capture) -> list[str]:
    """What a capture holds and what its reader assumed, one line each."""
    m = cap.meta
    exp = np.diff(cap.exposures, axis=1)[:, 0]
    lines = [
        f"layout: {m.get('source_layout', 'ebad-capture/1')}",
        f"frames: {cap.num_frames} x {cap.width}x{cap.height}, {'colour' if cap.channels == 3 else 'grey'}",
        f"exposures: {exp.min() * 1e3:.3f}..{exp.max() * 1e3:.3f} ms"
        + (" (nominal: the layout records none)" if m.get("exposure_known") is False else ""),
        f"events: {len(cap.events)}"
        + (
            f" (binned: {m['events_binned']['bins']} bins per exposure, placed at bin centres)"
            if "events_binned" in m
            else ""
        ),
        f"poses: {'yes' if cap.c2w is not None else 'no (SfM will estimate them)'}",
        f"test views: {len(cap.test_views)}",
    ]
    if m.get("K_guessed"):
        lines.append("intrinsics: guessed from a 70-degree field of view (pass --intrinsics FX FY CX CY)")
    if m.get("undistorted"):
        lines.append(f"undistorted on load ({m.get('events_dropped_undistort', 0)} events left the sensor)")
    return lines


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m scenes.convert", description=__doc__.split("\n\n")[0])
    p.add_argument("input", help="capture folder or file in any layout scenes.load reads")
    p.add_argument("--out", required=True, help="ebad-capture/1 folder to write")
    p.add_argument(
        "--exposure-us", type=int, default=None, help="APS exposure, microseconds (bags without /dvs/exposure)"
    )
    p.add_argument(
        "--intrinsics",
        type=float,
        nargs=4,
        metavar=("FX", "FY", "CX", "CY"),
        default=None,
        help="pixels, top-left pixel centre at (0.5, 0.5) (layouts without calibration)",
    )
    p.add_argument("--llffhold", type=int, default=LLFF_HOLD, help="EBAD-NeRF: hold out every Nth view (default 8)")
    p.add_argument("--no-undistort", action="store_true", help="keep the distortion coefficients instead")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is an ebad-capture/1 folder")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    K = None
    if args.intrinsics is not None:
        fx, fy, cx, cy = args.intrinsics
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    try:
        if args.llffhold < 1:
            raise EbadError(f"--llffhold must be >= 1, got {args.llffhold}")
        # the rule of ``ebad synth --overwrite``: never replace a folder this could not have written
        check_replaceable(
            Path(args.out), args.overwrite, CAPTURE_CONTENTS, "capture.json", "an ebad-capture/1 folder", "--out"
        )
        cap = load(
            args.input, undistort=not args.no_undistort, K=K, exposure_us=args.exposure_us, llffhold=args.llffhold
        )
        save(cap, args.out, overwrite=args.overwrite)
    except EbadError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USER_ERROR_EXIT
    except OSError as exc:
        print(f"error: {exc.filename or ''}: {exc.strerror or exc}", file=sys.stderr)
        return USER_ERROR_EXIT
    for line in summary(cap):
        print(f"  {line}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
