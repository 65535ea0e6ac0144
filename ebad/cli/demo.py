"""``ebad demo``: a synthetic blurry event capture from a realistic camera, reconstructed with
EBAD-Gaussian and with plain 3DGS (poses optimised too) on the blurry frames, equal time each;
scored by the evaluation protocol; prints PSNR / SSIM and writes renders and a comparison.

The capture goes to ``OUT/capture`` and each method's run folder (``OUT/run_3dgs``, ``OUT/run_ebad``)
is an ordinary one, checkpoint included: ``ebad eval``, ``render``, ``view`` and ``reconstruct
OUT/capture --out OUT/run_ebad --resume`` take it."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

if TYPE_CHECKING:
    from ..run import CaptureKind

NAME = "demo"
HELP = "reconstruct a synthetic blurry scene with ebad and with 3dgs, and compare (about 3 minutes)"

METHODS = (("3dgs", "3dgs (blurry frames)"), ("ebad", "ebad (EBAD-Gaussian)"))
RGB_CFA = "RGGB"  # the Bayer filter of the colour DAVIS346 that ``--rgb`` simulates


@dataclass
class Args:
    out: str = "ebad_demo"
    """output folder"""
    scene: str = "boxes"
    """synthetic scene name"""
    size: Literal["tiny", "small", "davis"] = "small"
    """frame size: tiny 64x48, small 160x120, davis 346x260"""
    sensor: Literal["realistic", "ideal"] = "realistic"
    """the simulated camera (realistic: non-linear APS, noisy thresholds and poses)"""
    rgb: bool = False
    (
        "a colour DAVIS346 instead of a grey one: an RGGB Bayer filter over the frame and event pixels (each pixel's "
        "events fire on its own channel), RGB frames demosaiced by the camera software"
    )
    seconds: float = 30.0
    """training time per method (50 s: ebad about 0.25 dB higher, the demo 40 s longer)"""
    iters: int = 100_000
    """at most this many steps per method"""
    seed: int = 0
    """scene seed"""
    no_progress: bool = False
    """no progress bars"""


def _upscale(img: np.ndarray, k: int) -> np.ndarray:
    return np.repeat(np.repeat(img, k, 0), k, 1)


def _label_strip(labels: list[str], tile_w: int, gap: int, width: int) -> np.ndarray:  # -> [h, width, 3] in [0, 1]
    """A white strip with each column's label in black at its tile's left edge (Pillow's default font)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default()
    h = int(font.getbbox("Ag")[3]) + 4
    im = Image.new("L", (width, h), 255)
    draw = ImageDraw.Draw(im)
    for i, text in enumerate(labels):
        draw.text((i * (tile_w + gap) + 2, 2), text, fill=0, font=font)
    return np.repeat(np.asarray(im, np.float32)[..., None] / 255.0, 3, -1)


def comparison_image(
    rows: list[list[np.ndarray]], k: int = 4, gap: int = 2, headers: dict[int, list[str]] | None = None
) -> np.ndarray:  # -> [H', W', 3] uint8
    """Grid of [H, W, D] images in [0, 1] as the camera records them (each upscaled k x, nearest),
    as 8-bit RGB (values shown as they are: the recorded values already carry the camera's response).
    ``headers[i]``: the column labels drawn in a strip above row i."""
    out_rows = []
    for i, row in enumerate(rows):
        if headers and i in headers:
            tile_w = row[0].shape[1] * k
            width = len(row) * tile_w + (len(row) - 1) * gap
            out_rows.append(_label_strip(headers[i], tile_w, gap, width))
        tiles = []
        for img in row:
            im = np.clip(np.asarray(img, dtype=np.float32), 0, 1)
            im = np.repeat(im, 3, -1) if im.shape[-1] == 1 else im
            tiles.append(_upscale(im, k))
            tiles.append(np.ones((tiles[-1].shape[0], gap, 3), np.float32))
        out_rows.append(np.concatenate(tiles[:-1], 1))
        out_rows.append(np.ones((gap, out_rows[-1].shape[1], 3), np.float32))
    return (np.concatenate(out_rows[:-1], 0) * 255 + 0.5).astype(np.uint8)


def run(args: Args) -> int:
    from ..errors import ConfigError
    from ..precompile import Precompile

    if args.iters < 1:
        raise ConfigError(f"--iters must be >= 1, got {args.iters}")
    if not args.seconds > 0:
        raise ConfigError(f"--seconds must be > 0, got {args.seconds:g}")
    t_all = time.perf_counter()
    kinds: list[CaptureKind] = ["cfa" if args.rgb else "grey"]
    # on a cold cache numba compiles in two child processes from here on, while this one imports and builds the scene
    with Precompile(kinds) as pre:
        from PIL import Image

        import scenes

        from ..config import preset, save_config
        from ..evaluate import evaluate, score_frames
        from ..export import write_render
        from ..run import reconstruct, warm_up
        from ..runfolder import json_safe, write_run

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        camera = f"{args.sensor} colour DAVIS ({RGB_CFA})" if args.rgb else f"{args.sensor} camera"
        print(f"ebad demo: building the synthetic scene '{args.scene}' ({args.size}, {camera}) ...", flush=True)
        cfa = RGB_CFA if args.rgb else None
        scene = scenes.make_scene(args.scene, size=args.size, seed=args.seed, rgb=args.rgb, sensor=args.sensor, cfa=cfa)
        cap = scene.capture
        scenes.save(cap, out / "capture", overwrite=True)  # what the run folders were made from (eval, --resume)
        print(
            f"  {cap.num_frames} blurry {cap.width}x{cap.height} frames, {len(cap.events)} events, "
            f"{len(cap.test_views)} held-out views, poses given: {cap.effective_pose_trust}",
            flush=True,
        )
        if pre.started:
            print("  compiling numba's kernels in two processes (a first run only) ...", end=" ", flush=True)
            seconds = pre.wait()
            failed = f" ({pre.failure}: compiled below)" if pre.failed else ""
            print(f"{seconds:.0f} s from the start{failed}", flush=True)
    print("  loading numba's kernels, outside both methods' time ...", end=" ", flush=True)
    print(f"{warm_up(kinds):.0f} s", flush=True)  # compiles what no child did (when none failed: loads them all)
    results, runs = {}, {}
    blurry_scores = score_frames(cap.frames, scene.gt_frames)  # SSIM's kernel: loaded by warm_up, not compiled twice
    blurry = {"train_psnr": blurry_scores.psnr, "train_ssim": blurry_scores.ssim}
    refine = cap.effective_pose_trust != "exact"
    for name, _ in METHODS:
        cfg = preset(name)
        cfg.train.iters = args.iters
        cfg.train.max_seconds = args.seconds
        cfg.train.progress = not args.no_progress
        cfg.train.eval_every = 0
        print(f"  reconstructing with '{name}' for {args.seconds:g} s ...", flush=True)
        run_dir = out / f"run_{name}"  # an ordinary run folder, as `ebad reconstruct` writes it
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / "metrics.json").unlink(missing_ok=True)  # unfinished until write_run ends
        save_config(cfg, run_dir / "config.json")
        r = reconstruct(cap, cfg, out_dir=run_dir)  # checkpoints/last.pt
        assert r.metrics is not None  # reconstruct() always sets the metrics
        runs[name] = r
        renders: dict[str, np.ndarray] = {}
        ev = evaluate(
            r, cap, refine=refine, gt_frames=scene.gt_frames, renders_to=renders.__setitem__, show=not args.no_progress
        )
        test = ev["test_refined" if refine else "test"]
        results[name] = {
            "test_psnr": test.psnr,
            "test_ssim": test.ssim,
            "train_psnr": ev["deblurred"].psnr,
            "train_ssim": ev["deblurred"].ssim,
            "seconds": r.metrics.train_seconds,
            "steps": r.metrics.steps,
            "gaussians": r.num_gaussians,
            "renders": renders,
        }
        for view_name, img in renders.items():
            write_render(out / "renders" / name / f"{view_name}.png", img, 8)
        gt_traj = np.stack([scene.gt_trajectory(k, 9) for k in range(cap.num_frames)])
        write_run(r, run_dir, gt_trajectories=gt_traj)
    assert scene.gt_test_images is not None  # make_scene always sets it
    truth = {v.name: scene.gt_test_images[j] for j, v in enumerate(cap.test_views)}  # noise-free, for display
    rows = [[truth[n]] + [results[m]["renders"][n] for m, _ in METHODS] for n in results["ebad"]["renders"]]
    db = {n: runs[n].deblurred_frames() for n, _ in METHODS}
    rows += [
        [cap.frames[k]] + [db[n][k] for n, _ in METHODS] + [scene.gt_frames[k]] for k in range(min(2, cap.num_frames))
    ]
    width = max(len(r_) for r_ in rows)
    blank = np.ones_like(cap.frames[0])
    n_test = len(results["ebad"]["renders"])
    rows = [r_ + [blank] * (width - len(r_)) for r_ in rows]
    headers = {0: ["test view: truth"] + [label for _, label in METHODS]}
    if len(rows) > n_test:
        headers[n_test] = ["training frame: blurry input"] + [label for _, label in METHODS] + ["truth"]
    grid = comparison_image(rows, k=4 if cap.width <= 64 else 2, headers=headers)
    Image.fromarray(grid).save(out / "comparison.png")
    for res in results.values():
        res.pop("renders")
    (out / "results.json").write_text(
        json.dumps(json_safe({"blurry_input": blurry, "test_poses_refined": refine, **results}), indent=2) + "\n"
    )

    print()
    print(f"{'':24s} {'novel views':>20s} {'training frames':>20s}")
    print(f"{'':24s} {'PSNR dB':>10s} {'SSIM':>9s} {'PSNR dB':>10s} {'SSIM':>9s}")
    print(f"{'blurry input':24s} {'-':>10s} {'-':>9s} {blurry['train_psnr']:10.2f} {blurry['train_ssim']:9.3f}")
    for name, label in METHODS:
        m = results[name]
        print(
            f"{label:24s} {m['test_psnr']:10.2f} {m['test_ssim']:9.3f} {m['train_psnr']:10.2f} {m['train_ssim']:9.3f}"
            f"   ({m['steps']} steps, {m['seconds']:.0f} s, {m['gaussians']} Gaussians)"
        )
    gain = results["ebad"]["test_psnr"] - results["3dgs"]["test_psnr"]
    print(
        f"\nebad is {gain:+.2f} dB over 3dgs on novel views"
        + (" (test poses refined against their images, scene frozen)." if refine else ".")
    )
    print(
        f"comparison image: {out / 'comparison.png'}  (rows: test views truth | 3dgs | ebad; "
        f"training frames blurry | 3dgs | ebad | truth)"
    )
    print(
        f"renders: {out / 'renders'}, run folders: {out / 'run_3dgs'}, {out / 'run_ebad'} "
        f"(made from the capture {out / 'capture'})"
    )
    print(f"total {time.perf_counter() - t_all:.0f} s")
    return 0
