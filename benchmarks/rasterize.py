"""Benchmark splat_cpu: fast (numba) path vs the pure-torch reference, in "units".

Forward and forward+backward milliseconds for N in {2k, 20k, 100k} Gaussians at 128x96 and
346x260, C in {1, 5} cameras, grey (D=1) and colour (D=3); peak memory. Each measurement
runs in its own subprocess so that its peak resident memory is its own.

    python -m benchmarks.rasterize [--quick | --target] [--baseline /work/main] [--rounds 3] [--omp-check] [--name N]

A "unit" (issue 31) is the time of `torch.exp` over 16M float32 values into a preallocated
output (`torch.exp(x, out=y)`), timed in the same subprocess between the repetitions; every
time is also reported divided by it, since absolute times drift on a shared machine. (Issue
10's unit wrote into a freshly allocated output, which adds its page faults; the JSON keeps
it as `unit_fresh_ms`.) The target for the fast path is forward+backward <= 3 units at 20k
Gaussians, 346x260, one grey camera (`--target` times that configuration only).

- `--baseline ROOT` also times the fast path of the splat_cpu found under ROOT (e.g. the
  main checkout), so a before/after pair comes from one run. With `--rounds R` each path
  runs in R subprocesses, the two alternately; the table shows each path's median run, and
  the JSON's `rounds` keeps every round's pair and its ratios of units and of milliseconds
  (a round's two subprocesses see about the same load on a shared machine; the unit, a
  memory-bound kernel, moves with other processes' memory traffic more than the rasteriser).
- Each row's JSON carries `phases_ms`: the median per stage of the forward+backward as the
  rasteriser reports it in `meta["timings"]` (project, bin, forward compositing, and on
  checkouts that report them the backward compositing and the backward projection); the
  same is printed as a second table.
- `--omp-check` times the fast path in subprocesses started without OMP_WAIT_POLICY and
  with OMP_WAIT_POLICY=PASSIVE, alternately, and reports their ratio: the library must not
  depend on the caller setting it (issue 8).

Backward is driven by fixed cotangents (`torch.autograd.backward((images, alphas), (1, 1))`,
gradients reset to None before each call), so no torch kernel of a loss is timed: only the
rasteriser's own work.

Scene: N random Gaussians filling the view frustum at depth 2..6, scales log-uniform in
0.01..0.1 (about 0.8..8 px at depth 4), opacity U(0.05, 1), random rotations; the C cameras
are small translations of each other (the virtual views of one exposure). Timings are
medians of repeated runs after one warm-up call.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

from ._common import peak_rss_mb

FULL_SIZES = [(128, 96), (346, 260)]
FULL_NS = [2_000, 20_000, 100_000]
FULL_CS = [1, 5]
FULL_DS = [1, 3]
UNIT_NUMEL = 16 * 2**20  # torch.exp over 16M float32 values into a preallocated output: the time unit of issue 31
TARGET = (20_000, 346, 260, 1, 1)  # N, W, H, C, D of the <= 3 units target (issue 31)
RESULTS = Path(__file__).resolve().parent / "results"
REF_LIMIT = 20_000 * 346 * 260 * 1  # skip the reference above this many Gaussian-pixel-cameras (minutes)


def make_scene(n: int, width: int, height: int, d: int = 1, n_cams: int = 1, seed: int = 0):
    """Seeded benchmark scene: (means, quats, scales, opacities, colors, viewmats, Ks)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    f = 0.87 * width
    z = 2.0 + 4.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.1 - 0.05) * width
    v = (torch.rand(n, generator=g) * 1.1 - 0.05) * height
    means = torch.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], -1)
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.empty(n, 3).uniform_(math.log(0.01), math.log(0.1), generator=g))
    opac = torch.rand(n, generator=g) * 0.95 + 0.05
    colors = torch.rand(n, d, generator=g)
    viewmats = torch.eye(4)[None].repeat(n_cams, 1, 1)
    for c in range(n_cams):
        viewmats[c, 0, 3] = 0.01 * c
        viewmats[c, 1, 3] = -0.005 * c
    ks = torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])[None].repeat(n_cams, 1, 1)
    return means, quats, scales, opac, colors, viewmats, ks


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def import_splat_cpu(root: str | None):  # -> the splat_cpu module, from `root` when given
    """This checkout's splat_cpu, or with `root` that checkout's (the "before" of a before/after pair).

    `_common` (through ebad.threads) has imported this checkout's splat_cpu already: its modules are
    dropped first, or the import would return them and the baseline would time this checkout. The
    threading set-up `_common` made (OMP_WAIT_POLICY noted, numba's layer chosen, in `_omp`'s state)
    is handed to the root's `_omp`, so that both paths run on the same layer (left alone, the root's
    would choose again once torch is loaded, from the starting environment: workqueue, not omp)."""
    if root:
        setup = sys.modules.get("splat_cpu._omp")
        for name in [m for m in sys.modules if m == "splat_cpu" or m.startswith("splat_cpu.")]:
            del sys.modules[name]
        sys.path.insert(0, root)
        omp = importlib.import_module("splat_cpu._omp") if setup is not None else None
        for state in ("_noted", "_chosen"):
            if omp is not None and hasattr(omp, state) and hasattr(setup, state):
                getattr(omp, state)[:] = getattr(setup, state)
    import splat_cpu

    if root and not Path(splat_cpu.__file__).resolve().is_relative_to(Path(root).resolve()):
        raise RuntimeError(f"--baseline {root}: imported {splat_cpu.__file__} instead")
    return splat_cpu


def measure_one(cfg: dict) -> dict:
    """Run in a subprocess: time one configuration with one path (and the unit between repetitions)."""
    splat_cpu = import_splat_cpu(cfg.get("root"))
    import torch

    fn = splat_cpu.rasterize if cfg["path"] == "fast" else splat_cpu.rasterize_reference
    scene = make_scene(cfg["n"], cfg["width"], cfg["height"], cfg["d"], cfg["c"])
    leaves = [t.clone().requires_grad_() for t in scene[:6]]
    ks = scene[6]
    w, h = cfg["width"], cfg["height"]
    x = torch.rand(UNIT_NUMEL)
    y = torch.empty_like(x)

    def unit():
        t = time.perf_counter()
        torch.exp(x, out=y)  # preallocated output (issue 31)
        return time.perf_counter() - t

    def unit_fresh():
        t = time.perf_counter()
        z = torch.exp(x)  # freshly allocated output (issue 10)
        dt = time.perf_counter() - t
        del z
        return dt

    def fwd():
        return fn(*leaves, ks, w, h)

    cot_img = torch.ones(cfg["c"], h, w, cfg["d"])
    cot_alpha = torch.ones(cfg["c"], h, w, 1)

    def fwd_bwd():
        for leaf in leaves:
            leaf.grad = None  # as optimizer.zero_grad() does: no accumulation kernel
        img, alpha, meta = fn(*leaves, ks, w, h)
        torch.autograd.backward((img, alpha), (cot_img, cot_alpha))
        return meta

    t = time.perf_counter()
    fwd_bwd()  # warm-up: loads (or compiles) the numba kernels
    first_ms = 1e3 * (time.perf_counter() - t)
    base_rss = _rss_mb()
    reps = cfg["reps"]
    tf, tfb, tu, tuf = [], [], [], []
    phases: dict[str, list[float]] = {}
    meta = None
    for _ in range(reps):
        tu.append(unit())
        tuf.append(unit_fresh())
        t = time.perf_counter()
        out = fwd()
        tf.append(time.perf_counter() - t)
        meta = out[2]
        del out
        t = time.perf_counter()
        for k, v in fwd_bwd()["timings"].items():  # the stages of this forward+backward (ms)
            phases.setdefault(k, []).append(v)
        tfb.append(time.perf_counter() - t)
    peak = peak_rss_mb()  # this process's own VmHWM (ru_maxrss would carry the parent's peak over exec)
    med = lambda xs: 1e3 * sorted(xs)[len(xs) // 2]  # noqa: E731
    return {
        **cfg,
        "splat_cpu": splat_cpu.__file__,
        "unit_ms": med(tu),
        "unit_fresh_ms": med(tuf),
        "fwd_ms": med(tf),
        "fwd_bwd_ms": med(tfb),
        "fwd_units": med(tf) / med(tu),
        "fwd_bwd_units": med(tfb) / med(tu),
        "first_call_ms": first_ms,
        "peak_rss_mb": peak,
        "peak_over_baseline_mb": peak - base_rss,
        "n_isect": meta.get("n_isect"),
        "phases_ms": {k: sorted(v)[len(v) // 2] for k, v in phases.items()},
        "n_visible": [int(x) for x in meta["n_visible"]],
    }


def _run_sub(cfg: dict, timeout: float, wait_policy: str) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.rasterize", "--one", json.dumps(cfg)]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
    env.pop("OMP_WAIT_POLICY", None)
    if wait_policy != "unset":
        env["OMP_WAIT_POLICY"] = wait_policy
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {**cfg, "skipped": f"took more than {timeout:.0f} s"}
    if out.returncode != 0:
        return {**cfg, "error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"rc {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _cell(r: dict, k: str, fmt: str = "{:8.1f}") -> str:
    width = len(fmt.format(0.0))
    return fmt.format(r[k]) if k in r else f"{'skip' if 'skipped' in r else 'ERR':>{width}}"


def _git_head(root: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", root, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
    except OSError:
        return None
    return out.stdout.strip() or None


def omp_check(reps: int, rounds: int, timeout: float) -> dict:
    """The TARGET configuration's fast path, without and with OMP_WAIT_POLICY=PASSIVE, alternately."""
    n, w, h, c, d = TARGET
    cfg = {"width": w, "height": h, "n": n, "c": c, "d": d, "reps": reps, "path": "fast"}
    runs: dict[str, list[dict]] = {"unset": [], "PASSIVE": []}
    for _ in range(rounds):
        for policy in runs:
            runs[policy].append(_run_sub(cfg, timeout, policy))
    med = lambda xs: sorted(xs)[len(xs) // 2] if xs else float("nan")  # noqa: E731
    summary = {}
    for policy, rs in runs.items():
        ok = [r for r in rs if "fwd_bwd_ms" in r]
        summary[policy] = {
            "fwd_bwd_ms": med([r["fwd_bwd_ms"] for r in ok]),
            "fwd_bwd_units": med([r["fwd_bwd_units"] for r in ok]),
            "runs": rs,
        }
    summary["ratio_unset_over_passive_ms"] = summary["unset"]["fwd_bwd_ms"] / summary["PASSIVE"]["fwd_bwd_ms"]
    return summary


def extent_check(seed: int = 0) -> dict:
    """Tile entries of the TARGET scene under three extents of a Gaussian (no timing): the fixed 3-sigma box
    (gsplat's classic radius; it drops pixels where alpha >= ALPHA_MIN for opacities above 0.353), the
    opacity-aware box (half-extent sqrt(2 ln(255 o)) sigma per axis, where alpha reaches ALPHA_MIN), and the
    fast path's binning (that box's tiles less those its alpha >= ALPHA_MIN ellipse misses: meta["n_isect"])."""
    import torch

    import splat_cpu
    from splat_cpu._project import project
    from splat_cpu.constants import TILE

    n, w, h, c, d = TARGET
    scene = make_scene(n, w, h, d, c, seed)
    proj = project(*scene[:4], scene[5], scene[6], w, h)
    # every Gaussian's 2D geometry: project with opacity 1, whose box (3.33 sigma) contains the 3-sigma box
    geo = project(scene[0], scene[1], scene[2], torch.ones_like(scene[3]), scene[5], scene[6], w, h)
    a, b, cc = geo.conics[0].double().unbind(-1)
    det = a * cc - b * b
    sd_x, sd_y = (cc / det).sqrt(), (a / det).sqrt()  # the 2D covariance's diagonal from its inverse
    u, v = geo.means2d[0].double().unbind(-1)
    op = scene[3].double()

    def tiles(rx: torch.Tensor, ry: torch.Tensor, keep: torch.Tensor) -> int:
        x0 = torch.clamp(torch.ceil(u - rx - 0.5), min=0)
        x1 = torch.clamp(torch.floor(u + rx - 0.5), max=w - 1)
        y0 = torch.clamp(torch.ceil(v - ry - 0.5), min=0)
        y1 = torch.clamp(torch.floor(v + ry - 0.5), max=h - 1)
        keep = keep & (x0 <= x1) & (y0 <= y1)
        nt = (torch.div(x1, TILE, rounding_mode="floor") - torch.div(x0, TILE, rounding_mode="floor") + 1) * (
            torch.div(y1, TILE, rounding_mode="floor") - torch.div(y0, TILE, rounding_mode="floor") + 1
        )
        return int(nt[keep].sum())

    ext = torch.sqrt(2 * torch.log(torch.clamp(op * 255, min=1.0)))
    three = tiles(torch.ceil(3 * sd_x), torch.ceil(3 * sd_y), geo.valid[0])
    aware = tiles(torch.ceil(ext * sd_x), torch.ceil(ext * sd_y), proj.valid[0])
    _, _, meta = splat_cpu.rasterize(*scene, w, h)
    return {
        "three_sigma_box": three,
        "opacity_aware_box": aware,
        "binned": meta["n_isect"],
        "opacity_share_below_0.353": float((op < 0.353).double().mean()),
    }


PHASES = [
    ("project_ms", "project"),
    ("bin_ms", "bin"),
    ("composite_ms", "forward"),
    ("backward_composite_ms", "backward"),
    ("backward_project_ms", "bwd proj"),
]


def _print_phases(rows: list[dict]) -> None:
    """Per-stage medians (ms) of the fast path's forward+backward, from `meta["timings"]` (JSON: phases_ms)."""
    print("\nstages of the fast path's forward+backward (ms, median; '-': not reported by that checkout)")
    print(f"{'W x H':>9} {'N':>7} {'C':>2} {'D':>2} | {'path':>8} | " + " ".join(f"{name:>8}" for _, name in PHASES))
    for r in rows:
        cfg = r["config"]
        for label, res in (("fast", r["fast"]), ("base", r["baseline"])):
            ph = res.get("phases_ms")
            if ph is None:
                continue
            cells = " ".join(f"{ph[k]:8.1f}" if k in ph else f"{'-':>8}" for k, _ in PHASES)
            size = f"{cfg['width']:>4}x{cfg['height']:<4}"
            print(f"{size} {cfg['n']:>7} {cfg['c']:>2} {cfg['d']:>2} | {label:>8} | {cells}")


def _median_run(runs: list[dict]) -> dict:
    """The run with the median fwd_bwd_units (the first run when none has a time)."""
    ok = sorted((r for r in runs if "fwd_bwd_units" in r), key=lambda r: r["fwd_bwd_units"])
    return ok[len(ok) // 2] if ok else runs[0]


def _alternate(cfg: dict, args: argparse.Namespace) -> tuple[dict, dict, list[dict]]:
    """The fast path (and with --baseline the baseline's) in `args.rounds` rounds, each round one subprocess of each
    back to back: on a shared machine the load drifts between subprocesses, and a round's pair sees about the same.
    Returns the median run of each and per round the pair's ratio of units (this checkout over the baseline)."""
    fasts, bases, pairs = [], [], []
    for _ in range(args.rounds):
        fasts.append(_run_sub({**cfg, "path": "fast"}, args.timeout, args.omp_wait_policy))
        if args.baseline:
            bases.append(_run_sub({**cfg, "path": "fast", "root": args.baseline}, args.timeout, args.omp_wait_policy))
            f, b = fasts[-1], bases[-1]
            if "fwd_bwd_units" in f and "fwd_bwd_units" in b:
                pairs.append(
                    {
                        "fast_units": f["fwd_bwd_units"],
                        "base_units": b["fwd_bwd_units"],
                        "units_ratio": f["fwd_bwd_units"] / b["fwd_bwd_units"],
                        "fast_ms": f["fwd_bwd_ms"],
                        "base_ms": b["fwd_bwd_ms"],
                        "ms_ratio": f["fwd_bwd_ms"] / b["fwd_bwd_ms"],
                        "load_avg_1min": os.getloadavg()[0],
                    }
                )
    base = _median_run(bases) if bases else {"skipped": "no --baseline"}
    return _median_run(fasts), base, pairs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="JSON output path (default benchmarks/results/rasterize[_quick].json)")
    ap.add_argument("--name", default=None, help="write benchmarks/results/NAME.json (when --out is not given)")
    ap.add_argument("--quick", action="store_true", help="a small subset (128x96 and 346x260, N=2k/20k, C=1, grey)")
    ap.add_argument("--target", action="store_true", help="only the target configuration (20k, 346x260, C=1, grey)")
    ap.add_argument("--no-reference", action="store_true", help="time only the fast path")
    ap.add_argument("--baseline", metavar="ROOT", help="also time the fast path of the splat_cpu under ROOT")
    ap.add_argument(
        "--omp-check",
        action="store_true",
        help="time the target configuration without and with OMP_WAIT_POLICY=PASSIVE (issue 8)",
    )
    ap.add_argument("--omp-rounds", type=int, default=3, help="subprocess pairs for --omp-check")
    ap.add_argument("--reps", type=int, default=7, help="timed repetitions per configuration (median reported)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds before a configuration is skipped")
    ap.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="subprocesses per path, this checkout and the baseline alternately (the median run is reported)",
    )
    ap.add_argument(
        "--omp-wait-policy",
        default="unset",
        choices=["unset", "PASSIVE", "ACTIVE"],
        help="OMP_WAIT_POLICY of the measuring subprocesses of the table ('unset': removed)",
    )
    ap.add_argument(
        "--extent-check",
        action="store_true",
        help="count the target scene's tile entries under 3-sigma and opacity-aware extents, and exit",
    )
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure_one(json.loads(args.one))))
        return 0
    if args.extent_check:
        print(json.dumps(extent_check()))
        return 0

    if args.target:
        n, w, h, c, d = TARGET
        configs = [(w, h, n, c, d)]
    elif args.quick:
        configs = [(w, h, n, 1, 1) for (w, h) in FULL_SIZES for n in (2_000, 20_000)] + [(346, 260, 20_000, 5, 1)]
    else:
        configs = [(w, h, n, c, d) for (w, h) in FULL_SIZES for n in FULL_NS for c in FULL_CS for d in FULL_DS]
    rows = []
    hdr = (
        f"{'W x H':>9} {'N':>7} {'C':>2} {'D':>2} | {'unit':>6} | {'fast fwd':>8} {'fast f+b':>8} {'units':>6} "
        f"{'MB':>5} | {'base f+b':>8} {'units':>6} | {'ref f+b':>8} {'units':>6} | {'ref/fast':>8}"
    )
    print(hdr)
    print("-" * len(hdr))
    for w, h, n, c, d in configs:
        cfg = {"width": w, "height": h, "n": n, "c": c, "d": d, "reps": args.reps}
        fast, base, pairs = _alternate(cfg, args)
        if args.no_reference:
            ref = {"skipped": "--no-reference"}
        elif n * w * h * c > REF_LIMIT:
            ref = {"skipped": "too slow for the torch reference (see REF_LIMIT)"}
        else:
            ref = _run_sub(
                {**cfg, "path": "reference", "reps": max(1, min(args.reps, 2))}, args.timeout, args.omp_wait_policy
            )
        ratio = ref["fwd_bwd_ms"] / fast["fwd_bwd_ms"] if "fwd_bwd_ms" in ref and "fwd_bwd_ms" in fast else None
        rows.append(
            {"config": cfg, "fast": fast, "baseline": base, "reference": ref, "ratio_fwd_bwd": ratio, "rounds": pairs}
        )
        print(
            f"{w:>4}x{h:<4} {n:>7} {c:>2} {d:>2} | {_cell(fast, 'unit_ms', '{:6.1f}')} | "
            f"{_cell(fast, 'fwd_ms')} {_cell(fast, 'fwd_bwd_ms')} {_cell(fast, 'fwd_bwd_units', '{:6.2f}')} "
            f"{_cell(fast, 'peak_rss_mb', '{:5.0f}')} | {_cell(base, 'fwd_bwd_ms')} "
            f"{_cell(base, 'fwd_bwd_units', '{:6.2f}')} | {_cell(ref, 'fwd_bwd_ms')} "
            f"{_cell(ref, 'fwd_bwd_units', '{:6.2f}')} | {f'{ratio:8.1f}' if ratio else '       -'}",
            flush=True,
        )
    _print_phases(rows)
    for r in rows:
        if r["rounds"]:
            for key in ("units", "ms"):
                ratios = sorted(p[f"{key}_ratio"] for p in r["rounds"])
                cells = " ".join(f"{p[f'fast_{key}']:.2f}/{p[f'base_{key}']:.2f}" for p in r["rounds"])
                print(
                    f"rounds ({key}, this checkout / baseline): {cells}; median ratio {ratios[len(ratios) // 2]:.3f}"
                    f" ({r['config']['width']}x{r['config']['height']}, N={r['config']['n']})"
                )
    notes = sorted({r["reference"]["skipped"] for r in rows if "skipped" in r["reference"]})
    for note in notes:
        print(f"reference skipped: {note}")
    print(
        "times in ms (median); units = time / unit, unit = torch.exp over 16M float32 values into a preallocated "
        "output in the same process; "
        f"MB = peak resident memory of the measuring process; OMP_WAIT_POLICY={args.omp_wait_policy}"
        + (f"; base = {args.baseline}" if args.baseline else "")
    )
    result = {
        "rows": rows,
        "cpu_count": os.cpu_count(),
        "quick": args.quick,
        "omp_wait_policy": args.omp_wait_policy,
        "baseline": {"root": args.baseline, "commit": _git_head(args.baseline)} if args.baseline else None,
        "commit": _git_head(str(Path(__file__).resolve().parents[1])),
    }
    if args.omp_check:
        chk = omp_check(args.reps, args.omp_rounds, args.timeout)
        result["omp_check"] = chk
        n, w, h, c, d = TARGET
        print(
            f"\nOMP_WAIT_POLICY check ({n} Gaussians, {w}x{h}, C={c}, D={d}; median of {args.omp_rounds} "
            f"alternating subprocesses each):"
        )
        for policy in ("unset", "PASSIVE"):
            print(f"  {policy:>8}: f+b {chk[policy]['fwd_bwd_ms']:7.1f} ms  {chk[policy]['fwd_bwd_units']:5.2f} units")
        print(f"  unset / PASSIVE = {chk['ratio_unset_over_passive_ms']:.2f}")
    result["load_avg"] = os.getloadavg()
    name = "rasterize_target.json" if args.target else "rasterize_quick.json" if args.quick else "rasterize.json"
    out = Path(args.out) if args.out else RESULTS / (f"{args.name}.json" if args.name else name)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
