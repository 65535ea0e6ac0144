"""Real data: novel views on slider_depth (Event Camera Dataset, DAVIS240C) from its frames.

    python -m benchmarks.slider_depth [--quick] [--data PATH]

The capture is read with ``scenes.load`` (ECD text layout, poses interpolated to the frame
times, undistorted). Every 8th frame is held out as a test view (pose + image); the others
train. The recording's events cover only its first 0.17 s (frames 0-4), so this is the
"frames only" protocol: the ``3dgs`` preset on the (nearly sharp) frames with trusted
poses, and, for comparison, ``ebad`` on the same capture (its event losses only act where
events exist). Prints novel-view PSNR / SSIM and writes JSON.
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
    out.names = [cap.names[i] for i in train] if cap.names else [f"{i:04d}" for i in train]
    out.split = ["train"] * len(train)
    out.test_views = [TestView(name=(cap.names[i] if cap.names else f"{i:04d}"), t=float(cap.exposures[i].mean()),
                               c2w=cap.c2w[i], image=cap.frames[i]) for i in test]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="every 3rd training frame, 300 steps")
    ap.add_argument("--data", default=str(DEFAULT_DATA))
    ap.add_argument("--iters", type=int, default=None, help="steps (default 1500; quick 300)")
    ap.add_argument("--presets", default="3dgs,ebad")
    ap.add_argument("--name", default="slider_depth", help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import scenes

    from ebad.config import preset
    from ebad.trainer import reconstruct

    data = Path(args.data)
    if not data.exists():
        print(f"slider_depth not found at {data}; pass --data", file=sys.stderr)
        return 2
    cap = held_out_capture(scenes.load(data), stride=3 if args.quick else 1)
    iters = args.iters if args.iters is not None else (300 if args.quick else 1500)
    rows = []
    for name in [p for p in args.presets.split(",") if p]:
        cfg = preset(name)
        cfg.train.iters = iters
        cfg.train.progress = False
        cfg.train.eval_every = 0
        t0 = time.perf_counter()
        run = reconstruct(cap, cfg)
        m = run.metrics
        rows.append({"preset": name, "test_psnr": m.test.psnr, "test_ssim": m.test.ssim,
                     "initial_psnr": m.test_initial.psnr, "steps": m.steps, "seconds": time.perf_counter() - t0,
                     "pose_source": m.prepare.pose_source, "poses_held": m.anchored_mid_poses,
                     "gaussians": run.num_gaussians, "train_frames": len(cap.frames), "test_views": len(cap.test_views)})
        r = rows[-1]
        print(f"{name:6s} novel-view PSNR {r['test_psnr']:6.2f} dB SSIM {r['test_ssim']:.3f} (initial {r['initial_psnr']:.2f}), "
              f"{r['steps']} steps, {r['seconds']:.0f} s, {r['gaussians']} Gaussians", flush=True)
    print(f"wrote {write_json(args.name, {'data': str(data), 'iters': iters, 'rows': rows})}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
