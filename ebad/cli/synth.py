"""``ebad synth``: build a synthetic blurry event capture with ground truth."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Annotated, Literal

import tyro

NAME = "synth"
HELP = "build a synthetic blurry event capture (capture/ for training, gt/ for evaluation)"


# the registries of scenes.synth (SCENES, SIZES, SENSORS), written out so that ``ebad --help`` does not import
# the scene builder; tests/ebad/cli/test_synth.py checks that they agree
SceneName = Literal["boxes", "glossy", "spheres"]
SizeName = Literal["davis", "small", "tiny"]
SensorName = Literal["ideal", "realistic"]


@dataclass
class Args:
    name: Annotated[tyro.conf.Positional[SceneName], tyro.conf.arg(metavar="NAME")]
    """scene to build (boxes, spheres, glossy: view-dependent highlights)"""
    out: str
    """output folder (gets capture/ and gt/)"""
    size: SizeName = "tiny"
    """image size (tiny 64x48, small 160x120, davis 346x260)"""
    seed: int = 0
    """random seed (shake, tremor, thresholds, noise, pose errors)"""
    rgb: bool = False
    """colour frames instead of grey (events of the luminance, the baseline; a colour DAVIS: --cfa)"""
    cfa: Literal["RGGB", "BGGR", "GRBG", "GBRG"] | None = None
    (
        "a colour DAVIS with this Bayer filter (implies --rgb): each pixel's events fire on its own channel, frames "
        "are the raw mosaic demosaiced (bilinear) unless --raw-frames"
    )
    raw_frames: bool = False
    """with --cfa, write the frames as 1-channel raw Bayer mosaics instead of demosaiced RGB"""
    sensor: SensorName = "realistic"
    (
        "camera model: realistic (non-linear saturating APS with read noise, c_pos != c_neg, noise events, hand "
        "tremor, noisy poses) or ideal (linear APS, symmetric thresholds, constant-velocity shake, exact poses)"
    )
    poses: Literal["exact", "noisy", "none"] | None = None
    """poses given with the capture (None: the sensor's; realistic: noisy, ideal: exact)"""
    noise_hz: float | None = None
    """shot-noise events per pixel per second (None: the sensor's)"""
    c: Annotated[tuple[float, ...] | None, tyro.conf.arg(metavar="C [C]")] = None
    (
        "contrast threshold (log units): one value, or two for c_pos c_neg (None: the sensor's; realistic 0.24 0.18, "
        "ideal 0.2)"
    )
    shake: float = 1.0
    """camera shake scale (0: no shake)"""
    tremor: float | None = None
    """accelerating hand-tremor strength (None: the sensor's; realistic 1, ideal 0)"""
    frames: int | None = None
    """number of training frames (None: 10)"""
    test_views: int | None = None
    """number of held-out views (None: 3)"""
    exposure: float | None = None
    """exposure in seconds (None: 0.05)"""
    sharp_fraction: float = 0.0
    """fraction of frames without shake"""
    overwrite: bool = False
    """replace an existing output folder"""


def run(args: Args) -> int:
    from ebad.errors import UserError
    from scenes.synth import make_scene, write_scene

    c: float | tuple[float, float] | None = None
    if args.c is not None:
        if len(args.c) not in (1, 2):
            raise UserError(f"--c takes one value or two (c_pos c_neg), got {len(args.c)}")
        c = args.c[0] if len(args.c) == 1 else (args.c[0], args.c[1])
    if args.raw_frames and args.cfa is None:
        raise UserError("--raw-frames needs --cfa PATTERN (a raw mosaic needs a colour filter array)")
    t0 = time.perf_counter()
    scene = make_scene(
        args.name,
        size=args.size,
        seed=args.seed,
        rgb=args.rgb,
        sensor=args.sensor,
        poses=args.poses,
        c=c,
        noise_hz=args.noise_hz,
        shake=args.shake,
        tremor=args.tremor,
        n_frames=args.frames,
        n_test=args.test_views,
        exposure=args.exposure,
        sharp_fraction=args.sharp_fraction,
        cfa=args.cfa,
        raw_frames=args.raw_frames,
    )
    out = write_scene(scene, args.out, overwrite=args.overwrite)
    cap = scene.capture
    colour = "" if cap.cfa is None else f", {cap.cfa} colour filter, {'raw' if cap.raw_mosaic else 'demosaiced'} frames"
    print(
        f"ebad synth: {args.name} {cap.width}x{cap.height}x{cap.channels} ({args.sensor} sensor{colour}, poses "
        f"{scene.sensor.poses}), {cap.num_frames} frames, {len(cap.test_views)} test views, {len(cap.events)} "
        f"events in {time.perf_counter() - t0:.1f} s"
    )
    print(f"  capture: {out / 'capture'}  (ebad-capture/1)")
    print(f"  ground truth: {out / 'gt'}")
    return 0
