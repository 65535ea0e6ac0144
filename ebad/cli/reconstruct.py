"""``ebad reconstruct``: a sharp Gaussian scene and per-exposure trajectories from a capture."""
from __future__ import annotations

import json
import time
from pathlib import Path

NAME = "reconstruct"
HELP = "reconstruct a sharp 3D Gaussian scene and camera trajectories from a capture"


def add_arguments(parser) -> None:
    from ..config import PRESETS, add_dataclass_arguments

    parser.add_argument("capture", help="capture folder or file (any layout scenes.load reads)")
    parser.add_argument("--out", required=True, help="run folder to write")
    parser.add_argument("--preset", default="ebad", choices=sorted(PRESETS), help="method (default ebad)")
    parser.add_argument("--config", default=None, help="a config.json to start from instead of the preset")
    parser.add_argument("--iters", type=int, default=None, help="optimisation steps")
    parser.add_argument("--max-seconds", type=float, default=None, help="wall-time budget of the optimisation")
    parser.add_argument("--resume", action="store_true", help="continue the run folder's checkpoint")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_dataclass_arguments(parser)


def resolve_config(args):
    from ..config import apply_dataclass_arguments, load_config, preset

    cfg = load_config(args.config) if args.config else preset(args.preset)
    cfg = apply_dataclass_arguments(cfg, args)
    if args.iters is not None:
        if args.iters < 1:
            raise ValueError(f"--iters must be >= 1, got {args.iters}")
        cfg.train.iters = args.iters
    if args.max_seconds is not None:
        if args.max_seconds <= 0:
            raise ValueError(f"--max-seconds must be > 0, got {args.max_seconds}")
        cfg.train.max_seconds = args.max_seconds
    if args.no_progress:
        cfg.train.progress = False
    return cfg


def run(args) -> int:
    import scenes

    from ..config import load_config
    from ..runfolder import json_safe, write_run
    from ..trainer import reconstruct

    out = Path(args.out)
    cfg = resolve_config(args)
    if args.resume and (out / "config.json").exists() and not args.config:
        saved = load_config(out / "config.json")
        saved.train.iters = cfg.train.iters
        saved.train.max_seconds = cfg.train.max_seconds
        saved.train.progress = cfg.train.progress
        cfg = saved
    elif not args.resume and (out / "checkpoints" / "last.pt").exists():
        raise ValueError(f"--out {out} already holds a run; pass --resume to continue it or choose another folder")
    capture = scenes.load(args.capture)
    out.mkdir(parents=True, exist_ok=True)
    from ..config import save_config
    save_config(cfg, out / "config.json")
    t0 = time.perf_counter()
    run_ = reconstruct(capture, cfg, out_dir=out, resume=args.resume)
    gt = None
    gt_json = Path(args.capture).parent / "gt" / "gt.json"
    if gt_json.exists():
        import numpy as np

        doc = json.loads(gt_json.read_text())
        trajs = {fr["name"]: fr["trajectory"]["c2w"] for fr in doc.get("frames", []) if "trajectory" in fr}
        if all(n in trajs for n in run_.names):
            gt = np.array([trajs[n] for n in run_.names])
    write_run(run_, out, gt_trajectories=gt)
    m = run_.metrics
    test = m.get("test") or {}
    print(f"ebad reconstruct [{cfg.name}]: {m['steps']} steps ({m['stop_reason']}), {m['gaussians']} Gaussians, "
          f"{time.perf_counter() - t0:.1f} s" + (f", test PSNR {test['psnr']:.2f} dB SSIM {test['ssim']:.3f}" if test else ""))
    print(f"  run folder: {out}")
    (out / "metrics.json").write_text(json.dumps(json_safe(m), indent=2) + "\n")
    return 0
