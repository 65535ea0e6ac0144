"""SfM (pycolmap, CPU) on the slider_depth frames against the ground-truth poses.

    python benchmarks/colmap_poses.py [--steps 1,2,4] [--no-synthetic] [--out bench_out/colmap_poses.json]

Runs ``scenes.colmap.estimate_poses`` on every ``step``-th frame (several steps by default),
aligns the estimate to the ground truth with a similarity transform and prints ATE (metres
and % of the 1 m slide) and rotation error (degrees), with the time taken. Then the same on
synthetic blurry captures (``scenes.make_scene``), once on the blurry frames and once on
EDI-deblurred ones. Writes JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

# running as a script puts benchmarks/ first on sys.path, where benchmarks/edi.py would
# shadow the edi package: drop it
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

SLIDER = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "slider_depth"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(SLIDER), help="an Event Camera Dataset folder (default slider_depth)")
    ap.add_argument("--steps", default="1,2,4", help="frame subsampling steps to run, comma separated")
    ap.add_argument("--matcher", default="auto", choices=["auto", "sequential", "exhaustive"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="bench_out/colmap_poses.json")
    ap.add_argument("--no-synthetic", dest="synthetic", action="store_false",
                    help="skip the synthetic rows (blurry versus EDI-deblurred frames)")
    ap.add_argument("--synthetic-size", default="small", choices=["tiny", "small", "davis"])
    args = ap.parse_args(argv)

    import scenes
    from scenes.colmap import ColmapConfig, SfMError, estimate_poses, pose_errors

    cap = scenes.load(args.data)
    if cap.c2w is None:
        raise SystemExit(f"{args.data}: no ground-truth poses")
    rows = []
    for step in (int(s) for s in args.steps.split(",")):
        idx = list(range(0, cap.num_frames, step))
        cfg = ColmapConfig(matcher=args.matcher, num_threads=args.threads)
        t0 = time.perf_counter()
        try:
            est = estimate_poses(cap, cfg, frames=idx)
        except SfMError as exc:
            rows.append({"step": step, "frames": len(idx), "error": str(exc), "time_s": time.perf_counter() - t0})
            continue
        wall = time.perf_counter() - t0
        reg = est.registered
        e = pose_errors(est.c2w[reg], cap.c2w[idx][reg])
        rows.append({"step": step, "frames": len(idx), "registered": int(reg.sum()), "points": len(est.points),
                     "ate_rmse_m": e["ate_rmse"], "ate_max_m": e["ate_max"],
                     "ate_pct_of_extent": 100 * e["ate_rmse"] / e["trajectory_extent"],
                     "rot_mean_deg": e["rot_mean_deg"], "rot_max_deg": e["rot_max_deg"],
                     "reproj_px": est.report["mean_reprojection_error_px"], "matcher": est.report["matcher"],
                     "time_s": wall, "time_features_s": est.report["time_features_s"],
                     "time_matching_s": est.report["time_matching_s"],
                     "time_mapping_s": est.report["time_mapping_s"]})
    hdr = f"{'step':>4} {'frames':>6} {'reg':>4} {'points':>6} {'ATE m':>8} {'ATE %':>6} {'rot deg':>8} " \
          f"{'rot max':>8} {'reproj':>6} {'time s':>7}"
    print(f"SfM on {args.data} ({cap.width}x{cap.height}, {cap.num_frames} frames), similarity-aligned to ground truth")
    print(hdr)
    for r in rows:
        if "error" in r:
            print(f"{r['step']:>4} {r['frames']:>6}  FAILED: {r['error']}")
            continue
        print(f"{r['step']:>4} {r['frames']:>6} {r['registered']:>4} {r['points']:>6} {r['ate_rmse_m']:>8.4f} "
              f"{r['ate_pct_of_extent']:>6.2f} {r['rot_mean_deg']:>8.3f} {r['rot_max_deg']:>8.3f} "
              f"{r['reproj_px']:>6.3f} {r['time_s']:>7.1f}")
    syn_rows = []
    if args.synthetic:
        for name in ("boxes", "spheres"):
            sc = scenes.make_scene(name, args.synthetic_size, n_frames=12, seed=0)
            for deblur in (False, True):
                t0 = time.perf_counter()
                row = {"scene": name, "size": args.synthetic_size, "frames": sc.capture.num_frames,
                       "input": "EDI-deblurred" if deblur else "blurry"}
                try:
                    est = estimate_poses(sc.capture, ColmapConfig(deblur=deblur, num_threads=args.threads))
                except SfMError as exc:
                    row.update(error=str(exc), time_s=time.perf_counter() - t0)
                    syn_rows.append(row)
                    continue
                reg = est.registered
                e = pose_errors(est.c2w[reg], sc.capture.c2w[reg])
                row.update(registered=int(reg.sum()), points=len(est.points), ate_rmse=e["ate_rmse"],
                           ate_pct_of_extent=100 * e["ate_rmse"] / e["trajectory_extent"],
                           rot_mean_deg=e["rot_mean_deg"], rot_max_deg=e["rot_max_deg"],
                           time_s=time.perf_counter() - t0)
                syn_rows.append(row)
        print(f"\nSfM on synthetic blurry captures (shake 1, c = 0.2), blurry frames versus EDI-deblurred")
        print(f"{'scene':>8} {'input':>14} {'frames':>6} {'reg':>4} {'points':>6} {'ATE %':>6} {'rot deg':>8} "
              f"{'rot max':>8} {'time s':>7}")
        for r in syn_rows:
            if "error" in r:
                print(f"{r['scene']:>8} {r['input']:>14} {r['frames']:>6}  FAILED: {r['error']}")
                continue
            print(f"{r['scene']:>8} {r['input']:>14} {r['frames']:>6} {r['registered']:>4} {r['points']:>6} "
                  f"{r['ate_pct_of_extent']:>6.2f} {r['rot_mean_deg']:>8.3f} {r['rot_max_deg']:>8.3f} {r['time_s']:>7.1f}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"data": args.data, "rows": rows, "synthetic": syn_rows}, indent=1))
    print(f"wrote {out}")
    return 0 if all("error" not in r for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
