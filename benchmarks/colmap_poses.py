"""SfM (pycolmap, CPU) pose accuracy: synthetic blurry captures with no truth in the pipeline,
and the slider_depth frames against their ground-truth poses.

    python -m benchmarks.colmap_poses [--sizes tiny,small] [--seeds 0,1,2] [--sensors realistic,ideal]
                                      [--frames 12] [--test-views 3] [--colours grey,cfa,raw]
                                      [--slider-steps 2,4 | --no-slider] [--out benchmarks/results/colmap_poses.json]

Synthetic rows: ``scenes.make_scene(..., poses="none")`` (the capture carries no pose at all,
neither for its frames nor for its test views) and ``scenes.colmap.estimate_poses`` on

- the blurry frames as recorded ("blurry"),
- EDI-deblurred frames with one contrast threshold estimated from the capture ("edi c", the default),
- EDI-deblurred frames with c_pos, c_neg estimated from the capture ("edi c+-"),
- on colour DAVIS captures (``--colours cfa``: RGGB, demosaiced RGB frames; ``raw``: the raw mosaics), the
  capture with its filter not stated ("edi luma": events taken as the luminance, raw mosaics as grey
  images), against "edi c" that deblurs per pixel of the mosaic and demosaics raw frames for SIFT,

with the test images registered by the same SfM. Nothing of the truth (c, response, poses)
reaches ``estimate_poses``: the truth is used afterwards only, to score. The estimate is
aligned to the true mid-exposure poses by ``align_similarity`` (Sim(3)); ATE is the RMSE of
camera centres in % of the trajectory extent; the test views are moved by the same Sim(3) and
scored the same way. One thread per SfM (deterministic). Writes JSON.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
SLIDER = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "slider_depth"
INPUTS = {
    "blurry": dict(deblur=False),
    "edi c": dict(deblur=True, c_polarity=False),
    "edi c+-": dict(deblur=True, c_polarity=True),
    "edi luma": dict(deblur=True, c_polarity=False),  # the capture's cfa removed (colour captures only)
}
COLOURS = {"grey": {}, "cfa": dict(rgb=True, cfa="RGGB"), "raw": dict(rgb=True, cfa="RGGB", raw_frames=True)}


def synthetic_row(sc, size: str, seed: int, sensor: str, inp: str, threads: int, colour: str = "grey") -> dict:
    import dataclasses

    from scenes.colmap import (
        ColmapConfig,
        SfMError,
        align_similarity,
        apply_similarity,
        choose_matcher,
        estimate_poses,
        pose_errors,
        rotation_errors_deg,
    )

    cap, name = sc.capture, sc.name
    if inp == "edi luma":
        cap = dataclasses.replace(cap, cfa=None)
    row = {
        "colour": colour,
        "scene": name,
        "size": size,
        "seed": seed,
        "sensor": sensor,
        "input": inp,
        "frames": cap.num_frames,
        "test_views": len(cap.test_views),
        "matcher": choose_matcher(ColmapConfig(), cap.num_frames + len(cap.test_views)),
    }
    t0 = time.perf_counter()
    try:
        est = estimate_poses(cap, ColmapConfig(num_threads=threads, **INPUTS[inp]))
    except SfMError as exc:
        return dict(row, error=str(exc), time_s=time.perf_counter() - t0)
    row["time_s"] = time.perf_counter() - t0
    reg = est.registered
    e = pose_errors(est.c2w[reg], sc.gt_c2w[reg])
    ext = e["trajectory_extent"]
    row.update(
        registered=int(reg.sum()),
        points=len(est.points),
        c_estimated=est.report.get("c_estimated"),
        c_true=[sc.sensor.c_pos, sc.sensor.c_neg],
        ate_pct=100 * e["ate_rmse"] / ext,
        rot_mean_deg=e["rot_mean_deg"],
        rot_max_deg=e["rot_max_deg"],
        test_registered=len(est.test_c2w),
    )
    if est.test_c2w:
        s, r, t = align_similarity(est.c2w[reg], sc.gt_c2w[reg])
        names = [tv.name for tv in cap.test_views]
        j = [i for i, n in enumerate(names) if n in est.test_c2w]
        test = apply_similarity(np.stack([est.test_c2w[names[i]] for i in j]), s, r, t)
        pos = np.linalg.norm(test[:, :3, 3] - sc.gt_test_c2w[j, :3, 3], axis=1)
        row.update(
            test_pos_pct=float(100 * np.sqrt((pos**2).mean()) / ext),
            test_rot_deg=float(rotation_errors_deg(sc.gt_test_c2w[j], test).mean()),
        )
    return row


def slider_rows(steps: list[int], threads: int) -> list[dict]:
    import scenes
    from scenes.colmap import ColmapConfig, SfMError, estimate_poses, pose_errors

    cap = scenes.load(SLIDER)
    rows = []
    for step in steps:
        idx = list(range(0, cap.num_frames, step))
        t0 = time.perf_counter()
        try:
            est = estimate_poses(cap, ColmapConfig(num_threads=threads), frames=idx)
        except SfMError as exc:
            rows.append({"step": step, "frames": len(idx), "error": str(exc), "time_s": time.perf_counter() - t0})
            continue
        reg = est.registered
        e = pose_errors(est.c2w[reg], cap.c2w[idx][reg])
        rows.append(
            {
                "step": step,
                "frames": len(idx),
                "registered": int(reg.sum()),
                "points": len(est.points),
                "ate_m": e["ate_rmse"],
                "ate_pct": 100 * e["ate_rmse"] / e["trajectory_extent"],
                "rot_mean_deg": e["rot_mean_deg"],
                "reproj_px": est.report["mean_reprojection_error_px"],
                "time_s": time.perf_counter() - t0,
            }
        )
    return rows


def _mean_std(v: list[float]) -> str:
    a = np.asarray(v, float)
    return f"{a.mean():6.2f} ± {a.std():4.2f}" if len(a) else "     -"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="tiny,small", help="synthetic sizes, comma separated")
    ap.add_argument("--scenes", default="boxes,spheres")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--sensors", default="realistic,ideal")
    ap.add_argument("--inputs", default=",".join(INPUTS), help=f"comma separated, of {list(INPUTS)}")
    ap.add_argument("--colours", default="grey", help=f"comma separated, of {list(COLOURS)}")
    ap.add_argument("--frames", default="12", help="training frames per capture, comma separated (issue 31: 30,40)")
    ap.add_argument("--test-views", type=int, default=3, help="held-out views per capture, registered with them")
    ap.add_argument("--threads", type=int, default=1, help="COLMAP threads (1: deterministic)")
    ap.add_argument("--slider-steps", default="2,4", help="slider_depth frame steps")
    ap.add_argument("--no-slider", dest="slider", action="store_false")
    ap.add_argument("--out", default=str(RESULTS / "colmap_poses.json"))
    args = ap.parse_args(argv)
    split = lambda s: [x for x in s.split(",") if x]  # noqa: E731
    import scenes

    rows = []
    for size in split(args.sizes):
        for sensor in split(args.sensors):
            for name, colour in itertools.product(split(args.scenes), split(args.colours)):
                for seed, n in itertools.product((int(s) for s in split(args.seeds)), map(int, split(args.frames))):
                    sc = scenes.make_scene(
                        name,
                        size,
                        seed=seed,
                        sensor=sensor,
                        poses="none",
                        n_frames=n,
                        n_test=args.test_views,
                        **COLOURS[colour],
                    )
                    for inp in split(args.inputs):
                        if inp == "edi luma" and colour == "grey":
                            continue  # no filter to leave out: "edi c"
                        r = synthetic_row(sc, size, seed, sensor, inp, args.threads, colour)
                        rows.append(r)
                        print(
                            json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}),
                            flush=True,
                        )
    print(
        f"\nSfM on synthetic blurry captures without poses ({args.frames} frames + {args.test_views} test views "
        "registered together); mean ± std over scenes and seeds"
    )
    print(
        f"{'size':>6} {'frames':>6} {'sensor':>9} {'colour':>6} {'input':>8} {'runs':>4} {'failed':>6} {'reg %':>6} "
        f"{'ATE %':>14} {'rot deg':>14} "
        f"{'test pos %':>14} {'test rot deg':>14} {'time s':>7}"
    )
    summary = []
    for size, n in itertools.product(split(args.sizes), map(int, split(args.frames))):
        for sensor, colour in itertools.product(split(args.sensors), split(args.colours)):
            for inp in split(args.inputs):
                sel = [
                    r
                    for r in rows
                    if (r["size"], r["frames"], r["sensor"], r["colour"], r["input"]) == (size, n, sensor, colour, inp)
                ]
                if not sel:
                    continue
                ok = [r for r in sel if "error" not in r]
                tst = [r for r in ok if "test_pos_pct" in r]
                s = {
                    "size": size,
                    "frames": n,
                    "sensor": sensor,
                    "colour": colour,
                    "input": inp,
                    "runs": len(sel),
                    "registered_pct": [
                        100 * (r["registered"] + r["test_registered"]) / (r["frames"] + r["test_views"]) for r in ok
                    ],
                    "failed": len(sel) - len(ok),
                    "ate_pct": [r["ate_pct"] for r in ok],
                    "rot_deg": [r["rot_mean_deg"] for r in ok],
                    "test_pos_pct": [r["test_pos_pct"] for r in tst],
                    "test_rot_deg": [r["test_rot_deg"] for r in tst],
                    "time_s": [r["time_s"] for r in ok],
                }
                summary.append(s)
                print(
                    f"{size:>6} {n:>6} {sensor:>9} {colour:>6} {inp:>8} {len(sel):>4} {s['failed']:>6} "
                    f"{np.mean(s['registered_pct']) if ok else float('nan'):>6.1f} {_mean_std(s['ate_pct']):>14} "
                    f"{_mean_std(s['rot_deg']):>14} {_mean_std(s['test_pos_pct']):>14} "
                    f"{_mean_std(s['test_rot_deg']):>14} {np.mean(s['time_s']) if ok else float('nan'):>7.1f}"
                )
    slider = []
    if args.slider and SLIDER.is_dir():
        slider = slider_rows([int(s) for s in split(args.slider_steps)], args.threads)
        print("\nSfM on slider_depth (default settings: EDI frames, one c), similarity-aligned to ground truth")
        print(f"{'step':>4} {'frames':>6} {'reg':>4} {'ATE m':>8} {'ATE %':>6} {'rot deg':>8} {'time s':>7}")
        for r in slider:
            if "error" in r:
                print(f"{r['step']:>4} {r['frames']:>6}  FAILED: {r['error']}")
            else:
                print(
                    f"{r['step']:>4} {r['frames']:>6} {r['registered']:>4} {r['ate_m']:>8.4f} {r['ate_pct']:>6.2f} "
                    f"{r['rot_mean_deg']:>8.3f} {r['time_s']:>7.1f}"
                )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "rows": rows, "summary": summary, "slider": slider}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
