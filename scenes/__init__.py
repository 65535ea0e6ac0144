"""scenes: capture format, readers for real recordings, synthetic scenes, camera initialisation.

Public API::

    load(path) -> Capture                 # ebad-capture/1, .aedat4, ROS1 .bag, Event Camera Dataset,
                                          # EvDeblurNeRF, EBAD-NeRF / E2NeRF (docs/formats.md)
    read_image(path), write_image(path, img, bits=None|8|16)   # the one image reader / writer
    read_ground_truth(gt_dir) -> GroundTruth                    # gt.json (or images_gt_blur/)
    save(capture, path)                   # ebad-capture/1, atomic, lossless
    CaptureError                          # ValueError naming the file and the field
    simulate_events(images, times, ...)   # ESIM-style event simulator
    make_scene(name, size, sensor="realistic"|"ideal"|Sensor, poses=None, ...) -> SynthScene, SCENES, SENSORS,
    write_scene(scene, out_dir)
    scenes.colmap.estimate_poses(capture) -> PoseEstimate   # pycolmap SfM, K fixed, test views registered too
"""

from . import colmap  # noqa: E402  (pycolmap itself is imported when estimate_poses runs)
from .capture import Capture, TestView
from .errors import CaptureError
from .format import read_ground_truth, save
from .images import read_image, write_image
from .readers import detect_layout, load
from .render import Quad, RayScene, Sphere, project_points, render
from .simulate import simulate_events
from .synth import SCENES, SENSORS, SIZES, Sensor, SynthScene, make_scene, write_scene

__all__ = [
    "Capture",
    "TestView",
    "CaptureError",
    "load",
    "save",
    "read_image",
    "write_image",
    "read_ground_truth",
    "detect_layout",
    "simulate_events",
    "make_scene",
    "write_scene",
    "SynthScene",
    "Sensor",
    "SENSORS",
    "SCENES",
    "SIZES",
    "render",
    "RayScene",
    "Quad",
    "Sphere",
    "project_points",
    "colmap",
]
