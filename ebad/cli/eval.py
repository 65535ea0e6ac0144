"""``ebad eval``: PSNR / SSIM of a run on a capture's test views and deblurred frames."""
from __future__ import annotations

import json
from pathlib import Path

NAME = "eval"
HELP = "PSNR/SSIM of a run on the capture's test views (optionally pose-refined) and deblurred frames"


def add_arguments(parser) -> None:
    parser.add_argument("run", help="run folder written by 'ebad reconstruct'")
    parser.add_argument("capture", help="the capture (its test views carry the images)")
    parser.add_argument("--refine-poses", action="store_true",
                        help="also refine each test pose against its image with the scene frozen (EBAD-NeRF protocol)")
    parser.add_argument("--refine-iters", type=int, default=60, help="Adam steps per test pose")
    parser.add_argument("--gt", default=None,
                        help="ground-truth folder with gt.json (default: CAPTURE/../gt when present)")
    parser.add_argument("--out", default=None, help="write the results as JSON here (default RUN/eval.json)")


def run(args) -> int:
    import scenes

    from ..evaluate import evaluate, load_gt_frames
    from ..errors import UserError
    from ..runfolder import json_safe, load_run

    run_ = load_run(args.run)
    cap = scenes.load(args.capture)
    gt_dir = Path(args.gt) if args.gt else Path(args.capture).resolve().parent / "gt"
    if args.gt and not (gt_dir / "gt.json").exists():
        raise UserError(f"--gt {gt_dir}: no gt.json there")
    gt = load_gt_frames(gt_dir, run_.names) if gt_dir.exists() else None
    res = evaluate(run_, cap, refine=args.refine_poses, gt_frames=gt, refine_iters=args.refine_iters)
    if not res:
        raise UserError(f"nothing to evaluate: capture {args.capture} has no test images and no ground truth was found")
    for key, label in [("test", "test views"), ("test_refined", "test views, poses refined"),
                       ("deblurred", "deblurred training frames")]:
        if key in res:
            print(f"{label:28s} PSNR {res[key].psnr:6.2f} dB  SSIM {res[key].ssim:.4f}  (n={res[key].n})")
    out = Path(args.out) if args.out else Path(args.run) / "eval.json"
    out.write_text(json.dumps(json_safe(res), indent=2) + "\n")
    return 0
