"""Should the trainer refine the contrast threshold c? The `ebad` preset with c learnt (as
log c, through the event loss) against c fixed at `edi.estimate_c`'s value, equal budgets.

    python benchmarks/learn_contrast.py [--seconds 60] [--size small] [--out bench_out/learn_contrast.json]
"""
from __future__ import annotations

import os

# before torch is imported: torch's spinning OpenMP threads slow the numba kernels (see ebad/cli)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]  # benchmarks/edi.py shadows edi
sys.path.insert(0, str(_HERE.parent))

import numpy as np  # noqa: E402
import torch  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="time budget per run")
    ap.add_argument("--size", default="small", choices=["tiny", "small", "davis"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench_out/learn_contrast.json")
    args = ap.parse_args()

    import scenes
    from ebad import preset, reconstruct
    from ebad.metrics import psnr

    scene = scenes.make_scene("boxes", args.size, seed=args.seed)
    cap = scene.capture
    views = [v for v in cap.test_views if v.image is not None]
    rows = []
    for learn in (True, False):
        cfg = preset("ebad")
        cfg.train.iters, cfg.train.max_seconds, cfg.train.progress = 100_000, args.seconds, False
        cfg.loss.learn_contrast = learn
        torch.manual_seed(0)
        run = reconstruct(cap, cfg)
        imgs = run.render(np.stack([v.c2w for v in views]))
        deblurred = run.deblurred_frames()
        rows.append({
            "learn_contrast": learn,
            "test_psnr": float(np.mean([psnr(i, v.image) for i, v in zip(imgs, views)])),
            "deblur_psnr": float(np.mean([psnr(a, b) for a, b in zip(deblurred, scene.gt_frames)])),
            "steps": run.metrics["steps"], "c_start": run.metrics.get("c"), "c_final": run.metrics.get("c_final"),
            "c_true": cap.meta.get("c"),
        })
    print(f"| c | novel PSNR dB | deblurred PSNR dB | steps | c start -> end (true {rows[0]['c_true']}) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {'learnt' if r['learn_contrast'] else 'fixed'} | {r['test_psnr']:.2f} | {r['deblur_psnr']:.2f} | "
              f"{r['steps']} | {r['c_start']:.3f} -> {r['c_final']:.3f} |")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
