"""Should the trainer refine the contrast threshold c? The `ebad` preset with c learnt (as
log c, through the event loss) against c fixed at `edi.estimate_c`'s value, equal budgets.

    python -m benchmarks.learn_contrast [--seconds 60] [--size small] [--seed 0] [--sensor realistic]

The true thresholds are read from the synthetic scene's truth for the table only.
"""

from __future__ import annotations

import argparse

from ._common import seed_all, write_json


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="time budget per run")
    ap.add_argument("--size", default="small", choices=["tiny", "small", "davis"])
    ap.add_argument("--sensor", default="realistic", choices=["realistic", "ideal"])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import scenes
    from ebad import preset, reconstruct
    from ebad.evaluate import evaluate
    from ebad.run import warm_up

    warm_up(["grey"])  # numba compiles outside the runs' budgets
    scene = scenes.make_scene("boxes", args.size, seed=args.seed, sensor=args.sensor)
    rows = []
    for learn in (True, False):
        cfg = preset("ebad")
        cfg.train.iters, cfg.train.max_seconds, cfg.train.progress = 100_000, args.seconds, False
        cfg.loss.learn_contrast = learn
        seed_all(0)
        run = reconstruct(scene.capture, cfg)
        ev = evaluate(run, scene.capture, refine=True, gt_frames=scene.gt_frames)
        rows.append(
            {
                "learn_contrast": learn,
                "test_refined_psnr": ev["test_refined"].psnr,
                "deblur_psnr": ev["deblurred"].psnr,
                "steps": run.metrics.steps,
                "c_start": run.metrics.prepare.c,
                "c_final": run.metrics.c_final,
                "c_true": scene.truth["c"],
            }
        )
    print(
        "| c | novel PSNR dB (refined) | deblurred PSNR dB | steps | "
        f"c_pos/c_neg start -> end (true {rows[0]['c_true']}) |"
    )
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {'learnt' if r['learn_contrast'] else 'fixed'} | {r['test_refined_psnr']:.2f} | "
            f"{r['deblur_psnr']:.2f} | "
            f"{r['steps']} | {r['c_start'][0]:.3f}/{r['c_start'][1]:.3f} -> "
            f"{r['c_final'][0]:.3f}/{r['c_final'][1]:.3f} |"
        )
    print(f"wrote {write_json('learn_contrast', {'args': vars(args), 'rows': rows})}")


if __name__ == "__main__":
    main()
