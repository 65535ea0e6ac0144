"""``ebad demo``: a tiny synthetic blurry event capture, reconstructed with EBAD-Gaussian and
with plain 3DGS on the blurry frames; prints PSNR / SSIM and writes renders and a comparison."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

NAME = "demo"
HELP = "reconstruct a tiny synthetic blurry scene with ebad and with 3dgs, and compare (about 1 minute)"


def add_arguments(parser) -> None:
    parser.add_argument("--out", default="ebad_demo", help="output folder (default ./ebad_demo)")
    parser.add_argument("--scene", default="boxes", help="synthetic scene name (default boxes)")
    parser.add_argument("--rgb", action="store_true", help="a colour scene (default grey, like a DAVIS346)")
    parser.add_argument("--iters", type=int, default=1000, help="optimisation steps per method (default 1000)")
    parser.add_argument("--max-seconds", type=float, default=70.0,
                        help="wall-time cap per method, so the demo ends in time on a busy machine (default 70)")
    parser.add_argument("--seed", type=int, default=0, help="scene seed")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def _upscale(img: np.ndarray, k: int) -> np.ndarray:
    return np.repeat(np.repeat(img, k, 0), k, 1)


def comparison_image(rows: list[list[np.ndarray]], k: int = 4, gap: int = 2) -> np.ndarray:  # -> [H', W', 3] uint8
    """Grid of [H, W, D] images (each upscaled k x, nearest), as 8-bit RGB."""
    out_rows = []
    for row in rows:
        tiles = []
        for img in row:
            im = np.clip(np.asarray(img, dtype=np.float32), 0, 1)
            im = np.repeat(im, 3, -1) if im.shape[-1] == 1 else im
            tiles.append(_upscale(im, k))
            tiles.append(np.ones((tiles[-1].shape[0], gap, 3), np.float32))
        out_rows.append(np.concatenate(tiles[:-1], 1))
        out_rows.append(np.ones((gap, out_rows[-1].shape[1], 3), np.float32))
    grid = np.concatenate(out_rows[:-1], 0)
    return (grid * 255 + 0.5).astype(np.uint8)


def run(args) -> int:
    import torch
    from PIL import Image

    import scenes

    from ..config import preset
    from ..errors import ConfigError
    from ..io import write_png16
    from ..evaluate import score_frames
    from ..runfolder import json_safe, write_run
    from ..trainer import reconstruct, score_views

    if args.iters < 1:
        raise ConfigError(f"--iters must be >= 1, got {args.iters}")
    t_all = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"ebad demo: building the tiny synthetic scene '{args.scene}' ...", flush=True)
    scene = scenes.make_scene(args.scene, size="tiny", seed=args.seed, rgb=args.rgb)
    cap = scene.capture
    print(f"  {cap.num_frames} blurry {cap.width}x{cap.height} frames, {len(cap.events)} events, "
          f"{len(cap.test_views)} held-out views", flush=True)
    views = [v for v in cap.test_views if v.image is not None]
    results, runs = {}, {}
    blurry_scores = score_frames(cap.frames, scene.gt_frames)
    blurry = {"train_psnr": blurry_scores.psnr, "train_ssim": blurry_scores.ssim}
    for name in ("3dgs", "ebad"):
        cfg = preset(name)
        cfg.train.iters = args.iters
        cfg.train.max_seconds = args.max_seconds
        cfg.train.progress = not args.no_progress
        cfg.train.eval_every = max(50, args.iters // 4)
        print(f"  reconstructing with '{name}' ...", flush=True)
        torch.manual_seed(0)
        r = reconstruct(cap, cfg)
        runs[name] = r
        imgs = r.render(np.stack([v.c2w for v in views]))
        test = score_views(imgs, views)
        train = score_frames(r.deblurred_frames(), scene.gt_frames)
        results[name] = {
            "test_psnr": test.psnr, "test_ssim": test.ssim, "train_psnr": train.psnr, "train_ssim": train.ssim,
            "seconds": r.metrics.train_seconds, "steps": r.metrics.steps, "gaussians": r.num_gaussians,
        }
        for v, img in zip(views, imgs):
            write_png16(out / "renders" / name / f"{v.name}.png", img)
        gt_traj = np.stack([scene.gt_trajectory(k, 9) for k in range(cap.num_frames)])
        write_run(r, out / f"run_{name}", gt_trajectories=gt_traj)
    rows = [[v.image, runs["3dgs"].render(v.c2w), runs["ebad"].render(v.c2w)] for v in views]
    db3, dbe = runs["3dgs"].deblurred_frames(), runs["ebad"].deblurred_frames()
    rows += [[cap.frames[k], db3[k], dbe[k], scene.gt_frames[k]] for k in range(min(2, cap.num_frames))]
    width = max(len(r_) for r_ in rows)
    blank = np.ones_like(views[0].image) if views else np.ones_like(cap.frames[0])
    rows = [r_ + [blank] * (width - len(r_)) for r_ in rows]
    Image.fromarray(comparison_image(rows)).save(out / "comparison.png")
    (out / "results.json").write_text(json.dumps(json_safe({"blurry_input": blurry, **results}), indent=2) + "\n")

    print()
    print(f"{'':24s} {'novel views':>20s} {'training frames':>20s}")
    print(f"{'':24s} {'PSNR dB':>10s} {'SSIM':>9s} {'PSNR dB':>10s} {'SSIM':>9s}")
    print(f"{'blurry input':24s} {'-':>10s} {'-':>9s} {blurry['train_psnr']:10.2f} {blurry['train_ssim']:9.3f}")
    for name, label in (("3dgs", "3dgs (blurry frames)"), ("ebad", "ebad (EBAD-Gaussian)")):
        m = results[name]
        print(f"{label:24s} {m['test_psnr']:10.2f} {m['test_ssim']:9.3f} {m['train_psnr']:10.2f} {m['train_ssim']:9.3f}"
              f"   ({m['steps']} steps, {m['seconds']:.0f} s, {m['gaussians']} Gaussians)")
    gain = results["ebad"]["test_psnr"] - results["3dgs"]["test_psnr"]
    print(f"\nebad is {gain:+.2f} dB over 3dgs on novel views.")
    print(f"comparison image: {out / 'comparison.png'}  (rows: test views gt | 3dgs | ebad; "
          f"training frames blurry | 3dgs | ebad | gt)")
    print(f"renders: {out / 'renders'}, run folders: {out / 'run_3dgs'}, {out / 'run_ebad'}")
    print(f"total {time.perf_counter() - t_all:.0f} s")
    return 0
