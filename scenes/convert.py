"""``python -m scenes.convert INPUT --out FOLDER``: any layout ``scenes.load`` reads, written as an
``ebad-capture/1`` folder, with a summary of what was found and what was assumed.

Layouts: an ``ebad-capture/1`` folder, an ``.aedat4`` file, a ROS1 ``.bag`` (rpg_dvs_ros), an
Event Camera Dataset folder, an EvDeblurNeRF folder, an EBAD-NeRF or E2NeRF folder. Options
that only some layouts need: ``--exposure-us`` (a bag without ``/dvs/exposure``),
``--intrinsics FX FY CX CY`` (AEDAT4 or a bag without camera_info), ``--llffhold`` (EBAD-NeRF).
Options for any layout (``hold_out``; ``ebad reconstruct`` has the same three for one run):
``--test-every N`` holds out every Nth frame (index 0, N, 2N, ...) as a test view, ``--test-frames
NAME,NAME`` the named frames; a held-out frame leaves the training frames and becomes a test view
with its recorded image (blurry if the frame is) and its pose (when the capture has poses).
``--pose-trust exact|approximate|none`` states how far the capture's poses are trusted.
``--cfa RGGB|BGGR|GRBG|GBRG`` states the Bayer filter of a colour DAVIS in the frames' pixel grid
when the input does not record it (``--cfa none``: take the events as luminance); a pattern that
disagrees with the one the input records is an error (``scenes.load``'s ``cfa``).
``--poses FILE`` takes the frames' poses from a pose file users already have (a COLMAP model,
``transforms.json``, LLFF ``poses_bounds.npy``, a TUM trajectory; ``scenes.pose_files``), with
``--pose-format`` when its name does not tell.

Exit status: 0 written; 2 for a user mistake (one line naming the file and field, or the path
of an OSError); anything else is a bug and shows its traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from edi import EbadError

from .capture import POSE_TRUST, Capture
from .e2nerf import LLFF_HOLD
from .format import save
from .holdout import hold_out
from .pose_files import POSE_FORMATS, apply_pose_file, read_pose_file
from .readers import load
from .synth import check_replaceable

__all__ = ["main", "summary", "hold_out", "parse_names"]

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
        f"poses: {'yes' if cap.c2w is not None else 'no (SfM will estimate them)'}"
        + (f" (from {m['pose_source']})" if cap.c2w is not None and m.get("pose_source") else ""),
        f"test views: {len(cap.test_views)}"
        + (f" ({len(m['held_out_frames'])} held-out frames)" if m.get("held_out_frames") else ""),
        f"pose trust: {cap.effective_pose_trust}" + ("" if cap.pose_trust is not None else " (unstated)"),
    ]
    if cap.cfa is not None:
        kind = "raw Bayer mosaics" if cap.raw_mosaic else "demosaiced RGB"
        lines.append(f"colour filter: {cap.cfa} ({m.get('cfa_source', 'stated')}); frames are {kind}")
    elif "cfa_note" in m:
        lines.append(f"colour filter: none ({m['cfa_note']})")
    if m.get("K_guessed"):
        lines.append("intrinsics: guessed from a 70-degree field of view (pass --intrinsics FX FY CX CY)")
    if cap.c2w is not None and m.get("pose_file_focal_differs"):
        lines.append(f"warning: {m['pose_file_focal_differs']}")
    if m.get("undistorted"):
        lines.append(f"undistorted on load ({m.get('events_dropped_undistort', 0)} events left the sensor)")
    return lines


def parse_names(text: str | None) -> list[str]:
    """``NAME,NAME`` as a list of names (blanks dropped); None or '' -> []."""
    return [n.strip() for n in (text or "").split(",") if n.strip()]


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
    p.add_argument(
        "--test-every",
        type=int,
        default=0,
        metavar="N",
        help="hold out frames 0, N, 2N, ... as test views (their recorded image and pose); 0: none (default)",
    )
    p.add_argument(
        "--test-frames", default=None, metavar="NAME,NAME", help="hold out these frames (by name) as test views"
    )
    p.add_argument(
        "--pose-trust",
        choices=POSE_TRUST,
        default=None,
        help="how far the capture's poses are trusted (motion capture: exact); default: the capture's own",
    )
    p.add_argument(
        "--cfa",
        default=None,
        metavar="PATTERN",
        help="Bayer filter of a colour DAVIS (RGGB, BGGR, GRBG, GBRG; pixels (0,0) (1,0) (0,1) (1,1)) when the "
        "input does not record it; 'none': events taken as luminance. Default: what the input records",
    )
    p.add_argument(
        "--poses",
        default=None,
        metavar="FILE",
        help="the frames' poses from this file: a COLMAP model folder (sparse/0), transforms.json, "
        "poses_bounds.npy or a TUM trajectory (docs/formats.md)",
    )
    p.add_argument(
        "--pose-format",
        choices=POSE_FORMATS,
        default=None,
        help="the format of --poses (default: from its name: folder colmap, .json transforms, .npy llff, .txt tum)",
    )
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
            args.input,
            undistort=not args.no_undistort,
            K=K,
            exposure_us=args.exposure_us,
            llffhold=args.llffhold,
            cfa=args.cfa,
        )
        if args.poses is not None:
            cap = apply_pose_file(cap, read_pose_file(args.poses, args.pose_format))
        elif args.pose_format is not None:
            raise EbadError("--pose-format needs --poses FILE")
        cap = hold_out(cap, args.test_every, parse_names(args.test_frames), args.pose_trust)
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
