"""Where ebad departs from the paper, measured: each departure against the paper's choice.

    python -m benchmarks.paper_departures [--quick] [--settings ideal,noisy] [--seeds 0,1,2]
                                          [--iters 600] [--specs SPEC,...] [--refine-iters 150]

The ``ebad`` preset (today's defaults) against the same preset with one option changed:

- ``loss.event_windows=random``: one random pair of the V virtual instants per step for L_ev
  (the paper samples its window start t_s at random), instead of every consecutive pair;
- ``loss.event_norm=l2``: L_ev as the mean squared residual (the paper's) instead of L1;
- ``loss.edi_prior=medi``: the latents of L_EDI from mEDI (all training frames jointly)
  instead of per-frame EDI.

On the ``small`` 160x120 boxes scene of ``scenes.make_scene`` in the settings of
``benchmarks.ablation`` (``ideal``: linear sensor, exact poses held; ``noisy``: the realistic
sensor, noisy given poses, optimised), seeds 0, 1, 2, a fixed step count per run (the options
cost about the same per step; ms/step is reported), scored by ``ebad.evaluate`` (novel views,
test poses refined against their images where the poses are not exact; deblurred training
frames against the sharp truth), mean ± std over seeds. ``prior PSNR`` is the L_EDI latents
(per-frame EDI or mEDI, with the run's estimated c) against the sharp truth: what the prior
itself gives. The JSON is rewritten after every run, so an interrupted run keeps its rows.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ._common import config_spec, seed_all, write_json
from .ablation import SETTINGS, summarise

SPECS = [
    "ebad",
    "ebad+loss.event_windows=random",
    "ebad+loss.event_norm=l2",
    "ebad+loss.edi_prior=medi+loss.edi_instants=mid",
]
KEYS = (
    "test_refined_psnr",
    "test_refined_ssim",
    "deblur_psnr",
    "deblur_ssim",
    "ms_per_step",
    "prior_psnr",
    "prepare_seconds",
)


def prior_psnr(scene, c: tuple[float, float], kind: str) -> float:
    """PSNR of the L_EDI latents (``kind`` edi | medi, threshold pair ``c``) against the sharp truth."""
    import edi
    from ebad.data import _train_indices
    from ebad.evaluate import score_frames

    cap = scene.capture
    idx = _train_indices(cap)
    frames = np.asarray(cap.frames, dtype=np.float32)[idx]
    ex = np.asarray(cap.exposures, dtype=np.float64)[idx]
    if kind == "medi":
        lat = np.asarray(edi.medi(frames, ex, cap.events, c=c)).reshape(frames.shape)
    else:
        lat = np.stack(
            [
                np.asarray(edi.deblur(fr, (t0, t1), cap.events, times=0.5 * (t0 + t1), c=c)).reshape(fr.shape)
                for fr, (t0, t1) in zip(frames, ex)
            ]
        )
    return score_frames(np.clip(lat, 0, 1), np.asarray(scene.gt_frames)[idx]).psnr


def run_one(scene, spec: str, iters: int, seed: int, refine: bool, refine_iters: int) -> dict:
    from ebad.evaluate import evaluate
    from ebad.run import reconstruct

    cfg = config_spec(spec)
    cfg.train.iters, cfg.train.max_seconds = iters, None
    cfg.train.progress, cfg.train.eval_every, cfg.train.seed = False, 0, seed
    t0 = time.perf_counter()
    run = reconstruct(scene.capture, cfg)
    wall = time.perf_counter() - t0
    ev = evaluate(run, scene.capture, refine=refine, gt_frames=scene.gt_frames, refine_iters=refine_iters)
    m = run.metrics
    novel = ev.get("test_refined", ev.get("test"))
    return {
        "preset": spec,
        "seed": seed,
        "steps": m.steps,
        "train_seconds": m.train_seconds,
        "wall_seconds": wall,
        "ms_per_step": 1e3 * m.train_seconds / max(m.steps, 1),
        "prepare_seconds": m.prepare_seconds,
        "gaussians": m.gaussians,
        "c": m.prepare.c,
        "refined": refine,
        "test_psnr": ev["test"].psnr if "test" in ev else None,
        "test_refined_psnr": novel.psnr if novel is not None else None,
        "test_refined_ssim": novel.ssim if novel is not None else None,
        "deblur_psnr": ev["deblurred"].psnr,
        "deblur_ssim": ev["deblurred"].ssim,
        "prior_psnr": prior_psnr(scene, tuple(m.prepare.c), "medi" if "edi_prior=medi" in spec else "edi")
        if m.prepare.c is not None
        else None,
    }


def _summary(rows: list[dict]) -> dict:
    """``ablation.summarise`` plus the keys of this benchmark (ms/step, prior PSNR, prepare time) and,
    for every config but the first of a setting (the baseline), the per-seed paired differences
    config - baseline of novel and deblurred PSNR (mean, std, and the seeds where the config is ahead)."""
    out = summarise(rows)
    for setting, by in out.items():
        base = next(iter(by))
        base_rows = {r["seed"]: r for r in rows if r["setting"] == setting and r["preset"] == base}
        for spec, s in by.items():
            rs = [r for r in rows if r["setting"] == setting and r["preset"] == spec]
            for k in KEYS:
                vals = [r[k] for r in rs if r.get(k) is not None]
                s[k] = (float(np.mean(vals)), float(np.std(vals))) if vals else (None, None)
            for k in ("test_refined_psnr", "deblur_psnr"):
                d = [
                    r[k] - base_rows[r["seed"]][k]
                    for r in rs
                    if r["seed"] in base_rows and r[k] is not None and base_rows[r["seed"]][k] is not None
                ]
                s[f"delta_{k}"] = (
                    (float(np.mean(d)), float(np.std(d)), int(sum(x > 0 for x in d)), len(d))
                    if d
                    else (None, None, 0, 0)
                )
    return out


def print_table(summary: dict) -> None:
    print(
        "| setting | config | novel PSNR dB | Δ novel (seeds ahead) | novel SSIM | deblurred PSNR dB | "
        "Δ deblurred (seeds ahead) | deblurred SSIM | prior PSNR dB | ms/step | prepare s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for setting, by in summary.items():
        for i, (spec, s) in enumerate(by.items()):
            dn, dd = s["delta_test_refined_psnr"], s["delta_deblur_psnr"]

            def fd(d, first=i == 0):
                return "-" if first or d[0] is None else f"{d[0]:+.2f} ± {d[1]:.2f} ({d[2]}/{d[3]})"

            print(
                f"| {setting} | `{spec}` | {_fmt(s['test_refined_psnr'])} | {fd(dn)} | "
                f"{_fmt(s['test_refined_ssim'], 3)} | "
                f"{_fmt(s['deblur_psnr'])} | {fd(dd)} | {_fmt(s['deblur_ssim'], 3)} | {_fmt(s['prior_psnr'])} | "
                f"{_fmt(s['ms_per_step'], 0)} | {_fmt(s['prepare_seconds'], 1)} |"
            )


def _fmt(v: tuple, digits: int = 2) -> str:
    return "-" if v[0] is None else f"{v[0]:.{digits}f} ± {v[1]:.{digits}f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny scene, seed 0, 100 steps")
    ap.add_argument("--settings", default="ideal,noisy")
    ap.add_argument(
        "--specs", default=",".join(SPECS), help="configs (benchmarks._common.config_spec), comma-separated"
    )
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--size", default=None, help="scene size (default small; quick tiny)")
    ap.add_argument("--iters", type=int, default=None, help="steps per run (default 600; quick 100)")
    ap.add_argument("--refine-iters", type=int, default=150, help="test-pose refinement steps at most")
    ap.add_argument("--name", default=None, help="results file benchmarks/results/NAME.json")
    ap.add_argument(
        "--summarise",
        default=None,
        metavar="JSON",
        help="print the table of an earlier run's JSON (and rewrite its summary), without training",
    )
    args = ap.parse_args(argv)
    if args.summarise:
        import json
        from pathlib import Path

        d = json.loads(Path(args.summarise).read_text())
        d["summary"] = _summary(d["rows"])
        d["summarised_from_run_of"] = d.pop("environment", None)  # the environment of the run that trained
        print(
            f"{d['size']} boxes, {d['iters']} steps per run, seeds {d['seeds']}; mean ± std over seeds "
            "(novel views at refined poses in settings without exact poses; "
            f"Δ: paired per seed against {d['specs'][0]})"
        )
        print_table(d["summary"])
        print(f"\nwrote {write_json(Path(args.summarise).stem, d)}")
        return 0
    import scenes

    iters = args.iters if args.iters is not None else (100 if args.quick else 600)
    size = args.size or ("tiny" if args.quick else "small")
    seeds = [0] if args.quick else [int(s) for s in args.seeds.split(",")]
    settings = [s for s in args.settings.split(",") if s]
    specs = [s for s in args.specs.split(",") if s]
    for spec in specs:
        config_spec(spec).check()  # a typo fails before any training
    name = args.name or ("paper_departures_quick" if args.quick else "paper_departures")
    seed_all(0)
    from ebad.run import warm_up

    warm_up(["grey"])  # numba compiles once, outside every spec's budget
    rows: list[dict] = []

    def save():
        return write_json(
            name,
            {
                "size": size,
                "iters": iters,
                "seeds": seeds,
                "refine_iters": args.refine_iters,
                "settings": {k: SETTINGS[k] for k in settings},
                "specs": specs,
                "rows": rows,
                "summary": _summary(rows),
                "argv": sys.argv[1:],
            },
        )

    for setting in settings:
        for seed in seeds:
            sc = scenes.make_scene("boxes", size=size, seed=seed, **SETTINGS[setting])
            refine = SETTINGS[setting]["poses"] != "exact"
            for spec in specs:
                r = run_one(sc, spec, iters, seed, refine, args.refine_iters)
                r.update({"setting": setting, "size": size})
                rows.append(r)
                save()
                print(
                    f"{setting:6s} seed {seed} {spec:34s} novel {r['test_refined_psnr'] or float('nan'):6.2f} dB"
                    f"  deblurred {r['deblur_psnr']:6.2f} dB  prior {r['prior_psnr'] or float('nan'):6.2f} dB"
                    f"  {r['ms_per_step']:6.1f} ms/step  prepare {r['prepare_seconds']:5.1f} s",
                    flush=True,
                )
    print(
        f"\n{size} boxes, {iters} steps per run, seeds {seeds}; mean ± std over seeds "
        f"(novel views at refined poses in settings without exact poses; Δ: paired per seed against {specs[0]})"
    )
    print_table(_summary(rows))
    print(f"\nwrote {save()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
