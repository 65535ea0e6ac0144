"""``ebad synth``: build a synthetic blurry event capture with ground truth."""
from __future__ import annotations

import time

NAME = "synth"
HELP = "build a synthetic blurry event capture (capture/ for training, gt/ for evaluation)"


def add_arguments(parser) -> None:
    from scenes.synth import SCENES, SENSORS, SIZES

    parser.add_argument("name", choices=sorted(SCENES), help="scene to build")
    parser.add_argument("--out", required=True, help="output folder (gets capture/ and gt/)")
    parser.add_argument("--size", choices=sorted(SIZES), default="tiny", help="image size (default tiny, 64x48)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (shake, tremor, thresholds, noise, pose errors)")
    parser.add_argument("--rgb", action="store_true", help="colour frames (default grey)")
    parser.add_argument("--sensor", choices=sorted(SENSORS), default="realistic",
                        help="camera model: realistic (default: non-linear saturating APS with read noise, "
                             "c_pos != c_neg, noise events, hand tremor, noisy poses) or ideal (linear APS, "
                             "symmetric thresholds, constant-velocity shake, exact poses)")
    parser.add_argument("--poses", choices=["exact", "noisy", "none"], default=None,
                        help="poses given with the capture (default: the sensor's; realistic: noisy, ideal: exact)")
    parser.add_argument("--noise-hz", type=float, default=None, help="shot-noise events per pixel per second "
                                                                     "(default: the sensor's)")
    parser.add_argument("--c", type=float, nargs="+", default=None, metavar="C",
                        help="contrast threshold (log units): one value, or two for c_pos c_neg "
                             "(default: the sensor's; realistic 0.24 0.18, ideal 0.2)")
    parser.add_argument("--shake", type=float, default=1.0, help="camera shake scale (0: no shake)")
    parser.add_argument("--tremor", type=float, default=None,
                        help="accelerating hand-tremor strength (default: the sensor's; realistic 1, ideal 0)")
    parser.add_argument("--frames", type=int, default=None, help="number of training frames (default 10)")
    parser.add_argument("--test-views", type=int, default=None, help="number of held-out views (default 3)")
    parser.add_argument("--exposure", type=float, default=None, help="exposure in seconds (default 0.05)")
    parser.add_argument("--sharp-fraction", type=float, default=0.0, help="fraction of frames without shake")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output folder")


def run(args) -> int:
    from ebad.errors import UserError
    from scenes.synth import make_scene, write_scene

    c = args.c
    if c is not None:
        if len(c) > 2:
            raise UserError(f"--c takes one value or two (c_pos c_neg), got {len(c)}")
        c = c[0] if len(c) == 1 else (c[0], c[1])
    t0 = time.perf_counter()
    scene = make_scene(args.name, size=args.size, seed=args.seed, rgb=args.rgb, sensor=args.sensor, poses=args.poses,
                       c=c, noise_hz=args.noise_hz, shake=args.shake, tremor=args.tremor, n_frames=args.frames,
                       n_test=args.test_views, exposure=args.exposure, sharp_fraction=args.sharp_fraction)
    out = write_scene(scene, args.out, overwrite=args.overwrite)
    cap = scene.capture
    print(f"ebad synth: {args.name} {cap.width}x{cap.height}x{cap.channels} ({args.sensor} sensor, poses "
          f"{scene.sensor.poses}), {cap.num_frames} frames, {len(cap.test_views)} test views, {len(cap.events)} "
          f"events in {time.perf_counter() - t0:.1f} s")
    print(f"  capture: {out / 'capture'}  (ebad-capture/1)")
    print(f"  ground truth: {out / 'gt'}")
    return 0
