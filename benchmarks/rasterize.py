"""Benchmark splat_cpu: fast (numba) path vs the pure-torch reference.

Forward and forward+backward milliseconds for N in {2k, 20k, 100k} Gaussians at 128x96 and
346x260, C in {1, 5} cameras, grey (D=1) and colour (D=3); their ratio; peak memory. Each
measurement runs in its own subprocess so that its peak resident memory is its own.

    python benchmarks/rasterize.py [--quick] [--out bench_out/rasterize.json]

Scene: N random Gaussians filling the view frustum at depth 2..6, scales log-uniform in
0.01..0.1 (about 0.8..8 px at depth 4), opacity U(0.05, 1), random rotations; the C cameras
are small translations of each other (the virtual views of one exposure). Timings are
medians of repeated runs after one warm-up call, and noisy on a shared machine: compare the
ratio column, taken in the same run.

The measuring subprocesses run with OMP_WAIT_POLICY=PASSIVE unless --omp-wait-policy says
otherwise: on a 2-core machine shared with other work, torch's spin-waiting OpenMP pool made
the (pure torch) projection 30x slower (20k Gaussians: 6 ms -> 200 ms forward, 11 -> 370 ms
backward), which swamps the compositing kernels.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

FULL_SIZES = [(128, 96), (346, 260)]
FULL_NS = [2_000, 20_000, 100_000]
FULL_CS = [1, 5]
FULL_DS = [1, 3]
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


def measure_one(cfg: dict) -> dict:
    """Run in a subprocess: time one configuration with one path."""
    import torch

    import splat_cpu

    torch.set_num_threads(int(cfg.get("threads", torch.get_num_threads())))
    fn = splat_cpu.rasterize if cfg["path"] == "fast" else splat_cpu.rasterize_reference
    scene = make_scene(cfg["n"], cfg["width"], cfg["height"], cfg["d"], cfg["c"])
    leaves = [t.clone().requires_grad_() for t in scene[:6]]
    ks = scene[6]
    w, h = cfg["width"], cfg["height"]

    def fwd():
        return fn(*leaves, ks, w, h)

    def fwd_bwd():
        img, alpha, _ = fn(*leaves, ks, w, h)
        (img.sum() + alpha.sum()).backward()

    t = time.perf_counter()
    fwd_bwd()  # warm-up: loads (or compiles) the numba kernels
    first_ms = 1e3 * (time.perf_counter() - t)
    base_rss = _rss_mb()
    reps = cfg["reps"]
    tf, tfb = [], []
    meta = None
    for _ in range(reps):
        t = time.perf_counter()
        out = fwd()
        tf.append(time.perf_counter() - t)
        meta = out[2]
        del out
        t = time.perf_counter()
        fwd_bwd()
        tfb.append(time.perf_counter() - t)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    med = lambda xs: 1e3 * sorted(xs)[len(xs) // 2]  # noqa: E731
    return {
        **cfg,
        "fwd_ms": med(tf),
        "fwd_bwd_ms": med(tfb),
        "first_call_ms": first_ms,
        "peak_rss_mb": peak,
        "peak_over_baseline_mb": peak - base_rss,
        "n_isect": meta.get("n_isect"),
        "n_visible": [int(x) for x in meta["n_visible"]],
    }


def _run_sub(cfg: dict, timeout: float, wait_policy: str) -> dict:
    cmd = [sys.executable, __file__, "--one", json.dumps(cfg)]
    env = dict(os.environ)
    if wait_policy != "default":
        env["OMP_WAIT_POLICY"] = wait_policy
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {**cfg, "skipped": f"took more than {timeout:.0f} s"}
    if out.returncode != 0:
        return {**cfg, "error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"rc {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench_out/rasterize.json", help="JSON output path")
    ap.add_argument("--quick", action="store_true", help="a small subset (128x96 and 346x260, N=2k/20k, C=1, grey)")
    ap.add_argument("--no-reference", action="store_true", help="time only the fast path")
    ap.add_argument("--reps", type=int, default=5, help="timed repetitions per configuration (median reported)")
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds before a configuration is skipped")
    ap.add_argument("--omp-wait-policy", default="PASSIVE", choices=["PASSIVE", "ACTIVE", "default"],
                    help="OMP_WAIT_POLICY of the measuring subprocesses ('default': inherit)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure_one(json.loads(args.one))))
        return 0

    if args.quick:
        configs = [(w, h, n, 1, 1) for (w, h) in FULL_SIZES for n in (2_000, 20_000)] + [(346, 260, 20_000, 5, 1)]
    else:
        configs = [(w, h, n, c, d) for (w, h) in FULL_SIZES for n in FULL_NS for c in FULL_CS for d in FULL_DS]
    rows = []
    hdr = (f"{'W x H':>9} {'N':>7} {'C':>2} {'D':>2} | {'fast fwd':>9} {'fast f+b':>9} {'MB':>6} | "
           f"{'ref fwd':>9} {'ref f+b':>9} {'MB':>6} | {'ratio f+b':>9}")
    print(hdr)
    print("-" * len(hdr))
    for w, h, n, c, d in configs:
        cfg = {"width": w, "height": h, "n": n, "c": c, "d": d, "reps": args.reps}
        fast = _run_sub({**cfg, "path": "fast"}, args.timeout, args.omp_wait_policy)
        if args.no_reference:
            ref = {"skipped": "--no-reference"}
        elif n * w * h * c > REF_LIMIT:
            ref = {"skipped": "too slow for the torch reference (see REF_LIMIT)"}
        else:
            ref = _run_sub({**cfg, "path": "reference", "reps": max(1, min(args.reps, 2))}, args.timeout,
                           args.omp_wait_policy)
        ratio = ref["fwd_bwd_ms"] / fast["fwd_bwd_ms"] if "fwd_bwd_ms" in ref and "fwd_bwd_ms" in fast else None
        rows.append({"config": cfg, "fast": fast, "reference": ref, "ratio_fwd_bwd": ratio})

        def cell(r, k, fmt="{:9.1f}"):
            return fmt.format(r[k]) if k in r else f"{'skip' if 'skipped' in r else 'ERR':>{len(fmt.format(0.0))}}"

        print(f"{w:>4}x{h:<4} {n:>7} {c:>2} {d:>2} | {cell(fast, 'fwd_ms')} {cell(fast, 'fwd_bwd_ms')} "
              f"{cell(fast, 'peak_rss_mb', '{:6.0f}')} | {cell(ref, 'fwd_ms')} {cell(ref, 'fwd_bwd_ms')} "
              f"{cell(ref, 'peak_rss_mb', '{:6.0f}')} | {('%9.1f' % ratio) if ratio else '        -'}", flush=True)
    notes = sorted({r["reference"]["skipped"] for r in rows if "skipped" in r["reference"]})
    for note in notes:
        print(f"reference skipped: {note}")
    print("times in ms (median), MB = peak resident memory of the measuring process (torch + numba included); "
          f"OMP_WAIT_POLICY={args.omp_wait_policy}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows, "cpu_count": os.cpu_count(), "quick": args.quick,
                                "omp_wait_policy": args.omp_wait_policy, "load_avg": os.getloadavg()}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    raise SystemExit(main())
