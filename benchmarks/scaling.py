"""The paper's scale (issue 31): how ebad's cost grows with the views, the events and the pixels.

    python -m benchmarks.scaling [--size davis] [--views 10,20,40] [--test-views 8] [--presets ebad,bad]
                                 [--poses noisy,sfm] [--seconds 900[,3600]] [--marks 8] [--refine-iters 200]
                                 [--refine-also 300] [--events 50e6] [--name scaling]
    python -m benchmarks.scaling --views 10 --presets ebad --poses noisy --seconds 300,300,300   # one budget's spread
    python -m benchmarks.scaling --size tiny --views 4 --seconds 20        # a check that it runs
    python -m benchmarks.scaling --views "" --events 50e6 --name scaling_events50m   # the events alone

For each number of training views, a realistic capture (``scenes.make_scene("boxes", size,
sensor="realistic")``, ``--test-views`` held-out views) is simulated once and written to disk; every
(preset, poses) pair then runs in its own subprocess, which loads the capture (``scenes.load``) and
reconstructs it under a wall-time budget of ``--seconds`` of training (several budgets, comma-separated: one
run each, the schedule following each run's own clock as a user's ``--train.max_seconds`` does; the capture
is simulated once for all): ``noisy`` trains from the
capture's noisy given poses, ``sfm`` finds them with pycolmap (``trajectory.pose_source colmap``).
Per run:

* every phase before the first step timed separately, from the lines ``ebad.progress`` and
  ``scenes.colmap`` log (loading, poses/SfM with features, matching and mapping, c estimation,
  sharpness, latents, initialisation, the initial scoring), the first step (numba's kernels loaded:
  the parent compiles them into the cache first, ``ebad.run.warm_up``) and the steps/s after it;
* test PSNR (poses refined against the images, ``ebad.evaluate``) of snapshots at ``--marks``
  instants against wall time (the prepare time included), and each test view's PSNR before and after its
  refinement with the refinement's steps (``view_scores``); with ``--refine-also``, the same snapshot refined
  again under each other step cap (``refined_at``), outside every budget;
* with several budgets, each one's final PSNR and its gain over the one before (``budget_curves``): the
  plateau is where that gain runs out; a budget given more than once is run that many times, and its runs'
  mean ± std is the spread of one setting's time-budgeted runs;
* the subprocess's peak RSS (its own ``VmHWM``: ``ru_maxrss`` would report the parent's peak, which
  Linux carries over ``exec``), its resident set at each of those lines and after loading, training
  and each evaluation (``memory_mb``), and the stored stream's bytes per event.

The parent's own peak while it simulates and writes each capture is ``simulate_peak_rss_mb``.

``--events N`` also measures one stream of N events (default 50M, 0: skip) in a subprocess: written
as an uncompressed .npz, read with ``edi.read_events`` (peak RSS, seconds, bytes per event), and
windowed per frame (30 windows: ``EventStream.window`` views and the counts per virtual window).
Writes ``benchmarks/results/NAME.json`` and a plot ``NAME.png``; the JSON is written after each run too,
marked ``partial`` until the end (as ``benchmarks.ablation`` does), so a benchmark stopped midway keeps its runs.
Timings are noisy on a shared machine: compare within one run.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import logging
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._common import RESULTS, config_spec, memory_mb, peak_rss_mb, reset_peak, write_json

if TYPE_CHECKING:
    from ebad.config import PoseSource

POSES: dict[str, PoseSource] = {"noisy": "capture", "sfm": "colmap"}  # --poses -> trajectory.pose_source
PHASE_LOGGERS = ("ebad.progress", "scenes.colmap")  # the lines a run's timeline keeps


class Timeline(logging.Handler):
    """The (seconds since ``t0``, message, resident MB, peak resident MB so far) of every line of the
    progress and SfM logs: a phase's memory is the peak at its end line against the resident set at its
    start line."""

    def __init__(self, t0: float):
        super().__init__(logging.INFO)
        self.t0 = t0
        self.lines: list[tuple[float, str, float | None, float | None]] = []

    def emit(self, record: logging.LogRecord) -> None:
        rss, hwm = memory_mb()
        self.lines.append((round(time.perf_counter() - self.t0, 3), record.getMessage(), rss, hwm))


class FirstStep:
    """A ``Callback`` noting, in seconds since ``t0``, the first step's end (``at``) and the training
    loop's start (``train_start``: ``at`` less the loop's own clock at that step, ``stats.time``)."""

    def __init__(self, t0: float):
        self.t0 = t0
        self.at: float | None = None
        self.train_start: float | None = None

    def on_step(self, state, stats) -> None:
        if self.at is None:
            self.at = time.perf_counter() - self.t0
            self.train_start = self.at - stats.time

    def on_end(self, state, reason: str) -> None:
        return None


def view_scores(res: dict) -> dict[str, dict[str, float | int | None]]:
    """Each test view's PSNR before and after its pose refinement and the refinement's steps, from an
    ``ebad.evaluate`` result: a mark's mean can move by one view whose refinement stopped short."""
    before = res["test"].per_view if "test" in res else {}
    after = res["test_refined"].per_view if "test_refined" in res else {}
    steps = res.get("refine_steps", {})
    return {
        name: {
            "psnr": before[name]["psnr"] if name in before else None,
            "psnr_refined": after[name]["psnr"] if name in after else None,
            "refine_steps": steps.get(name),
        }
        for name in dict.fromkeys([*before, *after])
    }


@contextlib.contextmanager
def _phase_timeline(t0: float) -> Iterator[Timeline]:
    """A ``Timeline`` on the ``PHASE_LOGGERS`` at INFO, taken off and their levels restored at the end, a failed run's
    too: ``run_child`` runs in-process in tests, where a timeline left on ``ebad.progress`` takes every later phase
    line from stderr."""
    timeline = Timeline(t0)
    loggers = [logging.getLogger(name) for name in PHASE_LOGGERS]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.INFO)
        lg.addHandler(timeline)
    try:
        yield timeline
    finally:
        for lg, level in zip(loggers, levels):
            lg.removeHandler(timeline)
            lg.setLevel(level)


def _refined_psnr(res: dict) -> float | None:
    return res["test_refined"].psnr if "test_refined" in res else None


def run_child(spec: dict) -> dict:
    """One reconstruction of a written capture; what the module docstring lists."""
    import scenes
    from ebad.evaluate import evaluate
    from ebad.run import reconstruct

    from .time_to_quality import Snapshots

    t0 = time.perf_counter()
    with _phase_timeline(t0) as timeline:
        memory = {"start": memory_mb()}  # (resident, peak so far) MB at the run's milestones
        capture = scenes.load(spec["capture"])
        load_s = time.perf_counter() - t0
        memory["loaded"] = memory_mb()
        ev = capture.events
        cfg = config_spec(spec["preset"])
        cfg.train.iters, cfg.train.max_seconds = 1_000_000, float(spec["seconds"])
        cfg.train.progress, cfg.train.eval_every = False, 0
        cfg.trajectory.pose_source = POSES[spec["poses"]]
        marks = int(spec["marks"])
        snaps = Snapshots([spec["seconds"] * (k + 1) / marks for k in range(marks - 1)])
        first = FirstStep(t0)
        run = reconstruct(capture, cfg, callbacks=[first, snaps])
        wall = time.perf_counter() - t0
        memory["trained"] = memory_mb()
        m = run.metrics
        assert m is not None  # reconstruct sets it
        # loading, prepare, initialisation, the initial scoring: up to the loop's start (not the wall less the
        # training seconds: reconstruct's work after the loop would count as before it)
        before_train = first.train_start if first.train_start is not None else wall - m.train_seconds
        points = []
        for snap in snaps.taken:
            r = copy.copy(run)
            r.params, r.trajectories, r.response = snap["params"], snap["trajectories"], snap["response"]
            res = evaluate(r, capture, refine=True, refine_iters=int(spec["refine_iters"]))
            point = {
                "train_seconds": snap["seconds"],
                "wall_seconds": before_train + snap["seconds"],
                "step": snap["step"],
                "gaussians": snap["gaussians"],
                "test_psnr_refined": _refined_psnr(res),
                "test_psnr": res["test"].psnr if "test" in res else None,
                "views": view_scores(res),
            }
            # the same snapshot refined with other step caps (``--refine-also``): whether the cap moves the figure
            for cap in spec.get("refine_also", []):
                other = evaluate(r, capture, refine=True, refine_iters=int(cap))
                point.setdefault("refined_at", {})[str(cap)] = {
                    "test_psnr_refined": _refined_psnr(other),
                    "views": view_scores(other),
                }
            points.append(point)
            memory[f"evaluated {len(points)}"] = memory_mb()
        first_step = None if first.at is None else first.at - before_train  # the first step's own duration
        later = (m.train_seconds - (first_step or 0.0)) / max(m.steps - 1, 1)
        return {
            **spec,
            "load_seconds": load_s,
            "timeline": timeline.lines,  # (seconds since start, what began or ended, resident MB, peak MB so far)
            "prepare_seconds": m.prepare_seconds,
            "before_first_step_seconds": before_train + (first_step or 0.0),
            "first_step_seconds": first_step,  # numba's kernels loaded (or compiled) and one step
            "steps": m.steps,
            "steps_per_second": 1.0 / later if later > 0 else None,
            "train_seconds": m.train_seconds,
            "wall_seconds": wall,
            "gaussians": m.gaussians,
            "events": len(ev),
            "bytes_per_event": ev.nbytes() / max(len(ev), 1),
            "peak_rss_mb": peak_rss_mb(),
            "memory_mb": memory,
            "sharp_frames": m.prepare.sharp_frames,
            "sharp_reason": m.prepare.sharp_reason,
            "points": points,
            "final_psnr_refined": points[-1]["test_psnr_refined"] if points else None,
        }


def events_measure(n: int, path: str, frames: int = 30) -> dict:
    """Read n events (already written to ``path``) and window them per frame; peak RSS of this process."""
    import numpy as np

    from ebad.virtual_views import event_counts
    from edi.io import read_events

    t0 = time.perf_counter()
    ev = read_events(path, t_unit="us")
    read_s = time.perf_counter() - t0
    rss_read = peak_rss_mb()
    span = ev.duration_s
    t1 = time.perf_counter()
    counts = 0
    for f in range(frames):
        a = f * span / frames
        win = ev[slice(*ev.window(a, a + 0.05))]
        counts += int(event_counts(ev, (a, a + 0.05), 5).sum())
        assert np.shares_memory(win.t, ev.t) or len(win) == 0
    win_s = time.perf_counter() - t1
    return {
        "events": len(ev),
        "bytes_per_event": ev.nbytes() / len(ev),
        "dtypes": {k: str(getattr(ev, k).dtype) for k in "txyp"},
        "read_seconds": read_s,
        "peak_rss_mb_after_read": rss_read,
        "window_seconds": win_s,
        "windowed_events": counts,
        "peak_rss_mb": peak_rss_mb(),
    }


def write_events(n: int, path: str, seed: int = 0) -> None:
    """n events on a 346x260 sensor over 60 s, raw epoch microseconds (t int64, x/y int16, p int8), as
    ``np.savez`` writes them (uncompressed), built in blocks."""
    import numpy as np

    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 60_000_000, n)) + 1_600_000_000_000_000
    np.savez(
        path,
        t=t,
        x=rng.integers(0, 346, n).astype(np.int16),
        y=rng.integers(0, 260, n).astype(np.int16),
        p=rng.integers(0, 2, n).astype(np.int8),
        width=np.array(346),
        height=np.array(260),
    )


def _db(psnr: float | None) -> str:
    return "-" if psnr is None else f"{psnr:.2f} dB"


def budget_curves(rows: list[dict]) -> list[str]:
    """Per (views, preset, poses) run at several budgets: each budget's final refined PSNR and what it gained over
    the budget before, for the time it took. Where that gain runs out is the plateau; a snapshot inside one run is
    not, since a run lays its schedule (resolution phases, learning-rate decay) over its own budget. A budget run
    several times (``--seconds 300,300,300``) is each run's figure and their mean ± std (population, as
    ``benchmarks.ablation``): the spread of one setting's time-budgeted runs, the gains compared between means."""
    groups: dict[tuple, dict[float, list[dict]]] = {}
    for r in rows:
        if "error" not in r and r.get("final_psnr_refined") is not None:
            key = (r["views"], r["preset"], r["poses"])
            groups.setdefault(key, {}).setdefault(float(r["seconds"]), []).append(r)
    lines = []
    for (views, preset, poses), by_budget in groups.items():
        if sum(len(rs) for rs in by_budget.values()) < 2:
            continue
        parts, prev = [], None
        for seconds in sorted(by_budget):
            rs = by_budget[seconds]
            psnr = float(np.mean([r["final_psnr_refined"] for r in rs]))
            wall = float(np.mean([r["wall_seconds"] for r in rs]))
            if len(rs) == 1:
                part = f"{seconds:.0f} s {_db(psnr)}"
            else:
                each = ", ".join(f"{r['final_psnr_refined']:.2f}" for r in rs)
                spread = float(np.std([r["final_psnr_refined"] for r in rs]))
                part = f"{seconds:.0f} s x{len(rs)} {each}: {psnr:.2f} ± {spread:.2f} dB"
            if prev is not None:
                part += f" ({psnr - prev[0]:+.2f} for {wall / prev[1]:.1f}x the wall time)"
            parts.append(part)
            prev = (psnr, wall)
        lines.append(f"{views:3d} views {preset:>6} {poses:>5} by budget: " + ", ".join(parts))
    return lines


def _subprocess(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, "-m", "benchmarks.scaling", *args], capture_output=True, text=True)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-5:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = list(results["runs"])
    fig, axes = plt.subplots(1, max(len(sizes), 1), figsize=(5 * max(len(sizes), 1), 3.8), squeeze=False)
    for ax, views in zip(axes[0], sizes):
        rows = results["runs"][views]
        several = len({r.get("seconds") for r in rows}) > 1  # budgets: say which curve is which
        runs_of = Counter((r.get("preset"), r.get("poses"), r.get("seconds")) for r in rows)
        seen: Counter = Counter()
        for r in rows:
            key = (r.get("preset"), r.get("poses"), r.get("seconds"))
            seen[key] += 1
            if "points" not in r:
                continue
            xs = [p["wall_seconds"] for p in r["points"]]
            ys = [p["test_psnr_refined"] for p in r["points"]]
            budget = f", {r['seconds']:.0f} s budget" if several else ""
            again = f", run {seen[key]}" if runs_of[key] > 1 else ""  # one budget repeated: its runs apart
            ax.plot(xs, ys, marker="o", label=f"{r['preset']} ({r['poses']}{budget}{again})")
        ax.set(xlabel="wall seconds (everything before the first step included)", ylabel="test PSNR dB (refined)")
        ax.set_title(f"{views} training views")
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend()
        else:  # every run of this size failed: its errors are in the JSON
            ax.text(0.5, 0.5, "no run finished", ha="center", va="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _measure(
    a: argparse.Namespace,
    views: list[int],
    presets: list[str],
    poses: list[str],
    budgets: list[float],
    work: Path,
    results: dict,
) -> None:
    """Every capture simulated and written under ``work``, every run of it measured, into ``results`` as it goes."""
    import scenes

    for n in views:
        t0 = time.perf_counter()
        reset_peak()  # this process's peak while it simulates and writes this capture
        sc = scenes.make_scene("boxes", a.size, seed=a.seed, n_frames=n, n_test=a.test_views, sensor="realistic")
        cap_dir = work / f"{a.size}_{n}"
        scenes.write_scene(sc, cap_dir)
        results["simulate_seconds"][n] = time.perf_counter() - t0
        results["simulate_peak_rss_mb"][n] = memory_mb()[1]
        del sc
        rows: list[dict] = []
        results["runs"][n] = rows
        for preset in presets:
            for pose in poses:
                for budget in budgets:
                    spec = {
                        "capture": str(cap_dir / "capture"),
                        "views": n,
                        "preset": preset,
                        "poses": pose,
                        "seconds": budget,
                        "marks": a.marks,
                        "refine_iters": a.refine_iters,
                        "refine_also": a.refine_also,
                    }
                    r = _subprocess(["--child", json.dumps(spec)])
                    rows.append({**spec, **r})
                    print(
                        f"{n:3d} views {preset:>6} {pose:>5} {budget:.0f} s: "
                        + (
                            f"before the first step {r['before_first_step_seconds']:.1f} s, "
                            f"{r['steps_per_second']:.2f} steps/s, peak RSS {r['peak_rss_mb']:.0f} MB, "
                            f"PSNR {_db(r['final_psnr_refined'])} after {r['wall_seconds']:.0f} s"
                            if "error" not in r
                            else f"failed: {r['error']}"
                        ),
                        flush=True,
                    )
                    # what is done survives a stop (an hour's run each at 40 views)
                    write_json(a.name, {**results, "partial": True})
        for line in budget_curves(rows):
            print(line, flush=True)
    if a.events > 0:
        path = work / "events.npz"
        write_events(int(a.events), str(path))
        results["events"] = _subprocess(["--events-child", str(int(a.events)), str(path)])
        path.unlink()
        print(f"events: {results['events']}", flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="davis", help="scene size: tiny, small or davis (346x260)")
    ap.add_argument("--views", default="10,20,40", help="training views per capture, comma-separated")
    ap.add_argument("--test-views", type=int, default=8, help="held-out test views per capture")
    ap.add_argument("--presets", default="ebad,bad")
    ap.add_argument("--poses", default="noisy,sfm", help="noisy (the capture's noisy poses) and/or sfm (pycolmap)")
    ap.add_argument("--seconds", default="900", help="training budget per run; several, comma-separated: a run each")
    ap.add_argument("--marks", type=int, default=8, help="snapshots per run")
    ap.add_argument("--refine-iters", type=int, default=200, help="test-pose refinement's step cap at each mark")
    ap.add_argument(
        "--refine-also",
        default="",
        help="other step caps, comma-separated, each mark's snapshot refined again with each (outside every budget)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--events", type=float, default=50e6, help="events of the stream measured on its own (0: skip)")
    ap.add_argument("--name", default="scaling", help="results file benchmarks/results/NAME.json (+ .png)")
    ap.add_argument(
        "--workdir",
        default=None,
        help="where the captures are written and kept (default a temporary folder, removed at the end)",
    )
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--events-child", nargs=2, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child is not None:
        print(json.dumps(run_child(json.loads(a.child))))
        return 0
    if a.events_child is not None:
        print(json.dumps(events_measure(int(float(a.events_child[0])), a.events_child[1])))
        return 0
    views = [int(v) for v in a.views.split(",") if v]
    presets = [p for p in a.presets.split(",") if p]
    try:
        budgets = [float(x) for x in a.seconds.split(",") if x]
    except ValueError:
        ap.error(f"--seconds: {a.seconds!r} is not a comma-separated list of seconds")
    if not budgets or any(b <= 0 for b in budgets):
        ap.error(f"--seconds: {a.seconds!r}: every budget must be > 0")
    raw = a.refine_also
    try:
        a.refine_also = [int(x) for x in raw.split(",") if x]
    except ValueError:
        ap.error(f"--refine-also: {raw!r} is not a comma-separated list of step counts")
    if any(k < 1 for k in a.refine_also):
        ap.error(f"--refine-also: {raw!r}: every step cap must be >= 1")
    poses = [p for p in a.poses.split(",") if p]
    for p in poses:
        if p not in POSES:
            ap.error(f"--poses: unknown {p!r} (choose from {', '.join(POSES)})")
    if any(v < 2 for v in views) or a.test_views < 1:
        ap.error("--views: every capture needs >= 2 training views, and --test-views >= 1")
    from ebad.run import warm_up

    # numba's kernels compiled (or loaded) into the cache here, outside every child's budget: a child on a stale
    # cache compiled its rasteriser in its first steps (8.3 s of a 300-s budget, docs/results.md)
    print(f"numba's kernels ready in {warm_up(['grey']):.0f} s (outside every budget)", flush=True)
    work = Path(a.workdir) if a.workdir else Path(tempfile.mkdtemp(prefix="ebad-scaling-"))
    results: dict = {"args": vars(a), "runs": {}, "simulate_seconds": {}, "simulate_peak_rss_mb": {}}
    try:
        _measure(a, views, presets, poses, budgets, work, results)
    except BaseException:  # Ctrl-C included
        if any(results["runs"].values()):
            print(
                f"stopped before its end: the runs it finished are in {RESULTS / a.name}.json (marked partial)",
                file=sys.stderr,
            )
        raise
    finally:
        if not a.workdir:  # the captures (hundreds of MB each) go with the run; --workdir keeps them
            shutil.rmtree(work, ignore_errors=True)
    out = write_json(a.name, results)
    if results["runs"]:  # no views asked (``--views ""``): the events measurement alone, nothing to plot
        plot(results, RESULTS / f"{a.name}.png")
        print(f"wrote {out} and {a.name}.png")
    else:
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
