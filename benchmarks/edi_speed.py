"""Benchmark of edi: EDI throughput, latent error against c error, estimate_c time.

    python -m benchmarks.edi_speed [--quick]    (writes benchmarks/results/edi_speed[_quick].json)

* events per second of ``edi.deblur`` (c given; 1 and 8 instants) at 346x260 with 1e5 to
  1e7 uniformly random events over 40 ms, against a naive time-binned EDI (100 bins,
  ``np.add.at`` per bin, the way many re-implementations work) timed in the same run;
  the ratio is the number to compare across machines (timings are noisy on a shared CPU).
* RMSE of the mid-exposure latent against ground truth on the synthetic moving texture
  (``edi.moving_texture``, c = 0.2) as the c used departs from the true one.
* wall time of ``estimate_c`` (single-frame and consistency) on that synthetic scene.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import edi
from edi import EventStream, moving_texture

from ._common import seed_all, write_json

W, H = 346, 260


def best_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return min(ts)


def throughput(sizes, repeats):
    rng = np.random.default_rng(0)
    B = rng.uniform(0.05, 0.95, (H, W))
    ex = (0.0, 0.04)
    rows = []
    warm = EventStream(np.arange(10), np.zeros(10), np.zeros(10), np.ones(10), W, H)
    edi.deblur(B, ex, warm, c=0.2)  # numba compile / cache load outside the timing
    for m in sizes:
        t = np.sort(rng.integers(0, 40_000, m))
        ev = EventStream(t, rng.integers(0, W, m), rng.integers(0, H, m), rng.integers(0, 2, m), W, H)
        for n_inst in (1, 8):
            times = None if n_inst == 1 else np.linspace(0.0, 0.04, n_inst)
            fast = best_time(lambda ev=ev, times=times: edi.deblur(B, ex, ev, times=times, c=0.2), repeats)
            naive = best_time(
                lambda ev=ev, times=times: edi.deblur(B, ex, ev, times=times, c=0.2, impl="binned", n_bins=100),
                1 if m >= 10**7 else repeats,
            )
            rows.append(
                dict(
                    events=m,
                    instants=n_inst,
                    fast_s=fast,
                    naive_binned_s=naive,
                    fast_mev_per_s=m / fast / 1e6,
                    naive_mev_per_s=m / naive / 1e6,
                    speedup=naive / fast,
                )
            )
    return rows


def c_error_curve():
    s = moving_texture(num_frames=1, seed=0, c=0.2)
    B, ex = s.frames[0], s.exposures[0]
    gt = s.sharp(ex.mean())
    rows = [dict(c_factor=0.0, c=0.0, rmse=float(np.sqrt(np.mean((B - gt) ** 2))))]  # the blurry frame
    for f in (0.5, 0.75, 0.9, 1.0, 1.1, 1.25, 1.5, 2.0):
        L = edi.deblur(B, ex, s.events, c=0.2 * f)
        rows.append(dict(c_factor=f, c=0.2 * f, rmse=float(np.sqrt(np.mean((L - gt) ** 2)))))
    return rows


def estimate_c_timing(repeats):
    s = moving_texture(num_frames=3, seed=1, c=0.2)
    out = {"scene": f"{s.frames.shape[2]}x{s.frames.shape[1]}, {len(s.events)} events, 3 frames, c=0.2"}
    for method, frames, exps in (("single", s.frames[0], s.exposures[0]), ("consistency", s.frames, s.exposures)):
        rep = edi.estimate_contrast(frames, exps, s.events, method=method)
        c = rep.c.mean
        t = best_time(
            lambda frames=frames, exps=exps, method=method: edi.estimate_c(frames, exps, s.events, method=method),
            repeats,
        )
        out[method] = dict(seconds=t, c=c, evals=rep.num_evals, bracket=list(rep.bracket), rel_error=abs(c - 0.2) / 0.2)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="1e5 and 1e6 events only, fewer repeats")
    args = ap.parse_args(argv)
    seed_all(0)
    sizes = (10**5, 10**6) if args.quick else (10**5, 10**6, 10**7)
    repeats = 2 if args.quick else 3
    res = dict(quick=args.quick)
    res["throughput"] = throughput(sizes, repeats)
    res["c_error"] = c_error_curve()
    res["estimate_c"] = estimate_c_timing(repeats)

    print(f"{'events':>10} {'inst':>4} {'fast s':>9} {'Mev/s':>8} {'naive s':>9} {'Mev/s':>8} {'speedup':>8}")
    for r in res["throughput"]:
        print(
            f"{r['events']:>10} {r['instants']:>4} {r['fast_s']:>9.4f} {r['fast_mev_per_s']:>8.1f} "
            f"{r['naive_binned_s']:>9.4f} {r['naive_mev_per_s']:>8.2f} {r['speedup']:>8.1f}"
        )
    print("\nlatent RMSE vs c used (true c = 0.2; c = 0 is the blurry frame)")
    for r in res["c_error"]:
        print(f"  c = {r['c']:.3f} ({r['c_factor']:.2f}x): RMSE {r['rmse']:.4f}")
    ec = res["estimate_c"]
    print(f"\nestimate_c on {ec['scene']}")
    for m in ("single", "consistency"):
        print(
            f"  {m:12s} {ec[m]['seconds']:.3f} s, c = {ec[m]['c']:.4f} ({ec[m]['rel_error']:.1%} off), "
            f"{ec[m]['evals']} evaluations"
        )
    out = write_json("edi_speed_quick" if args.quick else "edi_speed", res)
    print(f"\nwritten {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
