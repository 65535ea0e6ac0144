"""Ablation: every preset on synthetic scenes at an equal budget.

    python benchmarks/ablation.py [--quick] [--seconds S] [--iters N] [--out bench_out/ablation.json]

Scenes (``small`` 160x120 unless --quick): grey with shake 1 (the issue's target scene,
c = 0.2), grey with shake 2 (stronger blur), grey with 5 Hz/pixel noise events, colour.
Each preset gets the same wall-time budget (``--seconds``) and step cap (``--iters``);
``oracle`` trains on the sharp mid-exposure ground truth with trusted poses (the ceiling).
Reports PSNR / SSIM on held-out novel views and on the deblurred training frames, wall time,
steps and Gaussians; prints a table and writes JSON. Timings are noisy on a shared machine:
compare presets within one run.
"""
from __future__ import annotations

import os

# before torch is imported: torch's spinning OpenMP threads slow the numba kernels (see ebad/cli)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import json
import sys
import time
from pathlib import Path

# benchmarks/edi.py would shadow the edi package when this file runs as a script
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]

import numpy as np
import torch

PRESET_ORDER = ["3dgs", "bad", "edi-3dgs", "ebad", "oracle"]


def scene_specs(quick: bool) -> list[dict]:
    if quick:
        return [{"label": "tiny grey shake1", "size": "tiny", "rgb": False, "shake": 1.0, "noise_hz": 0.0}]
    return [
        {"label": "small grey shake1", "size": "small", "rgb": False, "shake": 1.0, "noise_hz": 0.0},
        {"label": "small grey shake2", "size": "small", "rgb": False, "shake": 2.0, "noise_hz": 0.0},
        {"label": "small grey noise5", "size": "small", "rgb": False, "shake": 1.0, "noise_hz": 5.0},
        {"label": "small rgb shake1", "size": "small", "rgb": True, "shake": 1.0, "noise_hz": 0.0},
    ]


def run_preset(scene, name: str, iters: int, seconds: float | None, seed: int = 0) -> dict:
    from ebad.config import preset
    from ebad.evaluate import oracle_capture
    from ebad.metrics import psnr, ssim
    from ebad.trainer import reconstruct

    cfg = preset(name)
    cfg.train.iters = iters
    cfg.train.max_seconds = seconds
    cfg.train.progress = False
    cfg.train.eval_every = 0
    cfg.train.seed = seed
    cap = oracle_capture(scene) if name == "oracle" else scene.capture
    t0 = time.perf_counter()
    run = reconstruct(cap, cfg)
    wall = time.perf_counter() - t0
    db = run.deblurred_frames()
    return {
        "preset": name, "test_psnr": run.metrics["test"]["psnr"], "test_ssim": run.metrics["test"]["ssim"],
        "deblur_psnr": float(np.mean([psnr(a, b) for a, b in zip(db, scene.gt_frames)])),
        "deblur_ssim": float(np.mean([ssim(a, b) for a, b in zip(db, scene.gt_frames)])),
        "train_seconds": run.metrics["train_seconds"], "wall_seconds": wall, "steps": run.metrics["steps"],
        "gaussians": run.num_gaussians, "c": run.metrics.get("c"), "c_final": run.metrics.get("c_final"),
        "stop_reason": run.metrics["stop_reason"],
    }


def warm_up() -> None:
    """Compile the numba kernels once so that no preset pays for it."""
    import scenes
    from ebad.config import preset
    from ebad.trainer import reconstruct

    sc = scenes.make_scene("boxes", size="tiny", n_frames=3, n_test=1)
    cfg = preset("ebad")
    cfg.train.iters = 3
    cfg.train.progress = False
    reconstruct(sc.capture, cfg)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one tiny scene, short budget")
    ap.add_argument("--seconds", type=float, default=None, help="wall-time budget per preset (default 120; quick 20)")
    ap.add_argument("--iters", type=int, default=None, help="step cap per preset (default 1500; quick 300)")
    ap.add_argument("--presets", default=",".join(PRESET_ORDER), help="comma-separated presets")
    ap.add_argument("--scenes", default=None, help="comma-separated scene labels to keep (default all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="bench_out/ablation.json")
    args = ap.parse_args(argv)
    import scenes

    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 120.0)
    iters = args.iters if args.iters is not None else (300 if args.quick else 1500)
    presets = [p for p in args.presets.split(",") if p]
    specs = scene_specs(args.quick)
    if args.scenes:
        keep = set(args.scenes.split(","))
        specs = [s for s in specs if s["label"] in keep]
    torch.manual_seed(args.seed)
    warm_up()
    rows = []
    for spec in specs:
        sc = scenes.make_scene("boxes", size=spec["size"], seed=args.seed, rgb=spec["rgb"], shake=spec["shake"],
                               noise_hz=spec["noise_hz"])
        from ebad.metrics import psnr
        blurry = float(np.mean([psnr(a, b) for a, b in zip(sc.capture.frames, sc.gt_frames)]))
        for name in presets:
            r = run_preset(sc, name, iters, seconds, args.seed)
            r.update({"scene": spec["label"], "blurry_psnr": blurry})
            rows.append(r)
            print(f"{spec['label']:20s} {name:9s} test {r['test_psnr']:6.2f} dB / {r['test_ssim']:.3f}  "
                  f"deblurred {r['deblur_psnr']:6.2f} dB / {r['deblur_ssim']:.3f}  {r['steps']:5d} steps "
                  f"{r['train_seconds']:6.1f} s  N={r['gaussians']}", flush=True)
    print()
    hdr = f"| scene | preset | novel PSNR | novel SSIM | deblurred PSNR | deblurred SSIM | blurry PSNR | steps | seconds | Gaussians |"
    print(hdr)
    print("|" + "---|" * 10)
    for r in rows:
        print(f"| {r['scene']} | {r['preset']} | {r['test_psnr']:.2f} | {r['test_ssim']:.3f} | {r['deblur_psnr']:.2f} | "
              f"{r['deblur_ssim']:.3f} | {r['blurry_psnr']:.2f} | {r['steps']} | {r['train_seconds']:.1f} | {r['gaussians']} |")
    checks = {}
    for label in sorted({r["scene"] for r in rows}):
        by = {r["preset"]: r["test_psnr"] for r in rows if r["scene"] == label}
        if {"ebad", "3dgs", "bad", "oracle", "edi-3dgs"} <= set(by):
            checks[label] = {
                "ebad_minus_3dgs": by["ebad"] - by["3dgs"], "ebad_minus_bad": by["ebad"] - by["bad"],
                "oracle_minus_ebad": by["oracle"] - by["ebad"],
                "order_3dgs<bad<edi-3dgs<ebad": bool(by["3dgs"] < by["bad"] < by["edi-3dgs"] < by["ebad"]),
            }
            c = checks[label]
            print(f"{label}: ebad - 3dgs {c['ebad_minus_3dgs']:+.2f} dB (target >= 4), ebad - bad "
                  f"{c['ebad_minus_bad']:+.2f} dB (target >= 1.5), oracle - ebad {c['oracle_minus_ebad']:+.2f} dB "
                  f"(target <= 1.5), order 3dgs<bad<edi-3dgs<ebad: {c['order_3dgs<bad<edi-3dgs<ebad']}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"seconds": seconds, "iters": iters, "rows": rows, "checks": checks,
                               "argv": sys.argv[1:]}, indent=2) + "\n")
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
