"""PSNR against wall time for each preset, and what each "skip" rule saves.

    python benchmarks/time_vs_error.py [--quick] [--seconds S] [--out bench_out/time_vs_error.json]

Part 1: every preset on the grey synthetic scene (``small``; ``tiny`` with --quick), with the
test-view PSNR sampled during training; printed as a table and plotted (PNG beside the JSON).
Part 2: the skip rules, each measured as a ratio against the same run without the rule, at
the same step count, on a capture where half of the frames are sharp:
  - adaptive V (sharp frames render once, no trajectory) vs V = n for every frame;
  - grey stays one channel vs the same grey scene rendered as three channels;
  - no events: L_ev and L_EDI (and their EDI pre-pass) skipped vs computed;
  - plateau stop vs running every step.
"""
from __future__ import annotations

import os

# before torch is imported: torch's spinning OpenMP threads slow the numba kernels (see ebad/cli)
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse
import copy
import json
import sys
import time
from pathlib import Path

# benchmarks/edi.py would shadow the edi package when this file runs as a script
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]

import numpy as np
import torch

PRESETS = ["3dgs", "bad", "edi-3dgs", "ebad", "oracle"]


def _cfg(name, iters, seconds=None, eval_every=0):
    from ebad.config import preset

    cfg = preset(name)
    cfg.train.iters = iters
    cfg.train.max_seconds = seconds
    cfg.train.progress = False
    cfg.train.eval_every = eval_every
    return cfg


def _timed(cap, cfg):
    from ebad.trainer import reconstruct

    t0 = time.perf_counter()
    run = reconstruct(cap, cfg)
    return run, time.perf_counter() - t0


def curves(scene, iters, seconds, eval_every) -> dict:
    from ebad.evaluate import oracle_capture

    out = {}
    for name in PRESETS:
        cap = oracle_capture(scene) if name == "oracle" else scene.capture
        run, wall = _timed(cap, _cfg(name, iters, seconds, eval_every))
        pts = [(0.0, run.metrics["test_initial"]["psnr"])] + [(h["time"], h["test_psnr"]) for h in run.history if "test_psnr" in h]
        out[name] = {"time": [p[0] for p in pts], "psnr": [p[1] for p in pts], "final_psnr": run.metrics["test"]["psnr"],
                     "steps": run.metrics["steps"], "train_seconds": run.metrics["train_seconds"]}
        print(f"{name:9s} final test PSNR {out[name]['final_psnr']:6.2f} dB after {out[name]['steps']} steps, "
              f"{out[name]['train_seconds']:.1f} s", flush=True)
    return out


def skip_rules(size: str, iters: int) -> dict:
    import scenes

    from edi import EventStream

    sc = scenes.make_scene("boxes", size=size, seed=3, sharp_fraction=0.5)
    res = {}

    # adaptive V
    on = _cfg("ebad", iters)
    off = _cfg("ebad", iters)
    off.trajectory.adaptive_views = False
    r_on, t_on = _timed(sc.capture, on)
    r_off, t_off = _timed(sc.capture, off)
    res["adaptive_views"] = {"seconds_with": r_on.metrics["train_seconds"], "seconds_without": r_off.metrics["train_seconds"],
                             "renders_per_pass_with": r_on.metrics["renders_per_pass"],
                             "renders_per_pass_without": r_off.metrics["renders_per_pass"],
                             "psnr_with": r_on.metrics["test"]["psnr"], "psnr_without": r_off.metrics["test"]["psnr"]}

    # grey as one channel vs three identical channels
    grey = _cfg("3dgs", iters)
    r1, _ = _timed(sc.capture, grey)
    cap3 = copy.copy(sc.capture)
    cap3.frames = np.repeat(sc.capture.frames, 3, -1)
    cap3.test_views = [copy.copy(v) for v in sc.capture.test_views]
    for v in cap3.test_views:
        v.image = np.repeat(v.image, 3, -1)
    r3, _ = _timed(cap3, _cfg("3dgs", iters))
    res["grey_one_channel"] = {"seconds_with": r1.metrics["train_seconds"], "seconds_without": r3.metrics["train_seconds"],
                               "psnr_with": r1.metrics["test"]["psnr"], "psnr_without": r3.metrics["test"]["psnr"]}

    # no events: the event losses and the EDI pre-pass are skipped
    cap0 = copy.copy(sc.capture)
    cap0.events = EventStream.empty(sc.capture.width, sc.capture.height)
    cfg_e = _cfg("ebad", iters)
    cfg_e.trajectory.adaptive_views = False
    r_e, w_e = _timed(sc.capture, cfg_e)
    cfg_0 = _cfg("ebad", iters)
    cfg_0.trajectory.adaptive_views = False
    r_0, w_0 = _timed(cap0, cfg_0)
    res["no_events_skip_losses"] = {"seconds_with": r_0.metrics["train_seconds"] + r_0.metrics["prepare_seconds"],
                                    "seconds_without": r_e.metrics["train_seconds"] + r_e.metrics["prepare_seconds"],
                                    "note": "with = capture without events (losses skipped); without = the losses computed"}

    # plateau stop
    long_iters = iters * 3
    p_on = _cfg("3dgs", long_iters)
    p_on.train.plateau_patience = 2
    p_on.train.plateau_every = 50
    p_on.train.plateau_tol = 0.01
    rp, _ = _timed(sc.capture, p_on)
    rf, _ = _timed(sc.capture, _cfg("3dgs", long_iters))
    res["plateau_stop"] = {"seconds_with": rp.metrics["train_seconds"], "seconds_without": rf.metrics["train_seconds"],
                           "steps_with": rp.metrics["steps"], "steps_without": rf.metrics["steps"],
                           "psnr_with": rp.metrics["test"]["psnr"], "psnr_without": rf.metrics["test"]["psnr"]}
    for k, v in res.items():
        v["time_ratio_without_over_with"] = v["seconds_without"] / max(v["seconds_with"], 1e-9)
    return res


def plot(curves_: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, c in curves_.items():
        ax.plot(c["time"], c["psnr"], "-o", ms=3, label=name)
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("novel-view PSNR (dB)")
    ax.set_title("PSNR against wall time")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seconds", type=float, default=None, help="budget per preset (default 120; quick 20)")
    ap.add_argument("--iters", type=int, default=None, help="step cap (default 1500; quick 300)")
    ap.add_argument("--skip-iters", type=int, default=None, help="steps of each skip-rule run (default 300; quick 60)")
    ap.add_argument("--out", default="bench_out/time_vs_error.json")
    args = ap.parse_args(argv)
    import scenes

    import importlib.util

    spec = importlib.util.spec_from_file_location("_ebad_ablation", _HERE / "ablation.py")
    ablation = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ablation)
    warm_up = ablation.warm_up

    size = "tiny" if args.quick else "small"
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 120.0)
    iters = args.iters if args.iters is not None else (300 if args.quick else 1500)
    skip_iters = args.skip_iters if args.skip_iters is not None else (60 if args.quick else 300)
    torch.manual_seed(0)
    warm_up()
    sc = scenes.make_scene("boxes", size=size, seed=0)
    cur = curves(sc, iters, seconds, eval_every=max(10, iters // 15))
    print("\n| preset | final novel PSNR | steps | seconds |\n|---|---|---|---|")
    for name, c in cur.items():
        print(f"| {name} | {c['final_psnr']:.2f} | {c['steps']} | {c['train_seconds']:.1f} |")
    skips = skip_rules(size, skip_iters)
    print("\n| skip rule | seconds with | seconds without | without/with | notes |\n|---|---|---|---|---|")
    for k, v in skips.items():
        notes = {kk: (round(vv, 2) if isinstance(vv, float) else vv) for kk, vv in v.items()
                 if kk not in ("seconds_with", "seconds_without", "time_ratio_without_over_with")}
        print(f"| {k} | {v['seconds_with']:.2f} | {v['seconds_without']:.2f} | {v['time_ratio_without_over_with']:.2f} | {notes} |")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    png = out.with_suffix(".png")
    plot(cur, png)
    out.write_text(json.dumps({"size": size, "seconds": seconds, "iters": iters, "curves": cur, "skip_rules": skips},
                              indent=2) + "\n")
    print(f"\nwrote {out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
