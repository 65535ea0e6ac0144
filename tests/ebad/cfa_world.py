"""A small synthetic colour-DAVIS capture for the cfa tests and measurements, built by hand from
``scenes.make_scene(rgb=True)`` (until ``make_scene(cfa=...)`` exists): the same world and camera
path, every sensor pixel behind one filter of a Bayer ``pattern``, its events simulated on the log
of its own channel (``scenes.synth.sensor_events`` on the irradiance mosaic), its APS value the
sensor's response of that channel (plus read noise and quantisation), and the frames either the
raw mosaics or their bilinear demosaic (``edi.cfa.demosaic``, the camera software's).

Run as a module to compare L_blur / L_EDI through the mosaic against RGB on RGB frames:
``python -m tests.ebad.cfa_world [iters] [seeds...]``.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from edi.cfa import demosaic, mosaic
from scenes.render import render
from scenes.synth import LEAD_S, PERIOD_S, Sensor, SynthScene, aps_record, make_scene, sensor_events


def cfa_scene(
    pattern: str = "RGGB",
    raw: bool = False,
    seed: int = 0,
    name: str = "boxes",
    size: str = "tiny",
    sensor: str | Sensor = "realistic",
    **kw,
) -> SynthScene:
    """``make_scene(name, size, seed, rgb=True, sensor=sensor, **kw)`` seen by a colour DAVIS
    (module docstring); the capture says ``cfa = pattern``. Test views stay the true RGB images
    (their mosaics with ``raw``: a capture's images share one shape; ``gt_test_images`` keeps the RGB)."""
    sc = make_scene(name, size, seed, rgb=True, sensor=sensor, **kw)
    cap, sen = sc.capture, sc.sensor
    n_blur, exposure = int(sc.truth["n_blur"]), float(sc.truth["exposure"])
    dt = exposure / n_blur
    lead, period = int(round(LEAD_S / dt)), int(round(PERIOD_S / dt))
    F = cap.num_frames
    grid = np.arange(2 * lead + period * (F - 1) + n_blur + 1) * dt
    irr = render(sc.ray_scene, sc.trajectory.c2w(grid), cap.K, cap.width, cap.height)  # [S, H, W, 3]
    events, c_pos, c_neg = sensor_events(mosaic(irr, pattern), grid, sen, seed)  # each pixel's own channel
    trap = np.full(n_blur + 1, 1.0 / n_blur)
    trap[[0, -1]] *= 0.5
    rng = np.random.default_rng([seed, 7])
    frames = []
    for k in range(F):
        i0 = lead + period * k
        rawk = aps_record(mosaic(np.tensordot(trap, irr[i0 : i0 + n_blur + 1], axes=1), pattern), sen, rng)
        frames.append(rawk[..., None] if raw else demosaic(rawk, pattern))
    tests = cap.test_views
    if raw:
        tests = [dataclasses.replace(v, image=mosaic(v.image, pattern)[..., None]) for v in tests]
    capture = dataclasses.replace(
        cap, frames=np.stack(frames).astype(np.float32), events=events, cfa=pattern, test_views=tests
    )
    capture.validate("cfa_scene")
    truth = dict(sc.truth, event_channel=f"cfa {pattern}")
    return dataclasses.replace(sc, capture=capture, c_pos=c_pos, c_neg=c_neg, truth=truth)


def _measure(iters: int, seeds: list[int]) -> None:  # pragma: no cover - a measurement, run by hand
    import time

    import torch

    from ebad.config import preset
    from ebad.run import reconstruct

    for seed in seeds:
        sc = cfa_scene(seed=seed, n_frames=8, n_test=3)
        for frames, events in (("rgb", "filter"), ("mosaic", "filter"), ("rgb", "luminance")):
            cfg = preset("ebad")
            cfg.train.iters, cfg.train.progress, cfg.train.eval_every = iters, False, 0
            cfg.loss.cfa_frames, cfg.loss.cfa_events = frames, events  # type: ignore[assignment]
            torch.manual_seed(seed)
            t = time.perf_counter()
            run = reconstruct(sc.capture, cfg)
            test = run.metrics.test if run.metrics else None
            psnr = f"{test.psnr:.2f}" if test else "-"
            print(f"seed {seed} frames {frames} events {events}: test PSNR {psnr} ({time.perf_counter() - t:.0f} s)")


if __name__ == "__main__":  # pragma: no cover
    _measure(int(sys.argv[1]) if len(sys.argv) > 1 else 300, [int(s) for s in sys.argv[2:]] or [0])
