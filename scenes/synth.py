"""Tiny synthetic blurry event captures with exact ground truth.

A scene (``SCENES``: "boxes", "spheres") is built from textured quads, boxes and spheres
(textures: scikit-image's bundled photographs, their 8-bit values taken as linear intensity
and rescaled into [0.05, 0.95]) and rendered by ray casting (``scenes.render``), never by
splat_cpu.

Timeline: frame k is exposed over [t_k, t_k + exposure], t_k = lead + k * period. The camera
follows a horizontal arc around the scene: it is parked on the arc during each exposure and
glides (smoothstep) to the next parking spot between exposures. On top, a per-exposure shake
(camera-local rotation vector and translation) moves linearly from -a_k / 2 to +a_k / 2 over
exposure k, and glides between exposures, so the whole trajectory is continuous and the blur
of frame k comes from its shake alone (``shake`` scales it; shake = 0 gives sharp frames,
``sharp_fraction`` zeroes it on a random subset of frames).

Renders sit on a uniform grid of step exposure / n_blur over the whole capture, exposure
boundaries included; a blurry frame is the trapezoidal mean of the n_blur + 1 (>= 33) renders
spanning its exposure, in linear intensity, quantised to 8 bits; the events come from
``simulate_events`` over all renders.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from .capture import Capture, TestView
from .format import save
from .images import quantize, write_image
from .render import Quad, RayScene, Sphere, render
from .simulate import simulate_events

__all__ = ["SynthScene", "make_scene", "write_scene", "SCENES", "SIZES", "look_at"]

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


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, -1.0, 0.0])) -> np.ndarray:
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
        a = a[int(crop[0] * h):int(crop[1] * h), int(crop[2] * w):int(crop[3] * w)]
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
    sx, sy, sz = (np.asarray(size, np.float64) / 2)
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
    wall = Quad(np.array([-11.0, -6.5, 8.5]), np.array([22.0, 0, 0]), np.array([0, 8.0, 0]),
                _texture("astronaut", rgb, 22.0 * ppu(8.5)))
    floor = Quad(np.array([-11.0, 1.4, -1.0]), np.array([22.0, 0, 0]), np.array([0, 0, 9.5]),
                 _texture("gravel", rgb, 22.0 * ppu(3.0)))
    prims = [wall, floor]
    prims += _box([-1.3, 0.55, 3.6], [1.2, 1.7, 1.2],
                  [_texture("coffee", rgb, 1.7 * ppu(3.0)), _texture("brick", rgb, 1.7 * ppu(3.0))])
    prims += _box([1.25, 0.8, 4.6], [1.3, 1.2, 1.3],
                  [_texture("chelsea", rgb, 1.3 * ppu(4.0)), _texture("grass", rgb, 1.3 * ppu(4.0))])
    prims.append(Quad(np.array([-0.2, -1.6, 6.0]), np.array([1.8, 0, 0.4]), np.array([0, 1.3, 0]),
                      _texture("rocket", rgb, 1.8 * ppu(6.0))))
    return RayScene(prims, background=0.1)


def build_spheres(width: int, rgb: bool) -> RayScene:
    """Textured spheres at three depths before a textured wall and floor."""
    ppu = lambda d: 1.5 * _px_per_unit(width, d)  # noqa: E731
    wall = Quad(np.array([-11.0, -6.5, 8.5]), np.array([22.0, 0, 0]), np.array([0, 8.0, 0]),
                _texture("coffee", rgb, 22.0 * ppu(8.5)))
    floor = Quad(np.array([-11.0, 1.4, -1.0]), np.array([22.0, 0, 0]), np.array([0, 0, 9.5]),
                 _texture("brick", rgb, 22.0 * ppu(3.0)))
    prims = [wall, floor,
             Sphere(np.array([-1.2, 0.5, 3.3]), 0.85, _texture("astronaut", rgb, 5.3 * ppu(3.0))),
             Sphere(np.array([1.1, 0.2, 4.6]), 1.1, _texture("chelsea", rgb, 6.9 * ppu(4.0))),
             Sphere(np.array([0.0, -1.2, 6.4]), 0.9, _texture("rocket", rgb, 5.7 * ppu(6.0)))]
    return RayScene(prims, background=0.1)


SCENES: dict[str, Callable[[int, bool], RayScene]] = {"boxes": build_boxes, "spheres": build_spheres}


# --------------------------------------------------------------------------- trajectory


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


@dataclass
class Trajectory:
    """Continuous camera path: parked base poses during exposures plus linear shake."""

    t_start: np.ndarray  # [F] exposure starts
    t_end: np.ndarray  # [F] exposure ends
    base_angle: np.ndarray  # [F] orbit angle (rad) parked at during exposure k
    shake_rot: np.ndarray  # [F, 3] rotation-vector amplitude a_k (camera frame)
    shake_trans: np.ndarray  # [F, 3] translation amplitude b_k (camera frame)

    def _phase(self, t: np.ndarray):
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

    def c2w(self, t) -> np.ndarray:
        """c2w [4, 4] at a time (seconds) or [T, 4, 4] at an array of times."""
        scalar = np.ndim(t) == 0
        ang, rot, tr = self._phase(t)
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
    """A synthetic capture and its ground truth (never mixed: ``write_scene`` puts them in
    separate folders)."""

    capture: Capture  # what the trainer reads: blurry frames, exposures, events, K, mid-exposure c2w
    gt_frames: np.ndarray  # [F, H, W, D] float32 sharp renders at each frame's mid-exposure
    gt_depths: np.ndarray  # [F, H, W] float32 z-depth at mid-exposure (0: no surface)
    trajectory: Trajectory = field(repr=False)
    ray_scene: RayScene = field(repr=False)
    name: str = "boxes"
    c_pos: np.ndarray | None = field(default=None, repr=False)  # [H, W] true per-pixel thresholds
    c_neg: np.ndarray | None = field(default=None, repr=False)

    def c2w_at(self, t):
        """True c2w [4, 4] at any time t (seconds) of the capture (or [T, 4, 4] for an array)."""
        return self.trajectory.c2w(t)

    def gt_c2w_at(self, frame_index: int, t):
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
        """Sharp ray-cast render(s) [.., H, W, D] from any pose(s) with the capture's K."""
        c = self.capture
        return render(self.ray_scene, c2w, c.K, c.width, c.height)


def _intrinsics(width: int, height: int) -> np.ndarray:
    f = 0.5 * width / math.tan(math.radians(HFOV_DEG) / 2)
    return np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


def make_scene(name: str = "boxes", size: str = "tiny", seed: int = 0, rgb: bool = False, c: float = 0.2,
               sigma_c: float = 0.03, noise_hz: float = 0.0, shake: float = 1.0, n_frames: int | None = None,
               n_test: int | None = None, exposure: float | None = None, sharp_fraction: float = 0.0,
               n_blur: int = N_BLUR, refractory: float = 0.0) -> SynthScene:
    """Build a synthetic blurry event capture with ground truth.

    Args:
        name: a key of ``SCENES``. size: "tiny" (64x48), "small" (160x120), "davis" (346x260).
        seed: shake, thresholds and noise. rgb: colour (D = 3) or grey (D = 1).
        c, sigma_c, noise_hz, refractory: event simulator settings (see ``simulate_events``).
        shake: scales the per-exposure camera motion (0: sharp frames).
        n_frames: training frames (default 10). n_test: held-out test views (default 3).
        exposure: seconds (default 0.05, frame period 0.1 s).
        sharp_fraction: fraction of frames (rounded) with no shake, hence sharp.
        n_blur: renders averaged per exposure (>= 32).
    """
    if name not in SCENES:
        raise ValueError(f"name: unknown scene {name!r}; choose from {sorted(SCENES)}")
    if size not in SIZES:
        raise ValueError(f"size: must be one of {sorted(SIZES)}, got {size!r}")
    if not (math.isfinite(shake) and shake >= 0):
        raise ValueError(f"shake: must be a finite number >= 0, got {shake!r}")
    if not (0.0 <= sharp_fraction <= 1.0):
        raise ValueError(f"sharp_fraction: must be in [0, 1], got {sharp_fraction!r}")
    n_frames = 10 if n_frames is None else int(n_frames)
    n_test = 3 if n_test is None else int(n_test)
    if n_frames < 2:
        raise ValueError(f"n_frames: need at least 2, got {n_frames}")
    if not (0 <= n_test <= n_frames - 1):
        raise ValueError(f"n_test: must be in [0, n_frames - 1 = {n_frames - 1}], got {n_test}")
    exposure = DEFAULT_EXPOSURE_S if exposure is None else float(exposure)
    if not (0 < exposure <= PERIOD_S - 0.01):
        raise ValueError(f"exposure: must be in (0, {PERIOD_S - 0.01}] s, got {exposure!r}")
    if int(n_blur) < 32:
        raise ValueError(f"n_blur: must be >= 32, got {n_blur}")
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

    scene = SCENES[name](width, rgb)
    renders = render(scene, traj.c2w(grid), K, width, height)  # [S, H, W, D]
    frames = np.empty((n_frames, height, width, scene.channels), np.float32)
    trap = np.full(n_blur + 1, 1.0 / n_blur)
    trap[[0, -1]] *= 0.5  # trapezoidal mean over the exposure's n_blur + 1 grid instants
    for k in range(n_frames):
        i0 = lead_steps + period_steps * k
        frames[k] = quantize(np.tensordot(trap, renders[i0:i0 + n_blur + 1], axes=1))
    events, c_pos, c_neg = simulate_events(renders, grid, c=c, sigma_c=sigma_c, refractory=refractory,
                                           noise_hz=noise_hz, seed=seed, return_thresholds=True)
    del renders
    mids = 0.5 * (starts + ends)
    c2w_mid = traj.c2w(mids)
    gt_frames, gt_depths = render(scene, c2w_mid, K, width, height, return_depth=True)
    # held-out views: mid-gap instants, spread over the capture
    gaps = np.linspace(0, n_frames - 2, n_test).round().astype(int) if n_test else np.zeros(0, int)
    gaps = np.unique(gaps)
    test_views = []
    for j, g in enumerate(gaps):
        t = float(0.5 * (ends[g] + starts[g + 1]))
        pose = traj.c2w(t)
        test_views.append(TestView(name=f"test_{j:03d}", t=t, c2w=pose,
                                   image=np.clip(render(scene, pose, K, width, height), 0, 1).astype(np.float32)))
    meta = {"source_layout": "synthetic", "scene": name, "size": size, "seed": int(seed), "rgb": bool(rgb),
            "c": float(c), "sigma_c": float(sigma_c), "noise_hz": float(noise_hz), "shake": float(shake),
            "refractory": float(refractory), "n_blur": int(n_blur), "exposure": float(exposure),
            "period": PERIOD_S, "sharp_frames": np.flatnonzero(sharp).tolist(),
            "event_channel": "mean over colour channels" if rgb else "grey",
            "renderer": "trimesh ray casting" + (" (embree)" if _has_embree() else " (pure Python)")}
    cap = Capture(frames=frames, exposures=np.stack([starts, ends], 1), events=events, K=K, c2w=c2w_mid,
                  split=["train"] * n_frames, test_views=test_views, names=[f"{k:04d}" for k in range(n_frames)],
                  meta=meta).validate("make_scene")
    return SynthScene(capture=cap, gt_frames=np.clip(gt_frames, 0, 1).astype(np.float32), gt_depths=gt_depths,
                      trajectory=traj, ray_scene=scene, name=name, c_pos=c_pos, c_neg=c_neg)


def _has_embree() -> bool:
    import trimesh.ray

    return bool(getattr(trimesh.ray, "has_embree", False))


def write_scene(scene: SynthScene, out_dir: str | os.PathLike, overwrite: bool = False,
                trajectory_samples: int = 9) -> Path:
    """Write ``out_dir/capture`` (ebad-capture/1, what the trainer reads) and ``out_dir/gt``
    (sharp mid-exposure frames as lossless images, depths, true thresholds and per-frame
    trajectories in gt.json, and copies of the held-out test views), atomically: both go to a
    temporary folder renamed at the end. The capture keeps its test views' images too (the
    format's ``test_views[].file``): they are held-out poses the trainer evaluates on, never
    trains on; the training frames' sharp renders exist only under gt/."""
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise ValueError(f"out_dir: {out} already exists and is not empty (pass overwrite)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        save(scene.capture, tmp / "capture")
        gt = tmp / "gt"
        (gt / "frames").mkdir(parents=True)
        cap = scene.capture
        files = [write_image(gt / "frames" / cap.names[k], scene.gt_frames[k]).relative_to(gt).as_posix()
                 for k in range(cap.num_frames)]
        (gt / "test").mkdir()
        test_docs = [{"name": tv.name, "t": float(tv.t), "c2w": np.asarray(tv.c2w).tolist(),
                      "file": write_image(gt / "test" / tv.name, tv.image).relative_to(gt).as_posix()}
                     for tv in cap.test_views if tv.image is not None]
        np.save(gt / "depths.npy", scene.gt_depths)
        if scene.c_pos is not None:
            np.savez(gt / "thresholds.npz", c_pos=scene.c_pos, c_neg=scene.c_neg)
        doc = {"scene": scene.name, "meta": cap.meta,
               "frames": [{"name": cap.names[k], "file": files[k],
                           "t_start": float(cap.exposures[k, 0]), "t_end": float(cap.exposures[k, 1]),
                           "c2w_mid": cap.c2w[k].tolist(),
                           "trajectory": {"t": np.linspace(*cap.exposures[k], trajectory_samples).tolist(),
                                          "c2w": scene.gt_trajectory(k, trajectory_samples).tolist()}}
                          for k in range(cap.num_frames)],
               "test_views": test_docs, "depths": "depths.npy", "thresholds": "thresholds.npz" if scene.c_pos is not None else None}
        (gt / "gt.json").write_text(json.dumps(doc, indent=1))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
