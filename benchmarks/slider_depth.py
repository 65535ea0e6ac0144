"""Real data: novel views on slider_depth (Event Camera Dataset, DAVIS240C) from its frames.

    python -m benchmarks.slider_depth [--quick] [--data PATH] [--presets 3dgs,3dgs-po,ebad]
                                      [--seeds 0,1,2] [--seconds S] [--refine-iters N]

The capture is read with ``scenes.load`` (ECD text layout, poses interpolated from the motion
capture to the frame times, undistorted). Every 8th frame is held out as a test view (pose +
image); the others train. The recording's events cover only its first 0.17 s (frames 0-4), and
its frames are nearly sharp, so this is the "frames only" protocol: what ebad does on a real
capture with little blur and few events, against 3dgs on the same frames. Every preset gets the
same wall time per run. The capture's poses (motion capture, interpolated to the frame times)
do not say they are exact, so they count as approximate: ``ebad`` and ``3dgs-po`` (3dgs with
per-frame pose optimisation) optimise them, plain ``3dgs`` holds them. Scores
(``ebad.evaluate``): the novel views at the capture's poses, before and after refining each
against its image (scene frozen). Prints the table and writes JSON.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

from ._common import write_json

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "slider_depth"


def held_out_capture(cap, every: int = 8, stride: int = 1):
    """Frames with index % every == 0 become test views; the others train (every ``stride``-th)."""
    from scenes import TestView

    if cap.c2w is None:
        raise ValueError("slider_depth capture has no poses (groundtruth.txt)")
    test = [i for i in range(cap.num_frames) if i % every == 0]
    train = [i for i in range(cap.num_frames) if i % every != 0][::stride]
    out = copy.copy(cap)
    out.frames = cap.frames[train]
    out.exposures = cap.exposures[train]
    out.c2w = cap.c2w[train]
    names = cap.frame_names()
    out.names = [names[i] for i in train]
    out.split = ["train"] * len(train)
    out.test_views = [
        TestView(
            name=names[i],
            t=float(cap.exposures[i].mean()),
            c2w=cap.c2w[i],
            image=cap.frames[i],
        )
        for i in test
    ]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="every 3rd training frame, one seed, 20 s per run")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument(
        "--presets", default="3dgs,3dgs-po,ebad", help="comma-separated (3dgs-po: 3dgs with pose optimisation)"
    )
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--seconds", type=float, default=None, help="training wall time per run (default 120; quick 20)")
    ap.add_argument("--iters", type=int, default=1000000, help="step cap per run")
    ap.add_argument("--refine-iters", type=int, default=150, help="test-pose refinement steps at most")
    ap.add_argument("--name", default="slider_depth", help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import numpy as np

    import scenes
    from ebad.evaluate import evaluate
    from ebad.run import capture_kind, reconstruct, warm_up

    from .ablation import make_config

    data = Path(args.data)
    if not data.exists():
        print(f"slider_depth not found at {data}; pass --data", file=sys.stderr)
        return 2
    presets = [p for p in args.presets.split(",") if p]
    seeds = [0] if args.quick else [int(s) for s in args.seeds.split(",")]
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 120.0)
    for name in presets:
        make_config(name, args.iters, seconds, 0).check()  # a typo fails before any training
    cap = held_out_capture(scenes.load(data), stride=3 if args.quick else 1)
    warm_up([capture_kind(cap)])  # numba compiles once, outside every preset's budget
    rows = []
    for seed in seeds:
        for name in presets:
            cfg = make_config(name, args.iters, seconds, seed)
            t0 = time.perf_counter()
            run = reconstruct(cap, cfg)
            wall = time.perf_counter() - t0
            ev = evaluate(run, cap, refine=True, refine_iters=args.refine_iters)
            m = run.metrics
            rows.append(
                {
                    "preset": name,
                    "seed": seed,
                    "test_psnr": ev["test"].psnr,
                    "test_ssim": ev["test"].ssim,
                    "test_refined_psnr": ev["test_refined"].psnr,
                    "test_refined_ssim": ev["test_refined"].ssim,
                    "steps": m.steps,
                    "train_seconds": m.train_seconds,
                    "wall_seconds": wall,
                    "pose_source": m.prepare.pose_source,
                    "poses_held": m.anchored_mid_poses,
                    "gaussians": run.num_gaussians,
                    "train_frames": len(cap.frames),
                    "test_views": len(cap.test_views),
                }
            )
            r = rows[-1]
            print(
                f"seed {seed} {name:8s} novel PSNR {r['test_psnr']:6.2f} dB, refined {r['test_refined_psnr']:6.2f} dB "
                f"(SSIM {r['test_refined_ssim']:.3f}), {r['steps']} steps in {r['train_seconds']:.0f} s, "
                f"{r['gaussians']} Gaussians, poses {'held' if r['poses_held'] else 'optimised'}",
                flush=True,
            )
    print(
        f"\nslider_depth, {len(cap.frames)} training frames, {len(cap.test_views)} test views, {seconds:g} s per run, "
        f"seeds {seeds}; mean ± std over seeds"
    )
    print("| preset | novel PSNR dB | refined | refined SSIM | steps |")
    print("|---|---|---|---|---|")
    summary = {}
    for name in presets:
        rs = [r for r in rows if r["preset"] == name]
        summary[name] = {
            k: (float(np.mean([r[k] for r in rs])), float(np.std([r[k] for r in rs])))
            for k in ("test_psnr", "test_refined_psnr", "test_refined_ssim", "steps")
        }
        s = summary[name]
        print(
            f"| `{name}` | {s['test_psnr'][0]:.2f} ± {s['test_psnr'][1]:.2f} | {s['test_refined_psnr'][0]:.2f} ± "
            f"{s['test_refined_psnr'][1]:.2f} | {s['test_refined_ssim'][0]:.3f} ± {s['test_refined_ssim'][1]:.3f} | "
            f"{s['steps'][0]:.0f} |"
        )
    path = write_json(
        args.name,
        {
            "data": str(data),
            "seconds": seconds,
            "iters": args.iters,
            "seeds": seeds,
            "refine_iters": args.refine_iters,
            "rows": rows,
            "summary": summary,
            "argv": sys.argv[1:],
        },
    )
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
