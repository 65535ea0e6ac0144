"""Time to quality at the sensor's own size: test PSNR against wall time and against steps.

    python -m benchmarks.time_to_quality [--quick] [--size davis] [--modes ideal,realistic]
                                         [--presets ebad,bad,3dgs] [--seconds 300] [--marks 8]
                                         [--baseline CHECKOUT [--baseline-steps 1500]]
                                         [--baseline-file FILE]

For each sensor mode (``ideal``: linear sensor, exact poses, held; ``realistic``: the realistic
sensor with SfM-like noisy given poses, optimised) and preset, one run with a wall-time budget;
the training state is snapshotted at ``--marks`` instants spread over the budget (copying the
parameters costs milliseconds and is inside the measured time), and every snapshot is scored
afterwards with the evaluation protocol (``ebad.evaluate``: test poses refined against their
images where the capture's poses are not exact; deblurred frames against the truth). Prints a
table, writes JSON and a plot (PSNR against seconds and against steps). Also records the start-up
(prepare) time, the mean step time, the Gaussian count, the process's peak resident memory and
the mean profile of the full-resolution steps (``ebad.loop.step_profile``: the rasteriser
against everything else). Timings are noisy on a shared machine: compare within one
run.

``--baseline CHECKOUT`` also trains the ``ebad`` preset of another checkout of the project (the
code before the speed work, e.g. a ``git worktree`` at an older commit) for ``--baseline-steps``
steps on the same capture, in a subprocess whose ``PYTHONPATH`` is that checkout, its
snapshots taken every ``--baseline-steps / marks`` steps; each snapshot's Gaussians are scored
here by the same protocol as the current code's (test poses refined where the capture's poses
are not exact). Its wall and CPU seconds are recorded with the machine's load. The baseline
results are written to ``NAME_baseline.pt``; ``--baseline-file`` reuses such a file instead of
training again (its rows then come from another run of the benchmark, which the table says).
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
from pathlib import Path

from ._common import RESULTS, config_spec, peak_rss_mb, seed_all, write_json

OLD_DRIVER = r"""
import os, sys, time
import torch
import scenes, ebad.trainer as T
from ebad.config import preset

capture_dir, out, steps, every = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
holder = {}
_init = T.init_gaussians
def init_gaussians(*a, **k):
    holder["params"] = _init(*a, **k)
    return holder["params"]
T.init_gaussians = init_gaussians
snaps, t0, c0 = [], None, None
def on_step(step, stats):
    if step % every == 0 or step == steps:
        snaps.append({"step": step, "seconds": stats["time"], "cpu_seconds": time.process_time() - c0,
                      "gaussians": stats["n"], "load1": os.getloadavg()[0],
                      "params": {k: v.detach().clone() for k, v in holder["params"].items()}})
cfg = preset("ebad")
cfg.train.iters, cfg.train.progress, cfg.train.eval_every = steps, False, 0
capture = scenes.load(capture_dir)
c0 = time.process_time()
t0 = time.perf_counter()
run = T.reconstruct(capture, cfg, on_step=on_step)
wall = time.perf_counter() - t0
m = run.metrics
torch.save({"snaps": snaps, "wall_seconds": wall, "steps": m["steps"], "stop_reason": m["stop_reason"],
            "train_seconds": m["train_seconds"], "prepare_seconds": m["prepare_seconds"],
            "own_test_psnr": (m.get("test") or {}).get("psnr"),
            # VmHWM, this process's own peak (ru_maxrss is carried over exec: it would be the parent's)
            "peak_rss_mb": int(next(ln for ln in open("/proc/self/status") if ln.startswith("VmHWM")).split()[1])
            / 1024}, out)
"""


MODES = {"ideal": {"sensor": "ideal", "poses": "exact"}, "realistic": {"sensor": "realistic", "poses": "noisy"}}


def parse_modes(ap: argparse.ArgumentParser, text: str) -> list[str]:
    """The comma-separated ``--modes``, each a key of ``MODES`` (else the parser's one-line error)."""
    modes = [m for m in text.split(",") if m]
    for m in modes:
        if m not in MODES:
            ap.error(f"--modes: unknown mode {m!r} (choose from {', '.join(MODES)})")
    return modes


class Snapshots:
    """A ``Callback`` keeping copies of the scene at given training times."""

    def __init__(self, marks: list[float]):
        self.marks = list(marks)
        self.taken: list[dict] = []
        self.cpu0 = time.process_time()  # CPU seconds are counted from here (prepare included)

    def on_step(self, state, stats) -> None:
        if self.marks and state.elapsed >= self.marks[0]:
            self.marks.pop(0)
            self.take(state)

    def take(self, state) -> None:
        self.taken.append(
            {
                "seconds": state.elapsed,
                "step": state.step,
                "cpu_seconds": time.process_time() - self.cpu0,
                "load1": os.getloadavg()[0],
                "params": {k: v.detach().clone() for k, v in state.params.items()},
                "trajectories": copy.deepcopy(state.trajectories),
                "response": copy.deepcopy(state.response),
                "gaussians": state.num_gaussians,
            }
        )

    def on_end(self, state, reason: str) -> None:
        if not self.taken or self.taken[-1]["step"] != state.step:
            self.take(state)


PLATEAU_PATIENCES = (2, 3, 5)


def plateau_points(history, cfg, points: list[dict]) -> list[dict]:
    """Where the plateau rule (``ebad.loop.should_stop``, ``train.plateau_every`` and
    ``plateau_tol`` of ``cfg``) would have stopped this run for each patience in
    ``PLATEAU_PATIENCES``, replayed over its loss history, and the test PSNR of the last
    snapshot at or before that step (None: the rule never fired within the run)."""
    from ebad.loop import should_stop

    out = []
    for patience in PLATEAU_PATIENCES:
        c = copy.deepcopy(cfg)
        c.train.plateau_patience, c.train.max_seconds = patience, None
        hit = next((h for i, h in enumerate(history) if should_stop(history[: i + 1], 0.0, c) == "plateau"), None)
        before = [p for p in points if hit is not None and p["step"] <= hit.step]
        out.append(
            {
                "patience": patience,
                "step": None if hit is None else hit.step,
                "seconds": None if hit is None else hit.time,
                "psnr_at_last_snapshot_before": before[-1]["test_psnr"] if before else None,
            }
        )
    return out


def run_one(scene, name: str, seconds: float, marks: int, exact: bool, refine_iters: int) -> dict:
    from ebad.evaluate import evaluate
    from ebad.loop import step_profile
    from ebad.run import reconstruct

    cfg = config_spec(name)
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
        points.append(
            {
                "seconds": snap["seconds"],
                "step": snap["step"],
                "gaussians": snap["gaussians"],
                "cpu_seconds": snap["cpu_seconds"],
                "load1": snap["load1"],
                "test_psnr": test.psnr,
                "test_ssim": test.ssim,
                "deblur_psnr": ev["deblurred"].psnr,
            }
        )
    m = run.metrics
    peak_mb = peak_rss_mb()  # this process's peak so far
    return {
        "preset": name,
        "peak_rss_mb_so_far": peak_mb,
        "gaussians": m.gaussians,
        "steps": m.steps,
        "train_seconds": m.train_seconds,
        "prepare_seconds": m.prepare_seconds,
        "wall_seconds": wall,
        "step_ms": 1000 * m.train_seconds / max(m.steps, 1),
        "points": points,
        "cpu_seconds": points[-1]["cpu_seconds"],
        "final_psnr": points[-1]["test_psnr"],
        "plateau": plateau_points(run.history, cfg, points),
        "profile": step_profile([h for h in run.history if h.width == run.width]),  # full-resolution steps
        "poses_refined": not exact,
    }, run


def run_baseline(scene, checkout: str, steps: int, marks: int) -> dict:
    """Train the ``ebad`` preset of ``checkout`` on ``scene.capture`` in a subprocess; its snapshots."""
    import subprocess
    import tempfile

    import torch

    import scenes

    with tempfile.TemporaryDirectory() as tmp:
        scenes.save(scene.capture, f"{tmp}/capture")
        (driver := Path(tmp) / "driver.py").write_text(OLD_DRIVER)
        env = dict(os.environ, PYTHONPATH=str(Path(checkout).resolve()), OMP_WAIT_POLICY="PASSIVE")
        commit = subprocess.run(
            ["git", "-C", checkout, "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        ).stdout.strip()
        subprocess.run(
            [sys.executable, str(driver), f"{tmp}/capture", f"{tmp}/out.pt", str(steps), str(max(steps // marks, 1))],
            check=True,
            env=env,
            cwd=tmp,
        )
        out = torch.load(f"{tmp}/out.pt", weights_only=False)
    out["checkout"], out["commit"] = str(checkout), commit
    return out


def score_baseline(run, base: dict, scene, exact: bool, refine_iters: int) -> dict:
    """Score the baseline's snapshots with this code's protocol, on this run's test poses.

    Only the Gaussians are taken from the baseline: the baseline held the capture's poses, so its
    test views are rendered at the capture's test poses (refined when they are not exact), like
    this code's runs. Its deblurred frames are not scored (they need its trajectories)."""
    from ebad.evaluate import evaluate
    from ebad.response import Response

    points = []
    for snap in base["snaps"]:
        r = copy.copy(run)
        r.params, r.response = snap.pop("params"), Response()
        ev = evaluate(r, scene.capture, refine=not exact, refine_iters=refine_iters)
        test = ev["test" if exact else "test_refined"]
        points.append({**snap, "test_psnr": test.psnr, "test_ssim": test.ssim})
    return {
        "preset": f"ebad@{base['commit']}",
        "baseline": True,
        "checkout": base["checkout"],
        "commit": base["commit"],
        "steps": base["steps"],
        "stop_reason": base["stop_reason"],
        "train_seconds": base["train_seconds"],
        "prepare_seconds": base["prepare_seconds"],
        "wall_seconds": base["wall_seconds"],
        "cpu_seconds": points[-1]["cpu_seconds"] if points else None,
        "step_ms": 1000 * base["train_seconds"] / max(base["steps"], 1),
        "gaussians": points[-1]["gaussians"],
        "peak_rss_mb": base["peak_rss_mb"],
        "own_test_psnr": base["own_test_psnr"],
        "points": points,
        "final_psnr": points[-1]["test_psnr"],
        "poses_refined": not exact,
    }


def time_to_baseline(rows: list[dict], margin: float = 0.5) -> dict:
    """The issue's target: the first snapshot of each run within ``margin`` dB of the baseline's
    final PSNR, and its time as a fraction of the baseline's (wall and CPU seconds)."""
    base = next(r for r in rows if r.get("baseline"))
    out = {
        "baseline_psnr": base["final_psnr"],
        "baseline_seconds": base["train_seconds"],
        "baseline_cpu_seconds": base["cpu_seconds"],
        "margin_db": margin,
        "presets": {},
    }
    for r in rows:
        if r.get("baseline"):
            continue
        hit = next((p for p in r["points"] if p["test_psnr"] >= base["final_psnr"] - margin), None)
        out["presets"][r["preset"]] = {
            "seconds": None if hit is None else hit["seconds"],
            "step": None if hit is None else hit["step"],
            "psnr": None if hit is None else hit["test_psnr"],
            "wall_ratio": None if hit is None else hit["seconds"] / base["train_seconds"],
            "cpu_ratio": None if hit is None else hit["cpu_seconds"] / base["cpu_seconds"],
        }
    return out


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
    ap.add_argument(
        "--presets",
        default="ebad,bad,3dgs",
        help="presets, each with optional overrides: ebad+train.coarse_scale=1 (benchmarks._common.config_spec)",
    )
    ap.add_argument("--seconds", type=float, default=None, help="training budget per run (default 300; quick 20)")
    ap.add_argument("--marks", type=int, default=8, help="snapshots per run")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--refine-iters", type=int, default=200)
    ap.add_argument("--name", default="time_to_quality", help="results file benchmarks/results/NAME.json (+ .png)")
    ap.add_argument("--baseline", default=None, help="another checkout of the project whose ebad preset to train too")
    ap.add_argument("--baseline-steps", type=int, default=1500)
    ap.add_argument("--baseline-only", action="store_true", help="train the baseline, save NAME_baseline.pt, stop")
    ap.add_argument("--baseline-file", default=None, help="reuse the baseline of an earlier run (NAME_baseline.pt)")
    args = ap.parse_args(argv)
    import scenes

    size = args.size or ("tiny" if args.quick else "davis")
    seconds = args.seconds if args.seconds is not None else (20.0 if args.quick else 300.0)
    seed_all(args.seed)
    presets = [p for p in args.presets.split(",") if p]
    if (args.baseline or args.baseline_file) and not any(p.split("+")[0] == "ebad" for p in presets):
        ap.error("--baseline needs the ebad preset in --presets (its run supplies the evaluation)")
    baselines = {}
    if args.baseline_file:
        import torch

        baselines = torch.load(args.baseline_file, weights_only=False)
    results: dict[str, list[dict]] = {}
    if not args.baseline_only:
        from ebad.run import warm_up

        warm_up(["grey"])  # numba compiles outside every run's budget
    for mode in parse_modes(ap, args.modes):
        scene = scenes.make_scene("boxes", size, seed=args.seed, **MODES[mode])
        exact = MODES[mode]["poses"] == "exact"
        results[mode] = []
        if args.baseline:
            t0 = time.perf_counter()
            baselines[mode] = run_baseline(scene, args.baseline, args.baseline_steps, args.marks)
            import torch

            torch.save(baselines, RESULTS / f"{args.name}_baseline.pt")
            print(
                f"{mode:9s} baseline {baselines[mode]['commit']}: {baselines[mode]['steps']} steps in "
                f"{time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        if args.baseline_only:
            continue
        for name in presets:
            r, run = run_one(scene, name, seconds, args.marks, exact, args.refine_iters)
            if name.split("+")[0] == "ebad" and mode in baselines and not any(x.get("baseline") for x in results[mode]):
                b = score_baseline(run, copy.deepcopy(baselines[mode]), scene, exact, args.refine_iters)
                b["from_earlier_run"] = not args.baseline
                results[mode].append(b)
                pts = "  ".join(f"{p['seconds']:.0f}s/{p['step']}:{p['test_psnr']:.2f}" for p in b["points"])
                print(
                    f"{mode:9s} {b['preset']}: {b['step_ms']:.0f} ms/step, {b['steps']} steps, "
                    f"{b['train_seconds']:.0f} s ({b['cpu_seconds']:.0f} CPU s) -> {b['final_psnr']:.2f} dB   [{pts}]",
                    flush=True,
                )
            results[mode].append(r)
            pts = "  ".join(f"{p['seconds']:.0f}s/{p['step']}:{p['test_psnr']:.2f}" for p in r["points"])
            fired = ", ".join(
                f"patience {q['patience']}: "
                + ("never" if q["step"] is None else f"step {q['step']} ({q['seconds']:.0f} s)")
                for q in r["plateau"]
            )
            print(f"{mode:9s} {name:5s} plateau rule would stop at {fired}", flush=True)
            print(
                f"{mode:9s} {name:5s} prepare {r['prepare_seconds']:.1f} s, {r['step_ms']:.0f} ms/step, "
                f"{r['steps']} steps, {r['gaussians']} Gaussians, peak RSS so far {r['peak_rss_mb_so_far']:.0f} MB "
                f"-> {r['final_psnr']:.2f} dB   [{pts}]",
                flush=True,
            )
            if r["profile"]:
                p = r["profile"]
                print(
                    f"{mode:9s} {name:5s} full-resolution step {p['step']:.0f} ms: rasteriser forward "
                    f"{p['raster_forward']:.0f} + backward {p['raster_backward']:.0f}, outside it "
                    f"{100 * p['outside_share']:.0f}%",
                    flush=True,
                )
    if args.baseline_only:
        print(f"wrote {RESULTS / (args.name + '_baseline.pt')}")
        return 0
    targets = {mode: time_to_baseline(rows) for mode, rows in results.items() if any(r.get("baseline") for r in rows)}
    for mode, t in targets.items():
        for name, row in t["presets"].items():
            reach = (
                "never within the run"
                if row["seconds"] is None
                else f"at {row['seconds']:.0f} s ({row['wall_ratio']:.2f} of the baseline's wall time, "
                f"{row['cpu_ratio']:.2f} of its CPU time)"
            )
            print(f"{mode:9s} {name} reaches the baseline's {t['baseline_psnr']:.2f} dB - 0.5 {reach}")
    path = write_json(
        args.name,
        {
            "targets": targets,
            "size": size,
            "seconds": seconds,
            "seed": args.seed,
            "modes": MODES,
            "results": results,
            "argv": sys.argv[1:],
        },
    )
    plot(results, RESULTS / f"{args.name}.png")
    print(f"wrote {path} and {RESULTS / (args.name + '.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
