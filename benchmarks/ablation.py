"""Ablation: every preset on synthetic captures, several seeds, an equal budget, the eval protocol.

    python -m benchmarks.ablation [--quick] [--settings ideal,noisy,sfm] [--seeds 0,1,2]
                                  [--seconds S] [--iters N] [--size small] [--colour grey,cfa]

Settings (what the method is given; the truth never reaches it):

- ``ideal``: the idealised world of the first benchmarks: linear sensor, symmetric thresholds,
  no noise, constant-velocity shake, exact poses (anchored).
- ``noisy``: the realistic sensor (response with black level, gamma and saturation, read noise,
  c_pos != c_neg with per-pixel mismatch, noise events, hot pixels, hand tremor) and given
  poses with SfM-like error (0.5 degrees, 1 cm): every preset optimises every frame's pose.
- ``sfm``: the realistic sensor and no poses at all: pycolmap SfM on EDI-deblurred frames
  registers the frames and the test images; every preset optimises its poses.

Colour (``--colour``, several allowed, each run on the same seeds): ``grey`` (a grey DAVIS),
``rgb`` (colour frames, events of the channel mean: no real sensor, the old synthetic world)
and ``cfa`` (a colour DAVIS: RGGB Bayer filter over APS and event pixels, each pixel's events on
its own channel, frames demosaiced bilinearly by the "camera software").

Presets: ``3dgs`` (blurry frames as sharp, poses held), ``3dgs-po`` (the same with per-frame
pose optimisation, gsplat's pose_opt), ``bad``, ``edi-3dgs``, ``ebad``, and ``3dgs-sharp``
(the sharp ground-truth frames at the capture's poses: a reference, not a ceiling), and
``ebad-luma``: ebad given the colour-DAVIS capture without its ``cfa`` (events taken as the
luminance of the RGB frames: what ebad did before it modelled the filter). In
``ideal`` the poses are exact and held by every preset (3dgs-po is left out there). Each preset
gets the same wall-time budget and step cap per run; ``--seconds 0`` drops the wall-time budget,
so every preset makes exactly ``--iters`` steps (repeatable, independent of the machine's load).
Scores (``ebad.evaluate``): novel views at their run-frame poses refined against their images
(scene frozen), and the deblurred training frames against the sharp truth; mean +- std over
seeds. Timings are noisy on a shared machine: compare presets within one run.

Colour diagnostics (``colour_split``, in every row): of the refined novel views and the deblurred
frames, the luminance (channel mean) PSNR and, for colour, each channel's PSNR and the split of the
squared error into its achromatic part (the error of the channel mean) and its chromatic part (the
rest), all pooled over the views; on ``cfa`` captures the same of the camera's demosaic itself
(``demosaic_ceiling``: the sharp truth mosaicked and demosaiced bilinearly against the truth).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ._common import config_spec, seed_all, write_json

PRESETS = ["3dgs", "3dgs-po", "bad", "edi-3dgs", "ebad", "3dgs-sharp"]
COLOURS = {"grey": {}, "rgb": {"rgb": True}, "cfa": {"rgb": True, "cfa": "RGGB"}}
REFINE_ITERS = 300  # test-pose refinement steps at most, unless --refine-iters says otherwise
SETTINGS = {
    "ideal": {"sensor": "ideal", "poses": "exact"},
    "noisy": {"sensor": "realistic", "poses": "noisy"},
    "sfm": {"sensor": "realistic", "poses": "none"},
}


def wall_budget(seconds: float | None, quick: bool = False) -> float | None:
    """The wall-time budget per run of ``--seconds``: its default when not given (60 s, 15 with
    ``--quick``), None (no wall-time budget: ``--iters`` steps exactly) for 0; ValueError below 0."""
    if seconds is None:
        return 15.0 if quick else 60.0
    if seconds < 0:
        raise ValueError(f"--seconds must be >= 0 (0: no wall-time budget), got {seconds:g}")
    return float(seconds) or None


def make_config(name: str, iters: int, seconds: float | None, seed: int):
    """A preset, ``3dgs-po``, or a preset with options (``_common.config_spec``: ``ebad+trajectory.kind=cubic``)."""
    base = _base(name)
    options = name[len(base) :]  # "" or "+section.field=value..."
    cfg = config_spec({"3dgs-po": "3dgs", "ebad-luma": "ebad"}.get(base, base) + options)
    cfg.name = name
    if base == "3dgs":
        cfg.trajectory.anchor_mid = "yes"  # poses held as given (the baseline without pose freedom)
    if base == "3dgs-po":
        cfg.trajectory.anchor_mid = "no"  # per-frame pose optimisation
    cfg.train.iters = iters
    cfg.train.max_seconds = seconds
    cfg.train.progress = False
    cfg.train.eval_every = 0
    cfg.train.seed = seed
    return cfg


def colour_split(images: np.ndarray, truth: np.ndarray) -> dict[str, float]:  # [N, H, W, D] x2, D = 1 or 3
    """Where the squared error of ``images`` (clamped to [0, 1]) against ``truth`` lies, pooled over all
    pixels: ``mse``; ``mse_luma``, the error of the channel mean (the achromatic part) and
    ``mse_chroma`` = ``mse - mse_luma``, each channel's error about that mean (the chromatic part;
    zero for grey); ``psnr_luma`` of the channel means; for colour ``psnr_r``, ``psnr_g``,
    ``psnr_b``. PSNRs in dB for data range 1."""
    a = np.clip(np.asarray(images, np.float64), 0.0, 1.0)
    b = np.asarray(truth, np.float64)
    if a.shape != b.shape or a.shape[-1] not in (1, 3):
        raise ValueError(f"colour_split needs two [..., H, W, 1 or 3] arrays of one shape, got {a.shape}, {b.shape}")
    e = a - b
    mse, mse_luma = float((e**2).mean()), float((e.mean(-1) ** 2).mean())

    def db(m: float) -> float:
        return 100.0 if m <= 1e-10 else float(-10 * np.log10(m))

    out = {"mse": mse, "mse_luma": mse_luma, "mse_chroma": mse - mse_luma, "psnr_luma": db(mse_luma)}
    if a.shape[-1] == 3:
        out |= {f"psnr_{c}": db(float((e[..., d] ** 2).mean())) for d, c in enumerate("rgb")}
    return out


def demosaic_ceiling(scene) -> dict[str, dict[str, float]] | None:
    """``colour_split`` of the sharp truth (the test images, the training frames' ``gt_frames``)
    mosaicked with the capture's ``cfa`` and demosaiced bilinearly, against itself: what the camera's
    demosaic alone loses in one frame, the error every RGB frame carries into a fit (not a ceiling: a fit
    to many frames, whose filter phase moves across the view, averages part of it away). None without a cfa."""
    from edi.cfa import demosaic, mosaic

    cfa = scene.capture.cfa
    if cfa is None:
        return None
    tests = np.stack([v.image for v in scene.capture.test_views if v.image is not None])
    out = {}
    for key, truth in (("test", tests), ("frames", np.asarray(scene.gt_frames))):
        truth = np.clip(np.asarray(truth, np.float64), 0.0, 1.0)
        out[key] = colour_split(demosaic(mosaic(truth, cfa), cfa), truth)
    return out


def run_one(scene, name: str, iters: int, seconds: float | None, seed: int, refine_iters: int) -> dict:
    from ebad.evaluate import evaluate, run_truth, sharp_capture
    from ebad.run import reconstruct

    cfg = make_config(name, iters, seconds, seed)
    cap = sharp_capture(scene) if name == "3dgs-sharp" else scene.capture
    if name == "ebad-luma":
        import dataclasses

        cap = dataclasses.replace(cap, cfa=None)  # the same capture, its filter not stated
    t0 = time.perf_counter()
    run = reconstruct(cap, cfg)
    wall = time.perf_counter() - t0
    renders: dict[str, np.ndarray] = {}
    ev = evaluate(
        run,
        scene.capture,
        refine=True,
        gt_frames=scene.gt_frames,
        refine_iters=refine_iters,
        renders_to=renders.__setitem__,
    )
    views = [v for v in scene.capture.test_views if v.name in renders and v.image is not None]
    m = run.metrics
    return {
        "preset": name,
        "seed": seed,
        "steps": m.steps,
        "train_seconds": m.train_seconds,
        "wall_seconds": wall,
        "prepare_seconds": m.prepare_seconds,
        "gaussians": m.gaussians,
        "pose_source": m.prepare.pose_source,
        "train_frames": m.prepare.train_frames,  # SfM's unregistered frames are left out
        "unregistered": m.prepare.unregistered_frames,
        "anchored": m.anchored_mid_poses,
        "c": m.prepare.c,
        "test_psnr": ev["test"].psnr if "test" in ev else None,
        "test_refined_psnr": ev["test_refined"].psnr if "test_refined" in ev else None,
        "test_refined_ssim": ev["test_refined"].ssim if "test_refined" in ev else None,
        "test_views": ev["test"].n if "test" in ev else 0,
        "deblur_psnr": ev["deblurred"].psnr,
        "deblur_ssim": ev["deblurred"].ssim,
        "novel_colour": colour_split(np.stack([renders[v.name] for v in views]), np.stack([v.image for v in views]))
        if views and views[0].image.shape[-1] == renders[views[0].name].shape[-1]
        else None,
        "deblur_colour": colour_split(run.deblurred_frames(), run_truth(run, scene.gt_frames, scene.capture)),
    }


def _ms(values: list[float]) -> str:
    a = np.asarray([v for v in values if v is not None], dtype=float)
    return "-" if a.size == 0 else f"{a.mean():.2f} ± {a.std():.2f}"


def _mean_std(rs: list[dict], k: str) -> tuple[float | None, float | None]:
    v = [r[k] for r in rs if r[k] is not None]
    return (float(np.mean(v)), float(np.std(v))) if v else (None, None)


def summarise(rows: list[dict]) -> dict:
    """{setting (with its colour): {preset: {metric: (mean, std), "seeds": n}}}."""
    keys = ("test_refined_psnr", "test_refined_ssim", "deblur_psnr", "deblur_ssim", "steps")
    out: dict = {}
    for setting in dict.fromkeys(r["setting"] for r in rows):
        out[setting] = {}
        for name in dict.fromkeys(r["preset"] for r in rows if r["setting"] == setting):
            rs = [r for r in rows if r["setting"] == setting and r["preset"] == name]
            out[setting][name] = {k: _mean_std(rs, k) for k in keys} | {"seeds": len(rs)}
    return out


_STARRED = {"3dgs*": ("3dgs", "3dgs-po"), "bad*": ("bad",)}


def _base(preset: str) -> str:
    """``bad`` of ``bad+loss.cfa_frames=mosaic``: the preset without its options."""
    return preset.split("+", 1)[0]


def margins(rows: list[dict]) -> dict:
    """Per setting: ebad's novel-view (refined) margin over each other preset, paired by seed, as
    (mean, std, per-seed list). ``3dgs*``: the strongest in that seed of 3dgs, 3dgs-po and their
    variants with options (``3dgs-po+loss.cfa_frames=mosaic``); ``bad*`` the same of bad's."""
    out: dict = {}
    for setting in dict.fromkeys(r["setting"] for r in rows):
        by_seed: dict[int, dict[str, float]] = {}
        for r in rows:
            if r["setting"] == setting and r["test_refined_psnr"] is not None:
                by_seed.setdefault(r["seed"], {})[r["preset"]] = r["test_refined_psnr"]
        res: dict = {}
        for other in ("3dgs*", "bad", "bad*", "ebad-luma", "edi-3dgs"):
            d = []
            for v in by_seed.values():
                ref = (
                    max((v[p] for p in v if _base(p) in _STARRED[other]), default=None)
                    if other in _STARRED
                    else v.get(other)
                )
                if "ebad" in v and ref is not None:
                    d.append(v["ebad"] - ref)
            if d:
                res[other] = (float(np.mean(d)), float(np.std(d)), d)
        out[setting] = res
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny scenes, one seed, short budget")
    ap.add_argument("--settings", default="ideal,noisy,sfm")
    ap.add_argument("--colour", default="grey", help=f"one or more of {', '.join(COLOURS)}, comma-separated")
    ap.add_argument("--scene", default="boxes", help="synthetic scene (scenes.SCENES)")
    ap.add_argument(
        "--presets",
        default=",".join(PRESETS),
        help="presets, or a preset with options (ebad+loss.w_edi=2), comma-separated",
    )
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--size", default=None, help="scene size (default small; quick tiny)")
    ap.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="wall-time budget per run (default 60; quick 15); 0: none, --iters steps exactly",
    )
    ap.add_argument("--iters", type=int, default=None, help="step cap per run (default 3000; quick 300)")
    ap.add_argument("--refine-iters", type=int, default=REFINE_ITERS, help="test-pose refinement steps at most")
    ap.add_argument("--name", default="ablation", help="results file benchmarks/results/NAME.json")
    args = ap.parse_args(argv)
    import scenes

    try:
        seconds = wall_budget(args.seconds, args.quick)
    except ValueError as exc:
        ap.error(str(exc))
    iters = args.iters if args.iters is not None else (300 if args.quick else 3000)
    size = args.size or ("tiny" if args.quick else "small")
    seeds = [0] if args.quick else [int(s) for s in args.seeds.split(",")]
    settings = [s for s in args.settings.split(",") if s]
    colours = [c for c in args.colour.split(",") if c]
    bad = [c for c in colours if c not in COLOURS] + [s for s in settings if s not in SETTINGS]
    if bad:
        ap.error(f"unknown --colour/--settings value(s) {bad}: colours {list(COLOURS)}, settings {list(SETTINGS)}")
    presets = [p for p in args.presets.split(",") if p]
    for name in presets:
        make_config(name, iters, seconds, 0).check()  # a typo fails before any training
    seed_all(0)
    from ebad.run import warm_up

    warm_up(
        [*colours, *(["rgb"] if "cfa" in colours else [])]
    )  # numba compiles once, outside every budget (ebad-luma: rgb)
    rows: list[dict] = []
    header = {
        "size": size,
        "seconds": seconds,
        "iters": iters,
        "seeds": seeds,
        "settings": {k: SETTINGS[k] for k in settings},
        "colours": {k: COLOURS[k] for k in colours},
        "scene": args.scene,
        "argv": sys.argv[1:],
    }
    for setting, colour in [(s, c) for s in settings for c in colours]:
        label = setting if colours == ["grey"] else f"{setting}/{colour}"
        for seed in seeds:
            sc = scenes.make_scene(args.scene, size=size, seed=seed, **SETTINGS[setting], **COLOURS[colour])
            from ebad.evaluate import score_frames

            blurry = score_frames(sc.capture.frames, sc.gt_frames).psnr
            ceiling = demosaic_ceiling(sc)
            for name in presets:
                if (
                    (_base(name) == "3dgs-po" and setting == "ideal")
                    or (name == "ebad-luma" and colour != "cfa")
                    or ("loss.cfa_" in name and colour != "cfa")  # the same run as the plain preset's
                ):
                    continue
                r = run_one(sc, name, iters, seconds, seed, args.refine_iters)
                r.update(
                    {
                        "setting": label,
                        "colour": colour,
                        "size": size,
                        "blurry_psnr": blurry,
                        "demosaic_ceiling": ceiling,
                    }
                )
                rows.append(r)
                write_json(args.name, header | {"rows": rows, "partial": True})  # what is done survives a stop
                print(
                    f"{label:10s} seed {seed} {name:10s} "
                    f"novel (refined) {r['test_refined_psnr'] or float('nan'):6.2f} dB"
                    f" (luma {r['novel_colour']['psnr_luma'] if r['novel_colour'] else float('nan'):6.2f})"
                    f"  deblurred {r['deblur_psnr']:6.2f} dB  {r['steps']:5d} steps  {r['train_seconds']:6.1f} s"
                    f"  poses {r['pose_source']}{' (held)' if r['anchored'] else ''}",
                    flush=True,
                )
    summary = summarise(rows)
    budget = f"{iters} steps" if seconds is None else f"{seconds:g} s / {iters} steps"
    print(f"\n{size}, {budget} per run, seeds {seeds}; mean ± std over seeds")
    print("| setting | preset | novel PSNR (refined) | novel SSIM | deblurred PSNR | deblurred SSIM | steps |")
    print("|---|---|---|---|---|---|---|")
    for setting, by in summary.items():
        for name, s in by.items():
            f = {k: (f"{v[0]:.2f} ± {v[1]:.2f}" if v[0] is not None else "-") for k, v in s.items() if k != "seeds"}
            f["test_refined_ssim"] = (
                f"{s['test_refined_ssim'][0]:.3f} ± {s['test_refined_ssim'][1]:.3f}"
                if s["test_refined_ssim"][0] is not None
                else "-"
            )
            f["deblur_ssim"] = f"{s['deblur_ssim'][0]:.3f} ± {s['deblur_ssim'][1]:.3f}"
            print(
                f"| {setting} | {name} | {f['test_refined_psnr']} | {f['test_refined_ssim']} | {f['deblur_psnr']} | "
                f"{f['deblur_ssim']} | {s['steps'][0]:.0f} |"
            )
    marg = margins(rows)
    print("\nebad's novel-view margin (refined, dB), paired by seed: mean ± std [per seed]")
    for setting, res in marg.items():
        for other, (m, sd, d) in res.items():
            print(f"  {setting:12s} ebad - {other:9s} {m:+6.2f} ± {sd:.2f}  [{', '.join(f'{x:+.2f}' for x in d)}]")
    path = write_json(args.name, header | {"rows": rows, "summary": summary, "margins": marg})
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
