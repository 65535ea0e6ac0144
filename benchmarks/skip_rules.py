"""What each "skip what the scene does not need" rule saves, each timed against the same run
without it, at the same step count, in one run of this module (PSNR to show nothing is lost).

    python -m benchmarks.skip_rules [--quick] [--size davis] [--iters N]

On a synthetic capture (idealised sensor, exact poses) where half of the frames are sharp:

- adaptive V: sharp frames render once, with no trajectory, vs V = n for every frame;
- grey stays one channel vs the same grey scene rendered as three channels;
- no events: L_ev, L_EDI and the EDI pre-pass skipped vs computed (same V);
- the plateau stop vs running every step.

The PSNR-against-time curves of the presets are ``benchmarks.time_to_quality``.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time

import numpy as np

from ._common import seed_all, write_json


def _cfg(name: str, iters: int):
    from ebad.config import preset

    cfg = preset(name)
    cfg.train.iters = iters
    cfg.train.progress = False
    cfg.train.eval_every = 0
    return cfg


def _timed(cap, cfg) -> tuple:
    from ebad.run import reconstruct

    t0 = time.perf_counter()
    run = reconstruct(cap, cfg)
    return run, time.perf_counter() - t0


def _psnr(run) -> float | None:
    return run.metrics.test.psnr if run.metrics.test is not None else None


def skip_rules(size: str, iters: int) -> dict:
    import scenes
    from edi import EventStream

    sc = scenes.make_scene("boxes", size=size, seed=3, sharp_fraction=0.5, sensor="ideal")
    res = {}
    on, off = _cfg("ebad", iters), _cfg("ebad", iters)
    off.trajectory.adaptive_views = False
    r_on, _ = _timed(sc.capture, on)
    r_off, _ = _timed(sc.capture, off)
    res["adaptive_views"] = {
        "seconds_with": r_on.metrics.train_seconds,
        "seconds_without": r_off.metrics.train_seconds,
        "renders_per_pass_with": r_on.metrics.prepare.renders_per_pass,
        "renders_per_pass_without": r_off.metrics.prepare.renders_per_pass,
        "psnr_with": _psnr(r_on),
        "psnr_without": _psnr(r_off),
    }
    r1, _ = _timed(sc.capture, _cfg("3dgs", iters))
    cap3 = copy.copy(sc.capture)
    cap3.frames = np.repeat(sc.capture.frames, 3, -1)
    cap3.test_views = [copy.copy(v) for v in sc.capture.test_views]
    for v in cap3.test_views:
        v.image = np.repeat(v.image, 3, -1)
    r3, _ = _timed(cap3, _cfg("3dgs", iters))
    res["grey_one_channel"] = {
        "seconds_with": r1.metrics.train_seconds,
        "seconds_without": r3.metrics.train_seconds,
        "psnr_with": _psnr(r1),
        "psnr_without": _psnr(r3),
    }
    cap0 = copy.copy(sc.capture)
    cap0.events = EventStream.empty(sc.capture.width, sc.capture.height)
    cfg_e, cfg_0 = _cfg("ebad", iters), _cfg("ebad", iters)
    cfg_e.trajectory.adaptive_views = cfg_0.trajectory.adaptive_views = False
    r_e, _ = _timed(sc.capture, cfg_e)
    r_0, _ = _timed(cap0, cfg_0)
    res["no_events_skip_losses"] = {
        "seconds_with": r_0.metrics.train_seconds + r_0.metrics.prepare_seconds,
        "seconds_without": r_e.metrics.train_seconds + r_e.metrics.prepare_seconds,
        "note": "with = capture without events (losses skipped); without = computed",
    }
    p_on = _cfg("3dgs", 3 * iters)
    p_on.train.plateau_patience, p_on.train.plateau_every, p_on.train.plateau_tol = 2, 50, 0.01
    rp, _ = _timed(sc.capture, p_on)
    rf, _ = _timed(sc.capture, _cfg("3dgs", 3 * iters))
    res["plateau_stop"] = {
        "seconds_with": rp.metrics.train_seconds,
        "seconds_without": rf.metrics.train_seconds,
        "steps_with": rp.metrics.steps,
        "steps_without": rf.metrics.steps,
        "psnr_with": _psnr(rp),
        "psnr_without": _psnr(rf),
    }
    for v in res.values():
        v["time_ratio_without_over_with"] = v["seconds_without"] / max(v["seconds_with"], 1e-9)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny scene, 60 steps")
    ap.add_argument("--size", default=None, help="scene size (default small; quick tiny)")
    ap.add_argument("--iters", type=int, default=None, help="steps of each run (default 300; quick 60)")
    ap.add_argument("--name", default="skip_rules", help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    size = args.size or ("tiny" if args.quick else "small")
    iters = args.iters if args.iters is not None else (60 if args.quick else 300)
    seed_all(0)
    res = skip_rules(size, iters)
    print(f"\n{size}, {iters} steps per run\n| skip rule | seconds with | seconds without | without/with | notes |")
    print("|---|---|---|---|---|")
    for k, v in res.items():
        notes = {
            kk: (round(vv, 2) if isinstance(vv, float) else vv)
            for kk, vv in v.items()
            if kk not in ("seconds_with", "seconds_without", "time_ratio_without_over_with")
        }
        print(
            f"| {k} | {v['seconds_with']:.2f} | {v['seconds_without']:.2f} | {v['time_ratio_without_over_with']:.2f} "
            f"| {notes} |"
        )
    print(f"wrote {write_json(args.name, {'size': size, 'iters': iters, 'skip_rules': res})}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
