"""``ebad eval``: PSNR / SSIM of a run on a capture's test views and deblurred frames.

The protocol (which poses, refinement, metric conventions) is ``ebad.evaluate``'s docstring.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

NAME = "eval"
HELP = "PSNR/SSIM of a run on the capture's test views (optionally pose-refined) and deblurred frames"


@dataclass
class Args:
    run: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="RUN")]
    """run folder written by 'ebad reconstruct'"""
    capture: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="CAPTURE")]
    """the capture (its test views carry the images)"""
    refine_poses: bool = False
    (
        "also refine each test pose against its image with the scene frozen, until the loss stops improving "
        "(BAD-Gaussians / EBAD-NeRF protocol); scores before and after"
    )
    refine_iters: int = 300
    """at most this many Adam steps per test pose"""
    renders: str | None = None
    """write each test render (refined when refining) here, one 16-bit PNG per view (round(65535 v), the capture's
    recorded values like its frames), named by the view"""
    gt: str | None = None
    """ground-truth folder with gt.json (None: CAPTURE/../gt when present)"""
    out: str | None = None
    """write the results as JSON here (None: RUN/eval.json)"""


def run(args: Args) -> int:
    import scenes
    from scenes.capture import file_in  # output paths from names: never outside their folder

    from ..errors import UserError
    from ..evaluate import evaluate
    from ..runfolder import json_safe, load_run, write_text_atomic

    if args.refine_iters < 1:
        raise UserError(f"--refine-iters must be >= 1, got {args.refine_iters}")
    run_ = load_run(args.run)
    cap = scenes.load(args.capture)
    gt_dir = Path(args.gt) if args.gt else Path(args.capture).resolve().parent / "gt"
    if args.gt and not (gt_dir / "gt.json").exists():
        raise UserError(f"--gt {gt_dir}: no gt.json there")
    gt = scenes.read_ground_truth(gt_dir).frames(run_.names) if (gt_dir / "gt.json").exists() else None
    renders_to = None
    if args.renders:

        def renders_to(name, img, folder=Path(args.renders)):
            scenes.write_image(file_in(folder, name, ".png", "test view name"), img, bits=16)

    res = evaluate(
        run_,
        cap,
        refine=args.refine_poses,
        gt_frames=gt,
        refine_iters=args.refine_iters,
        renders_to=renders_to,
        show=True,
    )
    if not any(k in res for k in ("test", "deblurred")):
        raise UserError(
            f"nothing to evaluate: capture {args.capture} has no test view with an image and a pose, "
            "and no ground truth was found"
        )
    missing = [n for n, how in res.get("poses", {}).items() if how == "none"]
    if missing:
        print(
            f"ebad eval: {len(missing)} test view(s) have no pose in the run's frame and are not scored: "
            f"{', '.join(missing)}"
        )
    for key, label in [
        ("test", "test views"),
        ("test_refined", "test views, poses refined"),
        ("deblurred", "deblurred training frames"),
    ]:
        if key in res:
            print(f"{label:28s} PSNR {res[key].psnr:6.2f} dB  SSIM {res[key].ssim:.4f}  (n={res[key].n})")
    out = Path(args.out) if args.out else Path(args.run) / "eval.json"
    write_text_atomic(out, json.dumps(json_safe(res), indent=2) + "\n")
    return 0
