"""``ebad video``: a video of a run, along a camera path or through one blurry exposure.

Two modes:

* **Fly-through** (default): ``--frames N`` views along a smooth path through the training
  cameras (``render.smooth_path``: a cubic spline through the mid-exposure centres, rotations
  slerped), or the cameras
  of a nerfstudio-style ``--camera-path camera_path.json`` (``camera_to_world`` 4x4 row-major
  in nerfstudio's OpenGL axes, vertical ``fov`` in degrees, ``render_width`` /
  ``render_height``; poses in the run's world frame; its ``fps`` is the video's unless ``--fps``).
* **The sharp video of a blurry exposure**: ``--exposure NAME --instants N``: the frame's
  recovered trajectory rendered at the centres of N equal sub-intervals of its exposure.
  With ``--capture CAPTURE`` each video frame is three panels side by side:
  the blurry frame | EDI's latent at the same instant | the render at that instant, labelled
  ``PANEL_LABELS`` in a white strip above them (Pillow's default font).
  EDI uses the contrast threshold the run used (``metrics.json``), else one estimated from
  the capture's frames.

Output by the suffix of ``--out``: ``.mp4`` (H.264, yuv420p, needs ``imageio-ffmpeg``, whose
wheel ships an ffmpeg binary; odd sizes are padded by one edge pixel), ``.gif`` (Pillow), or
a folder (no suffix): one PNG per frame. Frames are 8-bit ``round(255 v)`` of the renders in the
capture's recorded domain (the run's camera response applied, no other curve), like ``ebad render``'s
default.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from ..errors import UserError

NAME = "video"
HELP = "a video (mp4, GIF or PNGs) along a camera path, or the sharp video of one blurry exposure"

DEFAULT_FRAMES = 60
DEFAULT_FPS_PATH = 30.0
DEFAULT_FPS_EXPOSURE = 10.0
DEFAULT_INSTANTS = 20
PANEL_GAP = 2  # white pixels between side-by-side panels
PANEL_LABELS = ("blurry input", "EDI", "ebad")  # the three panels of the exposure video
RENDER_BATCH = 8  # views per rasteriser call (one progress-bar step)
_MP4_QUALITY = 8  # imageio-ffmpeg quality 0..10
_INSTALL_VIDEO = "pip install imageio-ffmpeg (or the 'video' extra)"
# nerfstudio cameras: x right, y up, z back (OpenGL); ours: x right, y down, z forward (OpenCV)
_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class Args:
    run: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="RUN")]
    """run folder written by 'ebad reconstruct'"""
    out: str
    (
        "FILE.mp4 (H.264, needs imageio-ffmpeg), FILE.gif, or a folder (no suffix) for a PNG sequence; frames are "
        "8-bit, the capture's recorded values like ebad render"
    )
    frames: int = DEFAULT_FRAMES
    """frames along a smooth path through the training cameras (their mid-exposure poses)"""
    camera_path: Annotated[str | None, tyro.conf.arg(metavar="JSON")] = None
    (
        "a nerfstudio-style camera_path.json to follow instead of the smooth path (camera_to_world 4x4 row-major in "
        "nerfstudio's OpenGL axes, vertical fov in degrees, render_width / render_height; poses in the run's frame)"
    )
    exposure: Annotated[str | None, tyro.conf.arg(metavar="NAME")] = None
    (
        "instead: the sharp video of this training frame's exposure, its recovered trajectory rendered at the centres "
        "of --instants equal sub-intervals"
    )
    instants: int = DEFAULT_INSTANTS
    """with --exposure: instants rendered inside the exposure"""
    capture: str | None = None
    (
        "with --exposure: the capture; each video frame is then the blurry frame | EDI's latent at the same instant "
        "(the run's contrast threshold, else one estimated from the capture) | the render"
    )
    fps: float | None = None
    """frames per second (None: the camera path's fps when it has one, else 30; 10 with --exposure)"""
    no_progress: bool = False
    """no progress bar"""


# --------------------------------------------------------------------------- writing


def check_out(path: str | Path) -> Path:
    """``--out`` can take a video: a ``.mp4`` or ``.gif`` file that is not a folder, or a folder (no suffix)
    that is not a file. Checked before rendering, and again when writing."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ("", ".mp4", ".gif"):
        raise UserError(f"--out {path}: use a .mp4 or .gif file, or a folder (no suffix) for PNGs")
    if suffix and path.is_dir():
        raise UserError(f"--out {path}: is a folder; give a {suffix} file name (or a name without suffix for PNGs)")
    if not suffix and path.exists() and not path.is_dir():
        raise UserError(f"--out {path}: exists and is not a folder (a name without suffix is a PNG folder)")
    return path


def write_video(path: str | Path, frames: np.ndarray, fps: float) -> Path:  # [T, H, W, D] uint8, D in {1, 3}
    """Write 8-bit frames as ``.mp4`` (imageio-ffmpeg), ``.gif`` (Pillow), or PNGs in a folder
    (a path without suffix). Returns the path written.

    A file is written under a temporary name and renamed into place once complete (an mp4 once
    ffmpeg's output reads back with every frame), so a failed write (a folder in the way, an
    unwritable folder, a full disk) leaves no partial file under ``path``.

    Raises:
        UserError: ``path`` cannot take the video, or writing it failed; names ``path``."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[3] not in (1, 3) or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"frames must be uint8 [T, H, W, 1|3] with T >= 1, got {frames.dtype} {frames.shape}")
    if not (math.isfinite(fps) and fps > 0):
        raise UserError(f"--fps must be a positive number, got {fps:g}")
    path = check_out(path)
    suffix = path.suffix.lower()
    from PIL import Image

    from scenes._atomic import atomic_path

    def pil(a):
        return Image.fromarray(a[..., 0] if a.shape[2] == 1 else a)

    try:
        if suffix == "":
            path.mkdir(parents=True, exist_ok=True)
            for i, fr in enumerate(frames):
                with atomic_path(path / f"frame_{i:05d}.png") as tmp:
                    pil(fr).save(tmp, format="PNG")
        elif suffix == ".gif":
            ims = [pil(fr) for fr in frames]
            with atomic_path(path) as tmp:
                ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:], duration=round(1000 / fps), loop=0)
        else:
            _write_mp4(path, frames, fps)
    except OSError as exc:
        why = exc.strerror or str(exc).splitlines()[0]
        raise UserError(f"--out {path}: could not be written ({why})") from None
    return path


def _write_mp4(path: Path, frames: np.ndarray, fps: float) -> None:  # [T, H, W, D] uint8
    """H.264 through imageio-ffmpeg into a temporary file, renamed onto ``path`` only when it reads back with
    every frame (imageio-ffmpeg does not check ffmpeg's exit status: a full disk left a truncated file)."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise UserError(
            f"--out {path}: writing .mp4 needs imageio-ffmpeg: {_INSTALL_VIDEO}; "
            "or write a .gif or a PNG folder instead"
        ) from None
    from scenes._atomic import atomic_path

    if frames.shape[3] == 1:
        frames = np.repeat(frames, 3, axis=3)
    H, W = frames.shape[1:3]
    pad = ((0, 0), (0, H % 2), (0, W % 2), (0, 0))  # yuv420p needs even sizes
    frames = np.pad(frames, pad, mode="edge")
    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp),
            (frames.shape[2], frames.shape[1]),
            fps=fps,
            codec="libx264",
            pix_fmt_in="rgb24",
            pix_fmt_out="yuv420p",
            quality=_MP4_QUALITY,
            macro_block_size=1,
            ffmpeg_log_level="error",
        )
        writer.send(None)
        for fr in frames:
            writer.send(np.ascontiguousarray(fr))
        writer.close()
        try:
            n = imageio_ffmpeg.count_frames_and_secs(str(tmp))[0] if tmp.stat().st_size else 0
        except RuntimeError:
            n = 0
        if n != len(frames):
            raise UserError(
                f"--out {path}: ffmpeg failed to write it ({n} of {len(frames)} frames read back; "
                f"is the disk full or the folder not writable?)"
            )


# --------------------------------------------------------------------------- camera paths


MAX_RENDER_SIDE = 16384  # the largest render side a camera path may ask for (one frame of 16384^2 is 3 GB)


def _read_path_json(path: Path) -> dict:
    """A camera-path file's top-level JSON object; UserError naming the file otherwise."""
    from scenes.jsonio import read_json_object

    return read_json_object(path, UserError, what="a nerfstudio camera path")


def read_camera_path(path: str | Path) -> tuple[np.ndarray, np.ndarray, int, int]:  # -> [T, 4, 4], [T, 3, 3], W, H
    """Cameras of a nerfstudio-style ``camera_path.json`` as OpenCV camera-to-world poses,
    intrinsics from each camera's vertical ``fov`` (principal point at the image centre)."""
    path = Path(path)
    doc = _read_path_json(path)
    for key in ("render_width", "render_height", "camera_path"):
        if key not in doc:
            raise UserError(f"{path}: missing field '{key}'")
    W, H = doc["render_width"], doc["render_height"]
    for key, v in (("render_width", W), ("render_height", H)):
        if isinstance(v, bool) or not isinstance(v, int) or not 0 < v <= MAX_RENDER_SIDE:
            raise UserError(
                f"{path}: field '{key}' must be an integer in [1, {MAX_RENDER_SIDE}], got {json.dumps(v)[:40]}"
            )
    cams = doc["camera_path"]
    if not isinstance(cams, list) or not cams:
        raise UserError(f"{path}: 'camera_path' must be a non-empty list")
    c2w, K = [], []
    for i, cam in enumerate(cams):
        try:
            T = np.asarray(cam["camera_to_world"], dtype=np.float64).reshape(4, 4)
            fov = float(cam["fov"])
        except KeyError as exc:
            raise UserError(f"{path}: camera_path[{i}] lacks field {exc}") from None
        except ValueError:
            raise UserError(f"{path}: camera_path[{i}].camera_to_world must be 16 numbers") from None
        if not (np.isfinite(T).all() and 0 < fov < 180):
            raise UserError(f"{path}: camera_path[{i}]: non-finite camera_to_world or fov {fov:g} outside (0, 180)")
        f = 0.5 * H / math.tan(math.radians(fov) / 2)
        c2w.append(T @ _GL_TO_CV)
        K.append([[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]])
    return np.stack(c2w), np.asarray(K), W, H


def camera_path_fps(path: str | Path) -> float | None:
    """The ``fps`` of a nerfstudio-style ``camera_path.json`` (None when it has none).

    Raises:
        UserError: ``fps`` is not a positive number; names the file and the field."""
    path = Path(path)
    fps = _read_path_json(path).get("fps")
    if fps is None:
        return None
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
        raise UserError(f"{path}: field 'fps' must be a positive number, got {json.dumps(fps)}")
    return float(fps)


def write_camera_path(
    path: str | Path,
    c2w: np.ndarray,
    K: np.ndarray,  # [T, 4, 4] OpenCV, [3, 3]
    width: int,
    height: int,
    fps: float = DEFAULT_FPS_PATH,
) -> Path:
    """A nerfstudio-style ``camera_path.json`` of OpenCV poses (a starting point to edit)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    fov = math.degrees(2 * math.atan(0.5 * height / float(K[1, 1])))
    cams = [
        {"camera_to_world": (T @ _GL_TO_CV).reshape(-1).tolist(), "fov": fov, "aspect": width / height} for T in c2w
    ]
    doc = {
        "camera_type": "perspective",
        "render_width": int(width),
        "render_height": int(height),
        "fps": fps,
        "seconds": len(cams) / fps,
        "camera_path": cams,
    }
    path = Path(path)
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return path


# --------------------------------------------------------------------------- frames


def render_views(
    run,
    c2w: np.ndarray,
    K: np.ndarray | None = None,
    width: int | None = None,
    height: int | None = None,
    progress: bool = True,
) -> np.ndarray:  # [T, 4, 4] -> [T, H, W, D]
    """Renders (recorded values, ``Run.render``) of ``c2w`` (K [3, 3] or [T, 3, 3]; default the run's), with a
    progress bar."""
    from tqdm import tqdm

    T = len(c2w)
    Ks = None if K is None else np.array(np.broadcast_to(np.asarray(K, np.float64), (T, 3, 3)))
    out = []
    with tqdm(total=T, desc="render", unit="view", disable=not progress) as bar:
        for i in range(0, T, RENDER_BATCH):
            sl = slice(i, i + RENDER_BATCH)
            if Ks is None or np.allclose(Ks[sl], Ks[i]):
                out.append(run.render(c2w[sl], None if Ks is None else Ks[i], width, height))
            else:  # per-view intrinsics (a camera path whose fov changes)
                out.append(np.stack([run.render(c, k, width, height) for c, k in zip(c2w[sl], Ks[sl])]))
            bar.update(len(out[-1]))
    return np.concatenate(out)


def label_panels(
    frames: np.ndarray, labels: list[str] | tuple[str, ...], panel_width: int, gap: int = PANEL_GAP
) -> np.ndarray:  # [T, H, W, D] uint8 -> [T, h + H, W, D]
    """A white strip above side-by-side panels (``side_by_side``) with each panel's label in black at its
    left edge (Pillow's default font, cut at the panel's edge)."""
    from PIL import Image, ImageDraw, ImageFont

    frames = np.asarray(frames)
    T, _, W, D = frames.shape
    font = ImageFont.load_default()
    left, top, _, bottom = font.getbbox("Ag")
    h = int(bottom) + 2
    strip = np.full((h, W), 255, np.uint8)
    for i, text in enumerate(labels):
        x0 = i * (panel_width + gap)
        im = Image.new("L", (max(1, min(panel_width, W - x0)), h), 255)
        ImageDraw.Draw(im).text((1, 1), text, fill=0, font=font)
        strip[:, x0 : x0 + im.size[0]] = np.asarray(im)
    strip_t = np.broadcast_to(strip[None, :, :, None], (T, h, W, D)).astype(frames.dtype)
    return np.concatenate([strip_t, frames], axis=1)


def side_by_side(panels: list[np.ndarray]) -> np.ndarray:  # each [T, H, W, D] -> [T, H, sum W + gaps, D]
    """Panels next to each other, ``PANEL_GAP`` white columns between them."""
    T, H, _, D = panels[0].shape
    gap = np.ones((T, H, PANEL_GAP, D), dtype=panels[0].dtype)
    parts = []
    for i, p in enumerate(panels):
        parts += ([gap] if i else []) + [p]
    return np.concatenate(parts, axis=2)


def exposure_instants(exposure: tuple[float, float], n: int) -> tuple[np.ndarray, np.ndarray]:  # -> [n], [n]
    """Normalised instants u (centres of n equal sub-intervals) and their times in seconds."""
    t0, t1 = float(exposure[0]), float(exposure[1])
    u = (np.arange(n) + 0.5) / n
    return u, t0 + u * (t1 - t0)


def exposure_frames(
    run, name: str, instants: int, capture=None, progress: bool = True
) -> tuple[np.ndarray, str]:  # -> [N, H, W', D] recorded values, description
    """The renders of frame ``name`` along its recovered exposure trajectory at ``instants``
    instants; with a capture, [blurry | EDI latent | render] side by side."""
    import torch

    if name not in run.names:
        shown = ", ".join(run.names[:8]) + (" ..." if len(run.names) > 8 else "")
        raise UserError(f"--exposure {name!r} is not a training frame of the run (frames: {shown})")
    if instants < 1:
        raise UserError(f"--instants must be >= 1, got {instants}")
    f = run.names.index(name)
    exposure = run.exposures[f]
    u, times = exposure_instants(exposure, instants)
    with torch.no_grad():
        poses = run.trajectories(torch.tensor([f]), torch.from_numpy(u).float())[0].numpy()
    renders = render_views(run, poses, progress=progress)
    if capture is None:
        return renders, "renders along the recovered trajectory"
    import edi

    cap_names = list(capture.names)
    if name not in cap_names:
        raise UserError(f"--capture: frame {name!r} of the run is not in the capture")
    j = cap_names.index(name)
    blurry = np.asarray(capture.frames[j], np.float64)
    if blurry.shape != renders.shape[1:]:
        raise UserError(f"--capture: frame {name!r} is {blurry.shape}, the run renders {renders.shape[1:]}")
    c = run.metrics.prepare.c if run.metrics is not None else None
    if c is None:
        c = edi.estimate_c(np.asarray(capture.frames), np.asarray(capture.exposures), capture.events, pair=True)
    c = (float(c[0]), float(c[1]))
    lat = np.asarray(
        edi.deblur(blurry, (float(exposure[0]), float(exposure[1])), capture.events, times=times.tolist(), c=c),
        np.float64,
    ).reshape(renders.shape)
    panels = side_by_side([np.broadcast_to(blurry, renders.shape), np.clip(lat, 0, 1), renders])
    return panels, f"blurry | EDI latent (c_pos {c[0]:.3f}, c_neg {c[1]:.3f}) | render, at the same instants"


def run(args: Args) -> int:
    from ..export import to_display8
    from ..runfolder import load_run

    check_out(args.out)  # before the renders
    run_ = load_run(args.run)
    progress = not args.no_progress
    if args.exposure is not None:
        capture = None
        if args.capture is not None:
            import scenes

            capture = scenes.load(args.capture)
        imgs, what = exposure_frames(run_, args.exposure, args.instants, capture, progress)
        fps = DEFAULT_FPS_EXPOSURE if args.fps is None else args.fps
        labels = PANEL_LABELS if capture is not None else None
    else:
        if args.capture is not None:
            raise UserError("--capture is only used with --exposure")
        if args.camera_path is not None:
            c2w, K, W, H = read_camera_path(args.camera_path)
            path_fps = camera_path_fps(args.camera_path)
            imgs = render_views(run_, c2w, K, W, H, progress=progress)
            what = f"{len(c2w)} cameras of {args.camera_path}"
        else:
            if args.frames < 2:
                raise UserError(f"--frames must be >= 2, got {args.frames}")
            from .render import smooth_path

            c2w = smooth_path(run_.trajectories.mid_poses().numpy().astype(np.float64), args.frames)
            imgs = render_views(run_, c2w, progress=progress)
            what = f"smooth path through the {len(run_.names)} training cameras"
            path_fps = None
        fps = args.fps if args.fps is not None else path_fps if path_fps is not None else DEFAULT_FPS_PATH
        labels = None
    frames = to_display8(imgs)
    if labels is not None:
        frames = label_panels(frames, labels, run_.width)
    out = write_video(args.out, frames, fps)
    print(f"ebad video: {len(frames)} frames {frames.shape[2]}x{frames.shape[1]} at {fps:g} fps ({what}) -> {out}")
    return 0
