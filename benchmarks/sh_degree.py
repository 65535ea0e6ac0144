"""Benchmark view-dependent colour: spherical harmonics of degree 3 against degree 0 (issue 29, section 3).

    python -m benchmarks.sh_degree [--quick] [--scene glossy] [--seconds 150] [--seeds 0 1 2]

1. The rasteriser's step: forward + backward of ``ebad.gaussians.render`` (the call a training step makes,
   coefficients assembled from the model's parameters) at 346 x 260 with 20k Gaussians, one camera and the V = 5
   virtual views of an exposure, grey (D = 1) and colour (D = 3): degree 0 (one colour per Gaussian, today's path)
   against degree 3 (16 coefficients per channel evaluated per camera). Medians of interleaved repetitions, so
   that load on the machine hits both alike. Target: degree 3 at most 1.5x the degree-0 step.
2. A short reconstruction at equal time, degree 0 against degree 3 (``--model.sh_degree``), on
   ``scenes.make_scene(SCENE, ...)``: novel-view PSNR on the test views at their exact poses, the number of steps
   and the step time. The scene is a parameter: a view-dependent (glossy) one is the fair test; "boxes" when the
   glossy scene does not exist in this checkout.

Writes ``benchmarks/results/sh_degree.json`` (``--quick``: ``sh_degree_quick.json``) and prints both tables.
``--quick`` is a smoke run at small sizes (its numbers mean nothing).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from benchmarks._common import seed_all, write_json

DEGREES = (0, 3)


def _params(n: int, d: int, degree: int, width: int, height: int, seed: int = 0):
    """n Gaussians filling the frustum of a camera at the origin looking down +z (as benchmarks.rasterize), with
    random SH coefficients of ``degree``."""
    import torch
    from torch import nn

    from ebad.gaussians import init_params, resize_sh

    g = torch.Generator().manual_seed(seed)
    f = 0.87 * width
    z = 2.0 + 4.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.1 - 0.05) * width
    v = (torch.rand(n, generator=g) * 1.1 - 0.05) * height
    pts = torch.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], -1)
    scales = torch.exp(torch.empty(n).uniform_(math.log(0.01), math.log(0.1), generator=g))
    params = init_params(pts, torch.rand(n, d, generator=g), scales=scales, opacity=0.5)
    with torch.no_grad():
        params["quats"].copy_(torch.randn(n, 4, generator=g))
        params["opacities"].uniform_(-3.0, 3.0, generator=g)
    resize_sh(params, degree)
    if degree:
        params["sh_rest"] = nn.Parameter(0.1 * torch.randn(params["sh_rest"].shape, generator=g))
    return params, torch.tensor([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])


def raster_step(n: int, width: int, height: int, d: int, cams: int, reps: int) -> dict:
    """Median ms of forward + backward of ``ebad.gaussians.render`` at degrees 0 and 3, interleaved."""
    import torch

    from ebad.gaussians import render

    c2w = torch.eye(4)[None].repeat(cams, 1, 1)
    c2w[:, 0, 3] = 0.01 * torch.arange(cams)  # the virtual views of one exposure: small translations
    setups = {deg: _params(n, d, deg, width, height) for deg in DEGREES}

    def step(deg: int) -> float:
        params, K = setups[deg]
        for p in params.values():
            p.grad = None
        t = time.perf_counter()
        img, alpha, _ = render(params, c2w, K, width, height)
        torch.autograd.backward((img, alpha), (torch.ones_like(img), torch.ones_like(alpha)))
        return 1e3 * (time.perf_counter() - t)

    for deg in DEGREES:  # warm-up: loads (or compiles) the kernels
        step(deg)
    times: dict[int, list[float]] = {deg: [] for deg in DEGREES}
    for _ in range(reps):
        for deg in DEGREES:
            times[deg].append(step(deg))
    med = {deg: statistics.median(ts) for deg, ts in times.items()}
    return {
        "n": n,
        "width": width,
        "height": height,
        "d": d,
        "cams": cams,
        "reps": reps,
        "ms_degree0": med[0],
        "ms_degree3": med[3],
        "ratio": med[3] / med[0],
    }


def reconstruction(scene_name: str, size: str, seconds: float, seed: int, degree: int, rgb: bool) -> dict:
    """One run of the ebad preset for ``seconds`` of training at ``degree``; test PSNR at the exact test poses."""
    import scenes
    from ebad.config import preset
    from ebad.evaluate import evaluate
    from ebad.run import reconstruct

    scene = scenes.make_scene(scene_name, size=size, seed=seed, rgb=rgb)
    cfg = preset("ebad")
    cfg.train.iters, cfg.train.max_seconds = 1_000_000, seconds
    cfg.train.progress, cfg.train.eval_every, cfg.train.seed = False, 0, seed
    cfg.model.sh_degree = degree
    run = reconstruct(scene.capture, cfg)
    ev = evaluate(run, scene.capture, gt_frames=scene.gt_frames)
    m = run.metrics
    assert m is not None
    return {
        "scene": scene_name,
        "size": size,
        "rgb": rgb,
        "seed": seed,
        "degree": degree,
        "steps": m.steps,
        "train_seconds": m.train_seconds,
        "step_ms": 1e3 * m.train_seconds / max(m.steps, 1),
        "gaussians": m.gaussians,
        "test_psnr": ev["test"].psnr if "test" in ev else None,
        "deblur_psnr": ev["deblurred"].psnr if "deblurred" in ev else None,
    }


def _scene_or_boxes(name: str) -> str:
    import scenes

    if name in scenes.SCENES:
        return name
    print(f"scene {name!r} is not in this checkout (scenes: {sorted(scenes.SCENES)}); using 'boxes'")
    return "boxes"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a smoke run at small sizes (numbers mean nothing)")
    ap.add_argument("--scene", default="glossy", help="scenes.make_scene name ('boxes' when it does not exist)")
    ap.add_argument("--size", default="small", help="scene size of the reconstructions (tiny, small, davis)")
    ap.add_argument("--seconds", type=float, default=150.0, help="training seconds of each reconstruction")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--reps", type=int, default=15, help="repetitions of each rasteriser step timing")
    ap.add_argument("--skip-reconstruction", action="store_true")
    args = ap.parse_args(argv)
    seed_all(0)
    n, width, height = (2000, 128, 96) if args.quick else (20_000, 346, 260)
    reps = 3 if args.quick else args.reps
    rows = [raster_step(n, width, height, d, cams, reps) for d in (1, 3) for cams in (1, 5)]
    print(f"\nrasteriser step (forward + backward of ebad.gaussians.render), {n} Gaussians, {width}x{height}")
    print(f"{'D':>2} {'cams':>4} {'deg 0 ms':>9} {'deg 3 ms':>9} {'ratio':>6}")
    for r in rows:
        print(f"{r['d']:>2} {r['cams']:>4} {r['ms_degree0']:>9.1f} {r['ms_degree3']:>9.1f} {r['ratio']:>6.2f}")
    recon = []
    if not args.skip_reconstruction:
        scene = _scene_or_boxes(args.scene)
        size, seconds, seeds = ("tiny", 8.0, args.seeds[:1]) if args.quick else (args.size, args.seconds, args.seeds)
        for rgb in (False, True):
            for seed in seeds:
                for degree in DEGREES:
                    recon.append(reconstruction(scene, size, seconds, seed, degree, rgb))
        print(f"\nreconstruction at equal time ({seconds:g} s of training), scene {scene} {size}")
        print(f"{'rgb':>5} {'seed':>4} {'deg':>3} {'steps':>6} {'step ms':>8} {'test PSNR':>9} {'deblur PSNR':>11}")
        for r in recon:
            tp = "-" if r["test_psnr"] is None else f"{r['test_psnr']:.2f}"
            dp = "-" if r["deblur_psnr"] is None else f"{r['deblur_psnr']:.2f}"
            print(
                f"{r['rgb']!s:>5} {r['seed']:>4} {r['degree']:>3} {r['steps']:>6} {r['step_ms']:>8.1f} {tp:>9} {dp:>11}"
            )
    out = write_json(
        "sh_degree_quick" if args.quick else "sh_degree",
        {"target_ratio": 1.5, "raster_step": rows, "reconstruction": recon},
    )
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
