"""Tiny synthetic blurry event captures with exact ground truth.

A scene (``SCENES``: "boxes", "spheres", "glossy") is built from textured quads, boxes and
spheres (textures: scikit-image's bundled photographs, their 8-bit values taken as linear
irradiance and rescaled into [0.05, 0.95]) and rendered by ray casting (``scenes.render``), never
by splat_cpu. "boxes" and "spheres" are matte (the same radiance from every direction);
"glossy" has Blinn-Phong highlights that move over its spheres and box as the camera moves
(view-dependent radiance, ``scenes.render.glossy``).

Timeline: frame k is exposed over [t_k, t_k + exposure], t_k = lead + k * period. The camera
follows a horizontal arc around the scene: it is parked on the arc during each exposure and
glides (smoothstep) to the next parking spot between exposures. On top, a per-exposure shake
(camera-local rotation vector and translation) moves linearly from -a_k / 2 to +a_k / 2 over
exposure k, and glides between exposures, so the whole trajectory is continuous and the blur
of frame k comes from its shake alone (``shake`` scales it; shake = 0 gives sharp frames,
``sharp_fraction`` zeroes it on a random subset of frames). A hand tremor (``Sensor.tremor``)
adds a sum of sinusoids of 2-12 Hz with a 1/f spectrum to the rotation and translation at all
times: it accelerates inside every exposure, which a constant-velocity (``linear``) exposure
trajectory cannot reproduce.

Renders of irradiance sit on a uniform grid of step exposure / n_blur over the whole capture,
exposure boundaries included. The camera (``Sensor``, presets ``SENSORS``):

- APS: a blurry frame is the trapezoidal mean of the n_blur + 1 (>= 33) irradiance renders
  spanning its exposure, mapped by the response ``aps_response`` (black level, gamma, gain
  such that bright parts saturate), plus Gaussian read noise, quantised to 8 or 16 bits;
- events: ``simulate_events`` over all irradiance renders with the sensor's own log offset,
  c_pos != c_neg, per-pixel mismatch, refractory period, shot and leak noise, hot pixels.
  Colour captures (``rgb``): the event pixels see luminance, ``Sensor.luminance`` weights of the
  linear R, G, B irradiance (Rec. 709 in the realistic preset, the channel mean in the ideal one),
  a baseline no colour DAVIS produces;
- a colour DAVIS (``cfa="RGGB"`` etc., ``edi.cfa``): every pixel sits behind one filter of the
  Bayer pattern; its events fire on the log of its own channel (the same thresholds, mismatch
  and noise per pixel), its APS value is its own channel through the response and read noise,
  and the frames are the camera software's bilinear demosaic of that raw mosaic (or the raw
  mosaic itself, ``raw_frames``). The capture records ``cfa``; the ground truth stays full RGB;
- poses: exact, with SfM-like error (``pose_rot_deg``, ``pose_trans``), or none; the capture
  states which (``Capture.pose_trust``: "exact", "approximate", "none").

``sensor="ideal"`` is the idealised world of the first benchmarks (linear APS, symmetric
thresholds, no noise events, ``edi.LOG_EPS`` as log offset, constant-velocity shake, exact
poses), bit for bit; ``sensor="realistic"`` (the default) is a DAVIS-like camera in a hand.

Nothing of the truth reaches the capture: ``Capture.meta`` holds labels only (scene, size,
colour, sensor preset name, pose source); thresholds, response, noise, depths, true poses and
the seed are on the ``SynthScene`` (``truth``, ``gt_*``) and in ``gt/`` on disk.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from edi import LOG_EPS, EventStream
from edi.cfa import check_pattern, demosaic, mosaic

from .capture import Capture, TestView, frame_name
from .errors import CaptureError
from .format import save
from .images import quantize, write_image
from .render import Quad, RayScene, Sphere, render
from .simulate import simulate_events

__all__ = [
    "SynthScene",
    "Sensor",
    "SENSORS",
    "make_scene",
    "write_scene",
    "aps_response",
    "aps_record",
    "sensor_events",
    "SCENES",
    "SIZES",
    "look_at",
    "TRUTH_KEYS",
]

SIZES = {"tiny": (64, 48), "small": (160, 120), "davis": (346, 260)}
HFOV_DEG = 60.0  # horizontal field of view of the synthetic camera
PERIOD_S = 0.1  # frame period
LEAD_S = 0.02  # capture time before the first exposure and after the last
DEFAULT_EXPOSURE_S = 0.05
N_BLUR = 32  # renders averaged per exposure (at least)
ROT_SHAKE_RAD = 0.07  # rotation shake amplitude per exposure at shake = 1
TRANS_SHAKE = 0.03  # translation shake amplitude per exposure at shake = 1, x orbit radius
ORBIT_RADIUS = 4.0
ORBIT_HALF_ANGLE_DEG = 14.0
TARGET = np.array([0.0, 0.0, 4.0])  # the arc's centre, looked at by the camera
TREMOR_BAND_HZ = (2.0, 12.0)  # hand tremor frequencies (physiological tremor and slower sway)
TREMOR_COMPONENTS = 4  # sinusoids per axis
TREMOR_ROT_RAD = 0.012  # RMS tremor rotation per axis at tremor = 1
TREMOR_TRANS = 0.004  # RMS tremor translation per axis at tremor = 1, x orbit radius
REC709_LUMA = (0.2126, 0.7152, 0.0722)  # luminance of linear R, G, B (ITU-R BT.709)
CHANNEL_MEAN = (1 / 3, 1 / 3, 1 / 3)
# Capture.meta keys a synthetic scene must never write (the no-leak tests check them)
TRUTH_KEYS = (
    "c",
    "c_pos",
    "c_neg",
    "sigma_c",
    "noise_hz",
    "leak_hz",
    "refractory",
    "hot_pixels",
    "log_eps",
    "response",
    "black_level",
    "gamma",
    "gain",
    "read_noise",
    "depth_range",
    "seed",
    "n_blur",
    "sharp_frames",
    "tremor",
    "shake",
    "truth",
)


@dataclass(frozen=True)
class Sensor:
    """The simulated camera in a hand: APS readout, event pixels, motion the trajectory model
    does not have, and where the poses come from. Presets: ``SENSORS``."""

    # APS: recorded = clip(black_level + (1 - black_level) * min(gain * E, 1) ** gamma + read noise, 0, 1)
    black_level: float = 0.0  # recorded value of zero irradiance
    gamma: float = 1.0  # exponent of the response curve (1: linear)
    gain: float = 1.0  # irradiance E multiplier; gain * E >= 1 saturates
    read_noise: float = 0.0  # std of Gaussian read noise, in recorded units
    bits: int = 8  # APS quantisation: 8 or 16 bits
    record_test_views: bool = False  # test images recorded by the APS (noise, quantisation); False: exact
    # event pixels
    c_pos: float = 0.2  # mean ON threshold, natural-log units
    c_neg: float = 0.2  # mean OFF threshold
    sigma_c: float = 0.03  # per-pixel threshold mismatch (std of C+ and C-)
    refractory: float = 0.0  # seconds after an event during which a pixel does not fire
    noise_hz: float = 0.0  # shot-noise events per pixel per second (random polarity)
    leak_hz: float = 0.0  # leak events per pixel per second (positive)
    hot_pixel_fraction: float = 0.0  # fraction of pixels firing ON events at HOT_PIXEL_HZ
    log_eps: float = LOG_EPS  # the pixel's log offset: events see log(E + log_eps)
    luminance: tuple[float, float, float] = CHANNEL_MEAN  # weights of R, G, B seen by the event pixels
    # motion
    tremor: float = 0.0  # strength of the accelerating hand tremor (0: constant-velocity shake only)
    # poses given with the capture
    poses: Literal["exact", "noisy", "none"] = "exact"
    pose_rot_deg: float = 0.5  # RMS rotation error of "noisy" poses, degrees
    pose_trans: float = 0.01  # RMS position error of "noisy" poses, world units (orbit radius 4: ~1 cm at 4 m)

    def validate(self) -> Sensor:
        """Raise CaptureError naming the field of a setting that cannot work; return self."""
        for name in ("gamma", "gain", "c_pos", "c_neg", "log_eps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise CaptureError(None, f"sensor.{name}", f"must be a positive finite number, got {v!r}")
        for name in (
            "read_noise",
            "sigma_c",
            "refractory",
            "noise_hz",
            "leak_hz",
            "tremor",
            "pose_rot_deg",
            "pose_trans",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise CaptureError(None, f"sensor.{name}", f"must be a finite number >= 0, got {v!r}")
        if not (0.0 <= self.black_level < 1.0):
            raise CaptureError(None, "sensor.black_level", f"must be in [0, 1), got {self.black_level!r}")
        if not (0.0 <= self.hot_pixel_fraction <= 1.0):
            raise CaptureError(None, "sensor.hot_pixel_fraction", f"must be in [0, 1], got {self.hot_pixel_fraction!r}")
        if self.bits not in (8, 16):
            raise CaptureError(None, "sensor.bits", f"must be 8 or 16, got {self.bits!r}")
        lum = np.asarray(self.luminance, np.float64)
        if lum.shape != (3,) or (lum < 0).any() or abs(lum.sum() - 1.0) > 1e-6:
            raise CaptureError(None, "sensor.luminance", f"must be 3 weights >= 0 summing to 1, got {self.luminance!r}")
        if self.poses not in ("exact", "noisy", "none"):
            raise CaptureError(None, "sensor.poses", f"must be 'exact', 'noisy' or 'none', got {self.poses!r}")
        return self


SENSORS: dict[str, Sensor] = {
    # the idealised world: linear APS, symmetric thresholds, no noise events, edi.LOG_EPS,
    # constant-velocity shake, exact poses
    "ideal": Sensor(),
    # a DAVIS-like camera in a hand
    "realistic": Sensor(
        black_level=0.04,
        gamma=0.75,
        gain=1.25,
        read_noise=0.008,
        record_test_views=True,
        c_pos=0.24,
        c_neg=0.18,
        sigma_c=0.03,
        refractory=5e-4,
        noise_hz=1.0,
        leak_hz=0.1,
        hot_pixel_fraction=5e-4,
        log_eps=0.02,
        luminance=REC709_LUMA,
        tremor=1.0,
        poses="noisy",
    ),
}
POSE_TRUST_OF = {"exact": "exact", "noisy": "approximate", "none": "none"}  # Sensor.poses -> Capture.pose_trust


def aps_response(
    irradiance: np.ndarray,  # [..., D] linear irradiance >= 0
    sensor: Sensor,
) -> np.ndarray:
    """The APS response, irradiance -> recorded value in [0, 1], noise-free and unquantised:
    ``black_level + (1 - black_level) * min(gain * E, 1) ** gamma``. Monotone (non-decreasing),
    saturating at 1 for E >= 1 / gain; the identity for the ideal sensor."""
    e = np.minimum(sensor.gain * np.asarray(irradiance, np.float64), 1.0)
    return np.clip(
        sensor.black_level + (1.0 - sensor.black_level) * np.power(np.maximum(e, 0.0), sensor.gamma), 0.0, 1.0
    )


def aps_record(
    irradiance: np.ndarray,  # [..., D] linear irradiance >= 0
    sensor: Sensor,
    rng: np.random.Generator,
) -> np.ndarray:
    """What the APS records: ``aps_response`` plus Gaussian read noise, quantised to
    ``sensor.bits`` (float32 in [0, 1], k / (2**bits - 1))."""
    v = aps_response(irradiance, sensor)
    if sensor.read_noise > 0:
        v = v + sensor.read_noise * rng.standard_normal(v.shape)
    return quantize(v, sensor.bits)


WORLD_UP = np.array([0.0, -1.0, 0.0])  # world up of the synthetic scenes: -y (OpenCV axes)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """OpenCV c2w [4, 4] at ``eye`` looking at ``target`` (``up`` is world up, -y here)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)  # with y down: x = z cross up(-y) points right
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


# --------------------------------------------------------------------------- textures


def _photo(name: str) -> np.ndarray:
    import skimage.data

    a = getattr(skimage.data, name)().astype(np.float32) / 255.0
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return a[..., :3]


def _texture(name: str, rgb: bool, px: float, crop: tuple[float, float, float, float] | None = None) -> np.ndarray:
    """Photograph ``name`` (optionally cropped, fractions y0 y1 x0 x1), resized with
    anti-aliasing so its longer side has about ``px`` texels, in [0.05, 0.95]."""
    from skimage.transform import resize

    a = _photo(name)
    if crop is not None:
        h, w = a.shape[:2]
        a = a[int(crop[0] * h) : int(crop[1] * h), int(crop[2] * w) : int(crop[3] * w)]
    h, w = a.shape[:2]
    s = min(1.0, max(8.0, px) / max(h, w))
    if s < 1.0:
        a = resize(a, (max(4, round(h * s)), max(4, round(w * s))), anti_aliasing=True, order=1)
    if not rgb:
        a = a.mean(axis=2, keepdims=True)
    return (0.05 + 0.9 * np.clip(a, 0, 1)).astype(np.float32)


def _box(center, size, textures: list[np.ndarray]) -> list[Quad]:
    """Six quads of an axis-aligned box (textures cycled over the faces)."""
    c = np.asarray(center, np.float64)
    sx, sy, sz = np.asarray(size, np.float64) / 2
    ex, ey, ez = np.array([2 * sx, 0, 0]), np.array([0, 2 * sy, 0]), np.array([0, 0, 2 * sz])
    lo = c - [sx, sy, sz]
    faces = [
        (lo, ex, ey),  # front (z = lo), facing the camera
        (lo + ez + ex, -ex, ey),  # back
        (lo + ez, -ez, ey),  # left (x = lo)
        (lo + ex, ez, ey),  # right
        (lo + ez, ex, -ez),  # top (y = lo, up is -y)
        (lo + ey, ex, ez),  # bottom
    ]
    return [Quad(o, u, v, textures[i % len(textures)]) for i, (o, u, v) in enumerate(faces)]


def _px_per_unit(width: int, depth: float) -> float:
    f = 0.5 * width / math.tan(math.radians(HFOV_DEG) / 2)
    return f / depth


def build_boxes(width: int, rgb: bool) -> RayScene:
    """Textured boxes and a plane at several depths in front of a photograph wall."""
    ppu = lambda d: 1.5 * _px_per_unit(width, d)  # noqa: E731 - texels per world unit at depth d
    wall = Quad(
        np.array([-11.0, -6.5, 8.5]),
        np.array([22.0, 0, 0]),
        np.array([0, 8.0, 0]),
        _texture("astronaut", rgb, 22.0 * ppu(8.5)),
    )
    floor = Quad(
        np.array([-11.0, 1.4, -1.0]),
        np.array([22.0, 0, 0]),
        np.array([0, 0, 9.5]),
        _texture("gravel", rgb, 22.0 * ppu(3.0)),
    )
    prims = [wall, floor]
    prims += _box(
        [-1.3, 0.55, 3.6],
        [1.2, 1.7, 1.2],
        [_texture("coffee", rgb, 1.7 * ppu(3.0)), _texture("brick", rgb, 1.7 * ppu(3.0))],
    )
    prims += _box(
        [1.25, 0.8, 4.6],
        [1.3, 1.2, 1.3],
        [_texture("chelsea", rgb, 1.3 * ppu(4.0)), _texture("grass", rgb, 1.3 * ppu(4.0))],
    )
    prims.append(
        Quad(
            np.array([-0.2, -1.6, 6.0]),
            np.array([1.8, 0, 0.4]),
            np.array([0, 1.3, 0]),
            _texture("rocket", rgb, 1.8 * ppu(6.0)),
        )
    )
    return RayScene(prims, background=0.1)


def _wall_and_floor(width: int, rgb: bool, wall_texture: str, floor_texture: str) -> list[Quad]:
    """The matte wall (z = 8.5) and floor (y = 1.4) behind and under the spheres and glossy scenes."""
    ppu = lambda d: 1.5 * _px_per_unit(width, d)  # noqa: E731
    wall = Quad(
        np.array([-11.0, -6.5, 8.5]),
        np.array([22.0, 0, 0]),
        np.array([0, 8.0, 0]),
        _texture(wall_texture, rgb, 22.0 * ppu(8.5)),
    )
    floor = Quad(
        np.array([-11.0, 1.4, -1.0]),
        np.array([22.0, 0, 0]),
        np.array([0, 0, 9.5]),
        _texture(floor_texture, rgb, 22.0 * ppu(3.0)),
    )
    return [wall, floor]


def build_spheres(width: int, rgb: bool) -> RayScene:
    """Textured spheres at three depths before a textured wall and floor."""
    ppu = lambda d: 1.5 * _px_per_unit(width, d)  # noqa: E731
    prims = [
        *_wall_and_floor(width, rgb, "coffee", "brick"),
        Sphere(np.array([-1.2, 0.5, 3.3]), 0.85, _texture("astronaut", rgb, 5.3 * ppu(3.0))),
        Sphere(np.array([1.1, 0.2, 4.6]), 1.1, _texture("chelsea", rgb, 6.9 * ppu(4.0))),
        Sphere(np.array([0.0, -1.2, 6.4]), 0.9, _texture("rocket", rgb, 5.7 * ppu(6.0))),
    ]
    return RayScene(prims, background=0.1)


def build_glossy(width: int, rgb: bool) -> RayScene:
    """View-dependent radiance: two glossy spheres and a glossy box (Blinn-Phong
    highlights of one white directional light, ``scenes.render.glossy``) on a matte floor before a matte wall.
    The highlights move over the surfaces as the camera moves, which view-independent colours
    cannot reproduce."""
    ppu = lambda d: 1.5 * _px_per_unit(width, d)  # noqa: E731
    prims = [
        *_wall_and_floor(width, rgb, "astronaut", "gravel"),
        Sphere(np.array([-1.2, 0.4, 3.4]), 0.9, _texture("coffee", rgb, 5.7 * ppu(3.0)), specular=0.8, shininess=30.0),
        Sphere(np.array([0.2, -1.1, 6.2]), 0.9, _texture("rocket", rgb, 5.7 * ppu(6.0)), specular=0.8, shininess=30.0),
    ]
    box = _box(
        [1.3, 0.75, 4.4],
        [1.3, 1.3, 1.3],
        [_texture("chelsea", rgb, 1.3 * ppu(4.0)), _texture("brick", rgb, 1.3 * ppu(4.0))],
    )
    prims += [replace(q, specular=0.7, shininess=12.0) for q in box]
    return RayScene(prims, background=0.1)


SCENES: dict[str, Callable[[int, bool], RayScene]] = {
    "boxes": build_boxes,
    "spheres": build_spheres,
    "glossy": build_glossy,
}


# --------------------------------------------------------------------------- trajectory


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


@dataclass
class Trajectory:
    """Continuous camera path: parked base poses during exposures plus linear shake, plus an
    optional tremor: sum_j A_j sin(2 pi f_j t + phi_j) per rotation / translation axis."""

    t_start: np.ndarray  # [F] exposure starts
    t_end: np.ndarray  # [F] exposure ends
    base_angle: np.ndarray  # [F] orbit angle (rad) parked at during exposure k
    shake_rot: np.ndarray  # [F, 3] rotation-vector amplitude a_k (camera frame)
    shake_trans: np.ndarray  # [F, 3] translation amplitude b_k (camera frame)
    tremor_freq: np.ndarray | None = None  # [J, 6] Hz, per component and axis (rot xyz, trans xyz)
    tremor_amp: np.ndarray | None = None  # [J, 6] amplitudes (rad, world units)
    tremor_phase: np.ndarray | None = None  # [J, 6] rad

    def tremor(self, t: float | np.ndarray) -> np.ndarray:
        """[T, 6] tremor offsets (rotation vector [3], translation [3], camera frame) at times t."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        if self.tremor_amp is None:
            return np.zeros((len(t), 6))
        if self.tremor_freq is None or self.tremor_phase is None:
            raise ValueError("tremor_amp needs tremor_freq and tremor_phase")
        arg = 2 * np.pi * self.tremor_freq[None] * t[:, None, None] + self.tremor_phase[None]
        return (self.tremor_amp[None] * np.sin(arg)).sum(axis=1)

    def _phase(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each t: base angle and shake offset (rot [3], trans [3])."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        ang = np.empty(len(t))
        rot = np.empty((len(t), 3))
        tr = np.empty((len(t), 3))
        ts, te = self.t_start, self.t_end
        for i, ti in enumerate(t):
            k = int(np.searchsorted(ts, ti, side="right")) - 1  # last exposure started at or before ti
            if k < 0:
                ang[i], rot[i], tr[i] = self.base_angle[0], -self.shake_rot[0] / 2, -self.shake_trans[0] / 2
            elif ti <= te[k]:
                s = 0.5 if te[k] == ts[k] else (ti - ts[k]) / (te[k] - ts[k])
                ang[i] = self.base_angle[k]
                rot[i] = self.shake_rot[k] * (s - 0.5)
                tr[i] = self.shake_trans[k] * (s - 0.5)
            elif k == len(ts) - 1:
                ang[i], rot[i], tr[i] = self.base_angle[k], self.shake_rot[k] / 2, self.shake_trans[k] / 2
            else:
                g = _smoothstep((ti - te[k]) / (ts[k + 1] - te[k]))
                ang[i] = (1 - g) * self.base_angle[k] + g * self.base_angle[k + 1]
                rot[i] = (1 - g) * self.shake_rot[k] / 2 - g * self.shake_rot[k + 1] / 2
                tr[i] = (1 - g) * self.shake_trans[k] / 2 - g * self.shake_trans[k + 1] / 2
        return ang, rot, tr

    def c2w(self, t: float | np.ndarray) -> np.ndarray:
        """c2w [4, 4] at a time (seconds) or [T, 4, 4] at an array of times."""
        scalar = np.ndim(t) == 0
        ang, rot, tr = self._phase(t)
        if self.tremor_amp is not None:
            off = self.tremor(t)
            rot, tr = rot + off[:, :3], tr + off[:, 3:]
        out = np.empty((len(ang), 4, 4))
        for i in range(len(ang)):
            eye = TARGET + ORBIT_RADIUS * np.array([math.sin(ang[i]), 0.0, -math.cos(ang[i])])
            eye[1] = -0.35 + 0.25 * math.sin(2.0 * ang[i] / math.radians(ORBIT_HALF_ANGLE_DEG))
            base = look_at(eye, TARGET)
            local = np.eye(4)
            local[:3, :3] = Rotation.from_rotvec(rot[i]).as_matrix()
            local[:3, 3] = tr[i]
            out[i] = base @ local
        return out[0] if scalar else out


# --------------------------------------------------------------------------- scene


@dataclass
class SynthScene:
    """A synthetic capture and its ground truth, never mixed: ``capture`` is what a method
    reads (blurry frames, exposures, events, K, the poses the sensor gives, test views);
    everything else is truth, for evaluation only (``write_scene`` puts it under gt/)."""

    capture: Capture  # what the method reads
    gt_frames: np.ndarray  # [F, H, W, D] float32 sharp mid-exposure frames as the camera records them, noise-free
    gt_depths: np.ndarray  # [F, H, W] float32 z-depth at mid-exposure (0: no surface)
    trajectory: Trajectory = field(repr=False)
    ray_scene: RayScene = field(repr=False)
    name: str = "boxes"
    c_pos: np.ndarray | None = field(default=None, repr=False)  # [H, W] true per-pixel thresholds
    c_neg: np.ndarray | None = field(default=None, repr=False)
    sensor: Sensor = field(default_factory=Sensor, repr=False)  # the simulated camera (truth)
    gt_c2w: np.ndarray | None = field(default=None, repr=False)  # [F, 4, 4] true mid-exposure poses
    gt_test_c2w: np.ndarray | None = field(default=None, repr=False)  # [T, 4, 4] true test-view poses
    gt_test_images: np.ndarray | None = field(default=None, repr=False)  # [T, H, W, D] noise-free, camera domain
    truth: dict = field(default_factory=dict, repr=False)  # JSON-able: sensor, seed, thresholds, sharp frames, ...

    def c2w_at(self, t: float | np.ndarray) -> np.ndarray:  # [4, 4] or [T, 4, 4]
        """True c2w [4, 4] at any time t (seconds) of the capture (or [T, 4, 4] for an array)."""
        return self.trajectory.c2w(t)

    def gt_c2w_at(self, frame_index: int, t: float | np.ndarray) -> np.ndarray:  # [4, 4] or [T, 4, 4]
        """True c2w [4, 4] (or [T, 4, 4]) at time(s) ``t`` in seconds inside frame
        ``frame_index``'s exposure [t_start, t_end]; ValueError outside it."""
        f = self.capture.num_frames
        if not (0 <= int(frame_index) < f):
            raise ValueError(f"frame_index: must be in [0, {f}), got {frame_index}")
        t0, t1 = self.capture.exposures[int(frame_index)]
        ta = np.asarray(t, np.float64)
        tol = 1e-9
        if np.any(ta < t0 - tol) or np.any(ta > t1 + tol):
            raise ValueError(f"t: must lie in frame {frame_index}'s exposure [{t0}, {t1}] s, got {t}")
        return self.trajectory.c2w(np.clip(ta, t0, t1))

    def gt_trajectory(self, frame_index: int, n: int) -> np.ndarray:
        """[n, 4, 4] true poses at n evenly spaced instants t_start .. t_end of a frame."""
        t0, t1 = self.capture.exposures[int(frame_index)]
        return self.gt_c2w_at(frame_index, np.linspace(t0, t1, int(n)))

    def render(self, c2w: np.ndarray) -> np.ndarray:
        """Sharp ray-cast render(s) of irradiance [.., H, W, D] from any pose(s) with the capture's K
        (``aps_response(render(c2w), sensor)`` is what the camera records, noise-free)."""
        c = self.capture
        return render(self.ray_scene, c2w, c.K, c.width, c.height)


def sensor_events(
    irradiance: np.ndarray,  # [S, H, W, D] linear irradiance renders
    times: np.ndarray,  # [S] seconds, increasing
    sensor: Sensor,
    seed: int = 0,
    cfa: str | None = None,
) -> tuple[EventStream, np.ndarray, np.ndarray]:
    """The events ``sensor``'s pixels fire watching ``irradiance``: with a colour filter array
    ``cfa`` (a colour DAVIS) each pixel fires on the log of its own channel (``edi.cfa.mosaic``);
    without, its luminance model for colour (the channel mean goes through ``simulate_events`` as it
    always did); thresholds, mismatch, refractory period, noise, hot pixels and log offset per pixel
    either way. Returns (EventStream, c_pos [H, W], c_neg [H, W])."""
    irr = np.asarray(irradiance)
    if cfa is None and irr.ndim == 4 and irr.shape[3] == 3 and tuple(sensor.luminance) != CHANNEL_MEAN:
        irr = np.tensordot(irr, np.asarray(sensor.luminance, np.float32), axes=([3], [0]))  # [S, H, W]
    hot = int(round(sensor.hot_pixel_fraction * irr.shape[1] * irr.shape[2]))
    return simulate_events(
        irr,
        times,
        c=(sensor.c_pos, sensor.c_neg),
        sigma_c=sensor.sigma_c,
        refractory=sensor.refractory,
        noise_hz=sensor.noise_hz,
        leak_hz=sensor.leak_hz,
        hot_pixels=hot,
        eps=sensor.log_eps,
        seed=seed,
        return_thresholds=True,
        cfa=cfa,
    )


def _intrinsics(width: int, height: int) -> np.ndarray:
    f = 0.5 * width / math.tan(math.radians(HFOV_DEG) / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def _tremor(rng: np.random.Generator, strength: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random tremor sinusoids [J, 6] (freq Hz, amplitude, phase) with a 1/f amplitude spectrum and
    RMS TREMOR_ROT_RAD * strength (rotation axes), TREMOR_TRANS * ORBIT_RADIUS * strength (translation)."""
    lo, hi = TREMOR_BAND_HZ
    freq = lo * (hi / lo) ** rng.random((TREMOR_COMPONENTS, 6))  # log-uniform in the band
    amp = 1.0 / freq
    amp = amp / np.sqrt((amp**2).sum(axis=0, keepdims=True) / 2)  # unit RMS per axis
    amp[:, :3] *= TREMOR_ROT_RAD * strength
    amp[:, 3:] *= TREMOR_TRANS * ORBIT_RADIUS * strength
    phase = 2 * np.pi * rng.random((TREMOR_COMPONENTS, 6))
    return freq, amp, phase


def _perturb(
    c2w: np.ndarray,  # [N, 4, 4]
    rng: np.random.Generator,
    rot_deg: float,
    trans: float,
) -> np.ndarray:
    """Poses with SfM-like error: a random rotation of RMS angle ``rot_deg`` (camera frame) and a
    random offset of RMS length ``trans`` (world units) per pose."""
    out = c2w.copy()
    n = len(c2w)
    dr = Rotation.from_rotvec(np.radians(rot_deg) / math.sqrt(3) * rng.standard_normal((n, 3))).as_matrix()
    out[:, :3, :3] = c2w[:, :3, :3] @ dr
    out[:, :3, 3] += trans / math.sqrt(3) * rng.standard_normal((n, 3))
    return out


def _resolve_sensor(sensor: str | Sensor, poses, c, sigma_c, noise_hz, refractory, tremor) -> Sensor:
    if isinstance(sensor, str):
        if sensor not in SENSORS:
            raise CaptureError(None, "sensor", f"unknown sensor {sensor!r}; choose from {sorted(SENSORS)}")
        sensor = SENSORS[sensor]
    elif not isinstance(sensor, Sensor):
        raise CaptureError(None, "sensor", f"must be a preset name or a Sensor, got {type(sensor).__name__}")
    over = {
        k: v
        for k, v in (
            ("poses", poses),
            ("sigma_c", sigma_c),
            ("noise_hz", noise_hz),
            ("refractory", refractory),
            ("tremor", tremor),
        )
        if v is not None
    }
    if c is not None:
        try:
            cp, cn = (float(c), float(c)) if np.ndim(c) == 0 else (float(c[0]), float(c[1]))
        except (TypeError, ValueError, IndexError):
            raise CaptureError(None, "c", f"must be a float or a pair (c_pos, c_neg), got {c!r}") from None
        over.update(c_pos=cp, c_neg=cn)
    return replace(sensor, **over).validate()


def make_scene(
    name: str = "boxes",
    size: str = "tiny",
    seed: int = 0,
    rgb: bool = False,
    sensor: str | Sensor = "realistic",
    poses: Literal["exact", "noisy", "none"] | None = None,
    c: float | tuple[float, float] | None = None,
    sigma_c: float | None = None,
    noise_hz: float | None = None,
    shake: float = 1.0,
    tremor: float | None = None,
    n_frames: int | None = None,
    n_test: int | None = None,
    exposure: float | None = None,
    sharp_fraction: float = 0.0,
    n_blur: int = N_BLUR,
    refractory: float | None = None,
    cfa: str | None = None,
    raw_frames: bool = False,
) -> SynthScene:
    """Build a synthetic blurry event capture with ground truth.

    Args:
        name: a key of ``SCENES``. size: "tiny" (64x48), "small" (160x120), "davis" (346x260).
        seed: shake, tremor, thresholds, noise and pose errors. rgb: colour (D = 3) or grey (D = 1).
        sensor: "realistic" (default), "ideal" (the idealised world), or a ``Sensor``.
        poses: overrides ``sensor.poses``: "exact", "noisy" (SfM-like error) or "none".
        c, sigma_c, noise_hz, refractory, tremor: override the sensor's values (``c``: a float
            sets c_pos = c_neg, or a pair (c_pos, c_neg)); None keeps the sensor's.
        shake: scales the per-exposure camera motion (0: sharp frames, unless tremor).
        n_frames: training frames (default 10). n_test: held-out test views (default 3).
        exposure: seconds (default 0.05, frame period 0.1 s).
        sharp_fraction: fraction of frames (rounded) with no shake, hence sharp.
        n_blur: renders averaged per exposure (>= 32).
        cfa: a colour DAVIS with this Bayer filter ("RGGB", "BGGR", "GRBG", "GBRG"; implies a colour
            scene): each pixel's events fire on the log of its own channel, the APS records the raw
            mosaic (response, read noise, quantisation per pixel), and the frames are the camera
            software's bilinear demosaic of it (``edi.cfa.demosaic``, re-quantised) or, with
            ``raw_frames``, the raw mosaic itself (D = 1). The capture records ``cfa``. Ground truth
            (``gt_frames``, test views' images) stays full RGB through the response, what a perfect
            camera would show; with raw frames the capture's test images are raw mosaics too.
            None: grey, or with ``rgb`` events of ``sensor.luminance`` (the luminance baseline).
        raw_frames: with ``cfa``, keep the frames as 1-channel raw mosaics.

    Raises:
        CaptureError naming the argument (or ``sensor.<field>``) of a value that cannot work.
    """
    if name not in SCENES:
        raise CaptureError(None, "name", f"unknown scene {name!r}; choose from {sorted(SCENES)}")
    if size not in SIZES:
        raise CaptureError(None, "size", f"must be one of {sorted(SIZES)}, got {size!r}")
    if not (math.isfinite(shake) and shake >= 0):
        raise CaptureError(None, "shake", f"must be a finite number >= 0, got {shake!r}")
    if not (0.0 <= sharp_fraction <= 1.0):
        raise CaptureError(None, "sharp_fraction", f"must be in [0, 1], got {sharp_fraction!r}")
    n_frames = 10 if n_frames is None else int(n_frames)
    n_test = 3 if n_test is None else int(n_test)
    if n_frames < 2:
        raise CaptureError(None, "n_frames", f"need at least 2, got {n_frames}")
    if not (0 <= n_test <= n_frames - 1):
        raise CaptureError(None, "n_test", f"must be in [0, n_frames - 1 = {n_frames - 1}], got {n_test}")
    exposure = DEFAULT_EXPOSURE_S if exposure is None else float(exposure)
    if not (0 < exposure <= PERIOD_S - 0.01):
        raise CaptureError(None, "exposure", f"must be in (0, {PERIOD_S - 0.01}] s, got {exposure!r}")
    if int(n_blur) < 32:
        raise CaptureError(None, "n_blur", f"must be >= 32, got {n_blur}")
    cfa = _check_cfa(cfa, raw_frames)
    rgb = rgb or cfa is not None  # a colour filter array sees a colour world
    sen = _resolve_sensor(sensor, poses, c, sigma_c, noise_hz, refractory, tremor)
    width, height = SIZES[size]
    K = _intrinsics(width, height)
    rng = np.random.default_rng(seed)

    dt = exposure / n_blur
    period_steps = int(round(PERIOD_S / dt))
    lead_steps = int(round(LEAD_S / dt))
    starts = (lead_steps + period_steps * np.arange(n_frames)) * dt
    ends = starts + n_blur * dt
    total_steps = lead_steps * 2 + period_steps * (n_frames - 1) + n_blur
    grid = np.arange(total_steps + 1) * dt  # exposure boundaries are grid instants

    half = math.radians(ORBIT_HALF_ANGLE_DEG)
    angles = np.linspace(-half, half, n_frames)
    dirs_r = rng.standard_normal((n_frames, 3))
    dirs_r /= np.linalg.norm(dirs_r, axis=1, keepdims=True)
    dirs_t = rng.standard_normal((n_frames, 3))
    dirs_t /= np.linalg.norm(dirs_t, axis=1, keepdims=True)
    mags = rng.uniform(0.8, 1.0, size=(n_frames, 1))
    sharp = np.zeros(n_frames, bool)
    n_sharp = int(round(sharp_fraction * n_frames))
    if n_sharp:
        sharp[rng.choice(n_frames, n_sharp, replace=False)] = True
    amp = shake * mags * (~sharp[:, None])
    traj = Trajectory(starts, ends, angles, amp * ROT_SHAKE_RAD * dirs_r, amp * TRANS_SHAKE * ORBIT_RADIUS * dirs_t)
    if sen.tremor > 0:  # drawn after everything the ideal world draws: its scenes stay bit for bit
        traj.tremor_freq, traj.tremor_amp, traj.tremor_phase = _tremor(rng, sen.tremor)
    rng_aps = np.random.default_rng([seed, 1])  # read noise
    rng_pose = np.random.default_rng([seed, 2])  # pose errors

    scene = SCENES[name](width, rgb)
    renders = render(scene, traj.c2w(grid), K, width, height)  # [S, H, W, D] irradiance
    starts_i = lead_steps + period_steps * np.arange(n_frames)
    frames = _aps_frames(renders, starts_i, n_blur, sen, rng_aps, cfa, raw_frames)
    events, c_pos, c_neg = sensor_events(renders, grid, sen, seed, cfa=cfa)
    del renders
    mids = 0.5 * (starts + ends)
    c2w_mid = traj.c2w(mids)
    gt_irr, gt_depths = render(scene, c2w_mid, K, width, height, return_depth=True)
    gt_frames = aps_response(gt_irr, sen).astype(np.float32)
    # held-out views: mid-gap instants, spread over the capture
    gaps = np.linspace(0, n_frames - 2, n_test).round().astype(int) if n_test else np.zeros(0, int)
    gaps = np.unique(gaps)
    test_t = np.array([0.5 * (ends[g] + starts[g + 1]) for g in gaps])
    test_c2w = traj.c2w(test_t) if len(gaps) else np.zeros((0, 4, 4))
    test_irr = render(scene, test_c2w, K, width, height) if len(gaps) else np.zeros((0, height, width, scene.channels))
    gt_test = aps_response(test_irr, sen).astype(np.float32)
    test_rec = aps_record(test_irr, sen, rng_aps) if sen.record_test_views else gt_test
    if cfa is not None and raw_frames:  # the capture's test images in the frames' raw domain; gt/ keeps RGB
        test_rec = quantize(mosaic(test_rec, cfa)[..., None], sen.bits) if len(gaps) else test_rec[..., :1]
    given: np.ndarray | None = c2w_mid
    given_test: np.ndarray | list[None] = test_c2w
    if sen.poses == "noisy":
        given, given_test = (_perturb(m, rng_pose, sen.pose_rot_deg, sen.pose_trans) for m in (c2w_mid, test_c2w))
    if sen.poses == "none":
        given, given_test = None, [None] * len(gaps)
    test_views = [
        TestView(name=f"test_{j:03d}", t=float(test_t[j]), c2w=given_test[j], image=test_rec[j])
        for j in range(len(gaps))
    ]
    meta = {
        "source_layout": "synthetic",
        "scene": name,
        "size": size,
        "rgb": bool(rgb),
        "sensor": sensor if isinstance(sensor, str) else "custom",
        "poses": sen.poses,
        "renderer": "trimesh ray casting" + (" (embree)" if _has_embree() else " (pure Python)"),
    }
    if cfa is not None:  # a label (the capture states its filter in Capture.cfa): gt/gt.json's meta carries it too
        meta["cfa"] = cfa
    cap = Capture(
        frames=frames,
        exposures=np.stack([starts, ends], 1),
        events=events,
        K=K,
        c2w=given,
        split=["train"] * n_frames,
        test_views=test_views,
        names=[frame_name(k) for k in range(n_frames)],
        meta=meta,
        pose_trust=POSE_TRUST_OF[sen.poses],
        cfa=cfa,
    ).validate("make_scene")
    hit = gt_depths[gt_depths > 0]
    truth = {
        "sensor": asdict(sen),
        "seed": int(seed),
        "c": [sen.c_pos, sen.c_neg],
        "shake": float(shake),
        "n_blur": int(n_blur),
        "exposure": float(exposure),
        "period": PERIOD_S,
        "sharp_frames": np.flatnonzero(sharp).tolist(),
        "depth_range": [float(hit.min()), float(hit.max())] if len(hit) else None,
        "event_channel": (
            f"cfa {cfa} (each pixel's own channel)"
            if cfa is not None
            else ("luminance " + str(list(sen.luminance)))
            if rgb
            else "grey"
        ),
        "cfa": cfa,
        "frames": "raw mosaic" if raw_frames else ("demosaiced" if cfa is not None else "as rendered"),
    }
    return SynthScene(
        capture=cap,
        gt_frames=gt_frames,
        gt_depths=gt_depths,
        trajectory=traj,
        ray_scene=scene,
        name=name,
        c_pos=c_pos,
        c_neg=c_neg,
        sensor=sen,
        gt_c2w=c2w_mid,
        gt_test_c2w=test_c2w,
        gt_test_images=gt_test,
        truth=truth,
    )


def _check_cfa(cfa: str | None, raw_frames: bool) -> str | None:
    """make_scene's ``cfa`` as a pattern of ``edi.cfa`` (or None); CaptureError naming the argument."""
    if cfa is None:
        if raw_frames:
            raise CaptureError(None, "raw_frames", "raw mosaic frames need a colour filter array (pass cfa)")
        return None
    try:
        return check_pattern(cfa)
    except ValueError as exc:
        raise CaptureError(None, "cfa", str(exc).split(": ", 1)[-1]) from None


def _aps_frames(
    renders: np.ndarray,  # [S, H, W, D] irradiance on the time grid
    starts: np.ndarray,  # [F] grid index of each exposure's start
    n_blur: int,
    sen: Sensor,
    rng: np.random.Generator,
    cfa: str | None,
    raw_frames: bool,
) -> np.ndarray:  # [F, H, W, D'] float32
    """The blurry frames the APS records: the trapezoidal mean of each exposure's n_blur + 1 renders
    through ``aps_record``. With ``cfa`` the APS records each pixel's own channel (the raw mosaic,
    D' = 1), then, unless ``raw_frames``, the camera software demosaics it (bilinear, ``edi.cfa``) and
    writes it at the APS's bit depth (D' = 3)."""
    _, h, w, d = renders.shape
    frames = np.empty((len(starts), h, w, 1 if cfa is not None else d), np.float32)
    trap = np.full(n_blur + 1, 1.0 / n_blur)
    trap[[0, -1]] *= 0.5  # trapezoidal mean over the exposure's n_blur + 1 grid instants
    for k, i0 in enumerate(starts):
        blurred = np.tensordot(trap, renders[i0 : i0 + n_blur + 1], axes=1)
        if cfa is not None:
            blurred = mosaic(blurred, cfa)[..., None]
        frames[k] = aps_record(blurred, sen, rng)
    if cfa is not None and not raw_frames:
        frames = quantize(demosaic(frames[..., 0], cfa), sen.bits)
    return frames


def _has_embree() -> bool:
    import trimesh.ray

    return bool(getattr(trimesh.ray, "has_embree", False))


def check_replaceable(out: Path, overwrite: bool, contents: set[str], marker: str, what: str, field="out_dir") -> None:
    """The rule of every writer that may replace a folder (``write_scene``, ``python -m scenes.convert``):
    ``out`` may be written when it does not exist or is empty; otherwise only with ``overwrite``, and only
    when it holds nothing but the names the writer itself writes (``contents``) and its ``marker`` file
    (a path relative to ``out``), so a folder of a user's own files is never deleted.

    Raises:
        CaptureError: ``out`` is a file, or non-empty without ``overwrite``, or not ``what``; names ``field``.
    """
    if out.exists() and not out.is_dir():
        raise CaptureError(None, field, f"{out} exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise CaptureError(None, field, f"{out} already exists and is not empty (pass overwrite)")
        held = sorted(p.name for p in out.iterdir())
        if not (set(held) <= contents and (out / marker).is_file()):
            raise CaptureError(
                None,
                field,
                f"refusing to overwrite {out}: it is not {what} "
                f"(it holds {', '.join(held[:5])}{' ...' if len(held) > 5 else ''})",
            )


def write_scene(
    scene: SynthScene, out_dir: str | os.PathLike, overwrite: bool = False, trajectory_samples: int = 9
) -> Path:
    """Write ``out_dir/capture`` (ebad-capture/1, what a method reads) and ``out_dir/gt``
    (sharp mid-exposure frames as the camera records them, noise-free, as lossless images;
    depths; true thresholds; gt.json with the truth, the true mid-exposure poses and per-frame
    trajectories, and the test views' true poses and noise-free images under gt/test),
    atomically: both go to a temporary folder renamed at the end. The capture keeps its test
    views' images (recorded by the camera) and the poses the sensor gives (exact, noisy or
    none): they are held out, never trained on; the training frames' sharp renders exist only
    under gt/."""
    if scene.gt_c2w is None or scene.gt_test_c2w is None or scene.gt_test_images is None:
        raise CaptureError(None, "scene", "needs its gt_c2w, gt_test_c2w and gt_test_images (make_scene sets them)")
    out = Path(out_dir)
    check_replaceable(out, overwrite, {"capture", "gt"}, "gt/gt.json", "a synthetic scene written by write_scene")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        save(scene.capture, tmp / "capture")
        gt = tmp / "gt"
        (gt / "frames").mkdir(parents=True)
        cap = scene.capture
        files = [
            write_image(gt / "frames" / cap.names[k], scene.gt_frames[k]).relative_to(gt).as_posix()
            for k in range(cap.num_frames)
        ]
        (gt / "test").mkdir()
        test_docs = [
            {
                "name": tv.name,
                "t": float(tv.t),
                "c2w": np.asarray(scene.gt_test_c2w[j]).tolist(),
                "file": write_image(gt / "test" / tv.name, scene.gt_test_images[j]).relative_to(gt).as_posix(),
            }
            for j, tv in enumerate(cap.test_views)
        ]
        np.save(gt / "depths.npy", scene.gt_depths)
        if scene.c_pos is not None and scene.c_neg is not None:
            np.savez(gt / "thresholds.npz", c_pos=scene.c_pos, c_neg=scene.c_neg)
        doc = {
            "scene": scene.name,
            "meta": cap.meta,
            "truth": scene.truth,
            "frames": [
                {
                    "name": cap.names[k],
                    "file": files[k],
                    "t_start": float(cap.exposures[k, 0]),
                    "t_end": float(cap.exposures[k, 1]),
                    "c2w_mid": scene.gt_c2w[k].tolist(),
                    "trajectory": {
                        "t": np.linspace(cap.exposures[k, 0], cap.exposures[k, 1], trajectory_samples).tolist(),
                        "c2w": scene.gt_trajectory(k, trajectory_samples).tolist(),
                    },
                }
                for k in range(cap.num_frames)
            ],
            "test_views": test_docs,
            "depths": "depths.npy",
            "thresholds": "thresholds.npz" if scene.c_pos is not None else None,
        }
        (gt / "gt.json").write_text(json.dumps(doc, indent=1))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
