"""What the start-up costs before the first step, and what a coarser contrast estimate costs in quality.

    python -m benchmarks.startup [--quick] [--size davis] [--modes ideal,realistic] [--seeds 0,1,2]
                                 [--strides 1,2,4]

Before its first step a run estimates the contrast thresholds from every training frame
(``edi.estimate_c``, pair) and places its first Gaussians by a plane sweep
(``ebad.gaussians.plane_sweep_points``, inside ``TrainState.create``). This module times both on
``scenes.make_scene("boxes", SIZE)`` captures, and times the estimate again on a pixel subset:
every ``stride``-th row and column of the frames with only the events of those pixels, which is
the same model on fewer pixels (no pooling, so nothing of the EDI relation is approximated). For
each stride it reports the seconds, the ratio to the full estimate's (same process, same
capture), the estimate against the full one, and what the estimate gives: the PSNR of the
per-frame EDI latents at mid-exposure against the sharp truth (``benchmarks.paper_departures
.prior_psnr``, the L_EDI prior of training). Settings as ``benchmarks.time_to_quality``
(``ideal``: linear sensor; ``realistic``: the realistic sensor). The truth is only used to score.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ._common import seed_all, write_json
from .paper_departures import prior_psnr
from .time_to_quality import MODES, parse_modes


def pixel_subset(frames: np.ndarray, events, stride: int):
    """Every ``stride``-th row and column of ``frames`` [F, H, W, D] and the events of those pixels."""
    from edi import EventStream

    if stride == 1:
        return frames, events
    keep = (events.x % stride == 0) & (events.y % stride == 0)
    W, H = -(-events.width // stride), -(-events.height // stride)
    sub = EventStream(
        events.t[keep], events.x[keep] // stride, events.y[keep] // stride, events.p[keep], W, H, t0=events.t0
    )
    return np.ascontiguousarray(frames[:, ::stride, ::stride]), sub


def measure(scene, strides: list[int]) -> dict:
    import edi
    from ebad.config import preset
    from ebad.data import _train_indices, prepare
    from ebad.state import TrainState

    cap = scene.capture
    idx = _train_indices(cap)
    frames = np.asarray(cap.frames, dtype=np.float32)[idx]
    ex = np.asarray(cap.exposures, dtype=np.float64)[idx]
    rows = []
    for s in strides:
        fr, ev = pixel_subset(frames, cap.events, s)
        t0 = time.perf_counter()
        c = edi.estimate_c(fr, ex, ev, pair=True)
        sec = time.perf_counter() - t0
        rows.append(
            {
                "stride": s,
                "seconds": sec,
                "c": [float(c[0]), float(c[1])],
                "prior_psnr": prior_psnr(scene, (float(c[0]), float(c[1])), "edi"),
            }
        )
    for r in rows:
        r["seconds_ratio"] = r["seconds"] / rows[0]["seconds"]
        r["c_ratio"] = [r["c"][k] / rows[0]["c"][k] for k in range(2)]
    cfg = preset("ebad")
    cfg.loss.contrast = tuple(rows[0]["c"])  # the estimate is timed above; prepare repeats the EDI latents
    data = prepare(cap, cfg)
    t0 = time.perf_counter()
    TrainState.create(data, cfg)
    init_s = time.perf_counter() - t0
    return {"estimates": rows, "init_seconds": init_s}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.startup", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny scene, one seed")
    ap.add_argument("--size", default=None, help="scene size (default davis; quick tiny)")
    ap.add_argument("--modes", default="ideal,realistic")
    ap.add_argument("--seeds", default=None, help="default 0,1,2 (quick 0)")
    ap.add_argument("--strides", default="1,2,4")
    ap.add_argument("--name", default=None, help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import scenes

    size = args.size or ("tiny" if args.quick else "davis")
    seeds = [int(s) for s in (args.seeds or ("0" if args.quick else "0,1,2")).split(",")]
    strides = [int(s) for s in args.strides.split(",")]
    if strides[0] != 1:
        ap.error("--strides must start with 1 (the full estimate the others are compared with)")
    modes = parse_modes(ap, args.modes)
    measure(scenes.make_scene("boxes", "tiny", seed=0), [1, 2])  # compile the numba kernels outside the timings
    results = {}
    print(f"start-up at size {size}: contrast estimate on every stride-th pixel, plane-sweep initialisation")
    print(
        f"{'mode':10s} {'seed':>4s} {'stride':>6s} {'seconds':>8s} {'x full':>7s} {'c_pos':>7s} {'c_neg':>7s} "
        f"{'c/full':>13s} {'EDI prior dB':>12s}"
    )
    for mode in modes:
        for seed in seeds:
            seed_all(seed)
            scene = scenes.make_scene("boxes", size, seed=seed, **MODES[mode])
            r = measure(scene, strides)
            results.setdefault(mode, []).append({"seed": seed, **r})
            for e in r["estimates"]:
                print(
                    f"{mode:10s} {seed:4d} {e['stride']:6d} {e['seconds']:8.2f} {e['seconds_ratio']:7.2f} "
                    f"{e['c'][0]:7.4f} {e['c'][1]:7.4f} {e['c_ratio'][0]:6.3f}/{e['c_ratio'][1]:6.3f} "
                    f"{e['prior_psnr']:12.2f}"
                )
            print(f"{mode:10s} {seed:4d} plane-sweep initialisation {r['init_seconds']:.2f} s", flush=True)
    name = args.name or ("startup_quick" if args.quick else "startup")
    write_json(
        name,
        {
            "size": size,
            "seeds": seeds,
            "strides": strides,
            "modes": {m: MODES[m] for m in modes},
            "results": results,
            "argv": sys.argv[1:] if argv is None else list(argv),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
