"""Where a training step's time goes at the sensor's size: the rasteriser against everything else.

    python -m benchmarks.step_profile [--quick] [--size davis] [--modes realistic] [--presets ebad,bad,3dgs]
                                      [--iters 400]

Each preset trains ``--iters`` steps on ``scenes.make_scene("boxes", SIZE)`` (settings of
``benchmarks.time_to_quality``: ``ideal`` linear sensor, exact poses held; ``realistic`` the
realistic sensor, noisy given poses optimised), and every step records where its time went
(``StepStats.profile``, averaged by ``ebad.loop.step_profile``): the forward, and inside it
the trajectory poses, the rasteriser's own forward (project, bin, composite) and the losses
(response, L1 + SSIM, L_ev); the backward and the rasteriser's backward inside it; Adam;
densification. The share outside the rasteriser is 1 - (rasteriser forward + backward) / step.
Steps at the coarse phase's half resolution and at full resolution are reported apart, and
``run`` is every step together: its share is the fraction of the run's step time outside the
rasteriser. The first 20 steps (numba's first calls, torch's warm-up) are left out.
"""

from __future__ import annotations

import argparse
import sys

from ._common import config_spec, seed_all, write_json
from .time_to_quality import MODES, parse_modes

WARMUP_STEPS = 20
PARTS = ("step", "forward", "poses", "raster_forward", "losses", "backward", "raster_backward", "adam", "densify")
LEVELS = ("coarse", "full", "run")


def profile_run(scene, spec: str, iters: int, seed: int) -> dict:
    from ebad.loop import step_profile
    from ebad.run import reconstruct

    cfg = config_spec(spec)
    cfg.train.iters, cfg.train.max_seconds = iters, None
    cfg.train.progress, cfg.train.eval_every, cfg.train.seed = False, 0, seed
    run = reconstruct(scene.capture, cfg)
    steps = run.history[WARMUP_STEPS:]
    out = {"preset": spec, "steps": run.metrics.steps, "gaussians": run.metrics.gaussians, "width": run.width}
    keep = {"coarse": lambda h: h.width != run.width, "full": lambda h: h.width == run.width, "run": lambda h: True}
    for level in LEVELS:
        out[level] = step_profile([h for h in steps if keep[level](h)])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.step_profile", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny scene, 60 steps")
    ap.add_argument("--size", default=None, help="scene size (default davis; quick tiny)")
    ap.add_argument("--modes", default="realistic")
    ap.add_argument("--presets", default="ebad,bad,3dgs")
    ap.add_argument("--iters", type=int, default=None, help="steps per run (default 400; quick 60)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--name", default=None, help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import scenes

    size = args.size or ("tiny" if args.quick else "davis")
    iters = args.iters or (60 if args.quick else 400)
    modes = parse_modes(ap, args.modes)
    results = {}
    print(
        f"step profile at size {size}, {iters} steps per run (the first {WARMUP_STEPS} left out), seed {args.seed}; "
        "ms per step"
    )
    print(
        f"{'mode':10s} {'preset':8s} {'level':6s} {'steps':>5s} "
        + " ".join(f"{p:>15s}" for p in PARTS)
        + f" {'outside share':>13s}"
    )
    for mode in modes:
        seed_all(args.seed)
        scene = scenes.make_scene("boxes", size, seed=args.seed, **MODES[mode])
        for spec in [p for p in args.presets.split(",") if p]:
            r = profile_run(scene, spec, iters, args.seed)
            results.setdefault(mode, []).append(r)
            for level in LEVELS:
                p = r[level]
                if p is None:
                    continue
                print(
                    f"{mode:10s} {spec:8s} {level:6s} {p['steps']:5d} "
                    + " ".join(f"{p[k]:15.1f}" for k in PARTS)
                    + f" {p['outside_share']:13.2f}",
                    flush=True,
                )
    name = args.name or ("step_profile_quick" if args.quick else "step_profile")
    write_json(
        name,
        {
            "size": size,
            "iters": iters,
            "seed": args.seed,
            "warmup_steps": WARMUP_STEPS,
            "modes": {m: MODES[m] for m in modes},
            "results": results,
            "argv": sys.argv[1:] if argv is None else list(argv),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
