"""Time to quality at the sensor's own size: test PSNR against wall time and against steps.

    python -m benchmarks.time_to_quality [--quick] [--size davis] [--modes ideal,realistic]
                                         [--presets ebad,bad,3dgs] [--seconds 300] [--marks 8]

For each sensor mode (``ideal``: linear sensor, exact poses, held; ``realistic``: the realistic
sensor with SfM-like noisy given poses, optimised) and preset, one run with a wall-time budget;
the training state is snapshotted at ``--marks`` instants spread over the budget (copying the
parameters costs milliseconds and is inside the measured time), and every snapshot is scored
afterwards with the evaluation protocol (``ebad.evaluate``: test poses refined against their
images where the capture's poses are not exact; deblurred frames against the truth). Prints a
table, writes JSON and a plot (PSNR against seconds and against steps). Also records the start-up
(prepare) time, the mean step time, the Gaussian count and the process's peak resident memory. Timings are noisy on a shared machine: compare within one
run.
"""
from __future__ import annotations

import argparse
import copy
import sys
import time

import numpy as np

from ._common import RESULTS, seed_all, write_json

MODES = {"ideal": {"sensor": "ideal", "poses": "exact"}, "realistic": {"sensor": "realistic", "poses": "noisy"}}


class Snapshots:
    """A ``Callback`` keeping copies of the scene at given training times."""

    def __init__(self, marks: list[float]):
        self.marks = list(marks)
        self.taken: list[dict] = []

    def on_step(self, state, stats) -> None:
        if self.marks and state.elapsed >= self.marks[0]:
            self.marks.pop(0)
            self.take(state)

    def take(self, state) -> None:
        self.taken.append({"seconds": state.elapsed, "step": state.step,
                           "params": {k: v.detach().clone() for k, v in state.params.items()},
                           "trajectories": copy.deepcopy(state.trajectories),
                           "response": copy.deepcopy(state.response), "gaussians": state.num_gaussians})

    def on_end(self, state, reason: str) -> None:
        if not self.taken or self.taken[-1]["step"] != state.step:
            self.take(state)


def run_one(scene, name: str, seconds: float, marks: int, exact: bool, refine_iters: int) -> dict:
    from ebad.config import preset
    from ebad.evaluate import evaluate
    from ebad.trainer import reconstruct

    cfg = preset(name)
    cfg.train.iters = 1_000_000
    cfg.train.max_seconds = seconds
    cfg.train.progress = False
    cfg.train.eval_every = 0
    snaps = Snapshots([seconds * (k + 1) / marks for k in range(marks - 1)])
    t0 = time.perf_counter()
    run = reconstruct(scene.capture, cfg, callbacks=[snaps])
    wall = time.perf_counter() - t0
    points = []
    for snap in snaps.taken:
        r = copy.copy(run)
        r.params, r.trajectories, r.response = snap["params"], snap["trajectories"], snap["response"]
        ev = evaluate(r, scene.capture, refine=not exact, gt_frames=scene.gt_frames, refine_iters=refine_iters)
        test = ev["test" if exact else "test_refined"]
        points.append({"seconds": snap["seconds"], "step": snap["step"], "gaussians": snap["gaussians"],
                       "test_psnr": test.psnr, "test_ssim": test.ssim, "deblur_psnr": ev["deblurred"].psnr})
    m = run.metrics
    import resource

    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB; the process's peak so far
    return {"preset": name, "peak_rss_mb_so_far": peak_mb, "gaussians": m.gaussians, "steps": m.steps, "train_seconds": m.train_seconds, "prepare_seconds": m.prepare_seconds,
            "wall_seconds": wall, "step_ms": 1000 * m.train_seconds / max(m.steps, 1), "points": points,
            "final_psnr": points[-1]["test_psnr"], "poses_refined": not exact}


def plot(results: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    modes = list(results)
    fig, axes = plt.subplots(len(modes), 2, figsize=(10, 3.6 * len(modes)), squeeze=False)
    for row, mode in enumerate(modes):
        for r in results[mode]:
            xs = [p["seconds"] for p in r["points"]]
            ys = [p["test_psnr"] for p in r["points"]]
            axes[row, 0].plot(xs, ys, marker="o", label=r["preset"])
            axes[row, 1].plot([p["step"] for p in r["points"]], ys, marker="o", label=r["preset"])
        axes[row, 0].set(xlabel="training seconds", ylabel="test PSNR dB", title=f"{mode}: PSNR against time")
        axes[row, 1].set(xlabel="steps", ylabel="test PSNR dB", title=f"{mode}: PSNR against steps")
        for ax in axes[row]:
            ax.grid(alpha=0.3)
            ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny scene, 20 s per run")
    ap.add_argument("--size", default=None, help="scene size (default davis; quick tiny)")
    ap.add_argument("--modes", default="ideal,realistic")
    ap.add_argument("--presets", default="ebad,bad,3dgs")
    ap.add_argument("--seconds", type=float, default=None, help="training budget per run (default 300; quick 20)")
    ap.add_argument("--marks", type=int, default=8, help="snapshots per run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--refine-iters", type=int, default=200)
    ap.add_argument("--name", default="time_to_quality", help="results file benchmarks/results/NAME.json (+ .png)")
    args = ap.parse_args(argv)
    import scenes

    size = args.size or ("tiny" if args.quick else "davis")
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 300.0)
    seed_all(args.seed)
    results: dict[str, list[dict]] = {}
    for mode in [m for m in args.modes.split(",") if m]:
        scene = scenes.make_scene("boxes", size, seed=args.seed, **MODES[mode])
        results[mode] = []
        for name in [p for p in args.presets.split(",") if p]:
            r = run_one(scene, name, seconds, args.marks, MODES[mode]["poses"] == "exact", args.refine_iters)
            results[mode].append(r)
            pts = "  ".join(f"{p['seconds']:.0f}s/{p['step']}:{p['test_psnr']:.2f}" for p in r["points"])
            print(f"{mode:9s} {name:5s} prepare {r['prepare_seconds']:.1f} s, {r['step_ms']:.0f} ms/step, "
                  f"{r['steps']} steps, {r['gaussians']} Gaussians, peak RSS so far {r['peak_rss_mb_so_far']:.0f} MB "
                  f"-> {r['final_psnr']:.2f} dB   [{pts}]", flush=True)
    path = write_json(args.name, {"size": size, "seconds": seconds, "seed": args.seed, "modes": MODES,
                                  "results": results, "argv": sys.argv[1:]})
    plot(results, RESULTS / f"{args.name}.png")
    print(f"wrote {path} and {RESULTS / (args.name + '.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
