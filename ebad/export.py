"""Files other tools open: display PNGs, 3DGS ``cameras.json``, the web ``.splat``, TUM trajectories.

**One colour domain** (DESIGN.md): the model renders irradiance; everything ebad writes or shows is in
the capture's own *recorded* domain, the run's camera response (``ebad.response``, the identity for
``linear``) applied once and no other curve on top. The frames of a capture are recorded values
(``scenes.images``: PNG value / 255 or / 65535, no transfer curve), so an output looks like the input
it came from and a PSNR between a render and a test image needs no decoding.

- **Images** (``ebad render``, ``ebad video``, ``ebad eval --renders``, the run's ``deblurred/``):
  ``Run.render`` already returns recorded values in [0, 1]; ``write_render`` stores them as they
  are: 8-bit ``round(255 v)`` or 16-bit ``round(65535 v)`` (``scenes.images.write_png16``), the
  same encoding as a capture's frames and ``ebad deblur``'s outputs. No gAMA chunk is written
  either way: the values are the camera's, not sRGB-encoded and not linear light (a viewer shows
  them as it shows the input frames).
- **Exported colours** (``point_cloud.ply``'s ``f_dc``, ``.splat``'s RGB bytes, the viewer): each
  Gaussian's colour through the response (``recorded_colors``; the curve without its saturation
  at 1 in the PLY, so that ``model_colors`` inverts it exactly when a run folder is read back),
  so the PLY and the ``.splat`` show the same colours (``to_recorded_params`` / ``from_recorded_params``).
  With view-dependent colour (``sh_rest``) the PLY's SH coefficients are the least-squares fit of the
  response of the model's colour over ``SH_FIT_DIRECTIONS`` directions (a curve cannot go through the
  coefficients one by one); the ``.splat`` (degree 0) holds that fit's DC, the mean over directions.
- **cameras.json**: the layout the 3DGS trainer writes and SIBR-style viewers read: a list of
  ``{"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"}``, position
  and rotation of the camera-to-world pose (OpenCV axes, rotation as three rows). We add
  ``cx``, ``cy`` (ignored by other readers).
- **.splat**: the antimatter15 web-viewer layout, 32 bytes per Gaussian, little endian:
  position f32x3, scale f32x3 (activated, ``exp``), colour RGBA u8x4 (``round(255 v)`` of the
  recorded colour ``v`` of ``0.5 + SH_C0 * f_dc``, clipped to [0, 1]; alpha =
  ``sigmoid(opacity)``), rotation u8x4 (w, x, y, z of the unit quaternion, ``round(q * 128 + 128)``
  clipped to 0..255); sorted by ``exp(sum log scale) * sigmoid(opacity)`` descending. A grey model
  writes its value into R, G and B (the file is for display).
- **TUM trajectories** (what ``evo`` reads): one line per timestamp,
  ``timestamp tx ty tz qx qy qz qw``, camera-to-world, seconds on the capture's clock,
  Hamilton quaternion with the real part LAST (TUM's order, unlike the project's w-first).
  A sharp frame (``t_start == t_end``) gives one line, not one per sample.
- ``srgb_encode`` / ``srgb_decode`` (IEC 61966-2-1) remain for callers that hold linear light and
  want a display encoding; no output of ebad applies them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from .errors import UserError
from .gaussians import SH_C0, activate
from .io import write_png16
from .lie import quat_to_rotmat

__all__ = [
    "srgb_encode",
    "srgb_decode",
    "to_display8",
    "write_render",
    "recorded_colors",
    "model_colors",
    "to_recorded_params",
    "from_recorded_params",
    "fibonacci_directions",
    "SH_FIT_DIRECTIONS",
    "rotmat_to_quat",
    "write_cameras_json",
    "read_cameras_json",
    "write_splat",
    "read_splat",
    "write_tum",
    "read_tum",
    "exposure_samples",
    "write_exports",
    "CAMERAS_JSON",
    "SPLAT_FILE",
    "TUM_FILE",
    "SPLAT_BYTES",
]

CAMERAS_JSON = "cameras.json"
SPLAT_FILE = "point_cloud.splat"
TUM_FILE = "trajectories_tum.txt"

# sRGB transfer curve (IEC 61966-2-1)
_SRGB_LINEAR_LIMIT = 0.0031308
_SRGB_ENCODED_LIMIT = 0.04045
_SRGB_SLOPE = 12.92
_SRGB_GAMMA = 2.4
_SRGB_A = 0.055

SPLAT_BYTES = 32  # per Gaussian: 3 f32 position, 3 f32 scale, 4 u8 RGBA, 4 u8 quaternion
_SPLAT_DTYPE = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
_QUAT_BYTE_SCALE = 128.0  # byte = round(q * 128 + 128)
_TUM_SAMPLES = 9  # poses per exposure in the TUM file (the same sampling as trajectories.json)


# --------------------------------------------------------------------------- display images


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear intensity [0, 1] -> sRGB-encoded [0, 1] (clipped first)."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= _SRGB_LINEAR_LIMIT, _SRGB_SLOPE * x, (1 + _SRGB_A) * np.power(x, 1 / _SRGB_GAMMA) - _SRGB_A)


def srgb_decode(y: np.ndarray) -> np.ndarray:
    """sRGB-encoded [0, 1] -> linear intensity [0, 1] (inverse of ``srgb_encode``)."""
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    return np.where(y <= _SRGB_ENCODED_LIMIT, y / _SRGB_SLOPE, np.power((y + _SRGB_A) / (1 + _SRGB_A), _SRGB_GAMMA))


def to_display8(img: np.ndarray) -> np.ndarray:  # [..., H, W, D] recorded values -> uint8
    """8-bit values of images in the recorded domain: ``round(255 * clip(v, 0, 1))`` (no transfer curve:
    the values are already what the camera recorded, see the module docstring)."""
    a = np.asarray(img)
    if not np.isfinite(a).all():
        raise ValueError("image has non-finite values")
    return np.round(np.clip(np.asarray(a, np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)


def write_render(path: str | Path, img: np.ndarray, bits: int = 8) -> Path:  # [H, W, D], D in {1, 3}
    """Write a render (recorded values, ``Run.render``'s output) as a PNG: ``bits=8`` ``round(255 v)``,
    ``bits=16`` ``round(65535 v)``: the encoding of a capture's frames, read back by ``scenes.read_image``."""
    a = np.asarray(img)
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"image must be [H, W, 1|3], got {a.shape}")
    if bits == 16:
        return write_png16(path, a)
    if bits != 8:
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    from PIL import Image

    q = to_display8(a)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(q[..., 0] if q.shape[2] == 1 else q).save(path, format="PNG")
    return path


# --------------------------------------------------------------------------- exported colours


def _curve(response) -> tuple[float, float, float] | None:  # (black, gain, gamma); None: the identity
    if response is None or not getattr(response, "learnable", False):
        return None
    v = response.values()
    return float(v["black"]), float(v["gain"]), float(v["gamma"])


def recorded_colors(colors, response=None, saturate: bool = True) -> np.ndarray:  # [N, D] -> [N, D] float64
    """Gaussian colours (irradiance, the activated ``0.5 + SH_C0 * f_dc``) in the recorded domain: through
    the response's curve ``b + (1 - b) (g E)^gamma`` (``ebad.response``; identity for ``linear`` or None),
    clipped to [0, 1] with ``saturate``; without it the curve goes on above 1 (``model_colors`` inverts it)."""
    c = np.clip(
        np.asarray(colors.detach().cpu().numpy() if isinstance(colors, torch.Tensor) else colors, np.float64), 0, None
    )
    curve = _curve(response)
    if curve is not None:
        b, g, k = curve
        c = b + (1 - b) * np.power(g * c, k)
    return np.clip(c, 0.0, 1.0) if saturate else c


def model_colors(recorded, response=None) -> np.ndarray:  # [N, D] -> [N, D] float64
    """Inverse of ``recorded_colors(..., saturate=False)``: irradiance colours of recorded ones
    (values below the black level give 0)."""
    y = np.asarray(recorded, np.float64)
    curve = _curve(response)
    if curve is None:
        return y
    b, g, k = curve
    return np.power(np.clip((y - b) / (1 - b), 0.0, None), 1.0 / k) / g


#: directions the SH coefficients of a PLY are fitted over (``to_recorded_params``): a Fibonacci sphere
SH_FIT_DIRECTIONS = 128
_SH_FIT_CHUNK = 16384  # Gaussians per least-squares solve ([directions, chunk, D] float64 at a time)


def fibonacci_directions(n: int) -> np.ndarray:  # -> [n, 3] unit vectors
    """``n`` nearly even unit directions on the sphere (the Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _refit_sh(params: dict[str, torch.Tensor], curve) -> dict[str, torch.Tensor]:
    """``params`` whose SH colours (DC ``colors`` and ``sh_rest``) are the least-squares fit, over
    ``SH_FIT_DIRECTIONS`` directions, of ``curve`` (a map of [..., D] colours) applied to the model's
    colour max(SH(d) . coeffs + 0.5, 0) in each direction (``splat_cpu``'s convention): a non-linear
    curve cannot go through the coefficients one by one."""
    from splat_cpu._sh import sh_basis

    dc, rest = params["colors"], params["sh_rest"]
    degree = math.isqrt(rest.shape[1] + 1) - 1
    basis = sh_basis(degree, torch.from_numpy(fibonacci_directions(SH_FIT_DIRECTIONS))).numpy()  # [S, K]
    pinv = np.linalg.pinv(basis)  # [K, S]
    coeffs = torch.cat([dc[:, None, :], rest], dim=1).detach().double().cpu().numpy()  # [N, K, D]
    out = np.empty_like(coeffs)
    for i in range(0, coeffs.shape[0], _SH_FIT_CHUNK):
        c = coeffs[i : i + _SH_FIT_CHUNK]
        colour = np.clip(np.einsum("sk,nkd->snd", basis, c) + 0.5, 0.0, None)  # [S, n, D]
        out[i : i + _SH_FIT_CHUNK] = np.einsum("ks,snd->nkd", pinv, curve(colour) - 0.5)
    fitted = torch.from_numpy(out).to(dc.dtype)
    return {**params, "colors": fitted[:, 0].contiguous(), "sh_rest": fitted[:, 1:].contiguous().to(rest.dtype)}


def to_recorded_params(params: dict[str, torch.Tensor], response=None) -> dict[str, torch.Tensor]:
    """``params`` whose colours give the recorded colours of ``recorded_colors(..., saturate=False)``: what
    ``point_cloud.ply`` stores. At degree 0 the DC colour through the curve (exact); with ``sh_rest`` the
    SH coefficients fitted to the curve of the model's colour over ``SH_FIT_DIRECTIONS`` directions
    (``_refit_sh``; exact for the identity, within the fit's error otherwise). The same dict when the
    response is the identity (bit-exact)."""
    if _curve(response) is None:
        return params
    if params.get("sh_rest") is not None:
        return _refit_sh(params, lambda c: recorded_colors(c, response, saturate=False))
    dc = params["colors"]
    rec = recorded_colors((0.5 + SH_C0 * dc.detach().double()).clamp_min(0.0), response, saturate=False)
    return {**params, "colors": torch.from_numpy((rec - 0.5) / SH_C0).to(dc.dtype)}


def from_recorded_params(params: dict[str, torch.Tensor], response=None) -> dict[str, torch.Tensor]:
    """Inverse of ``to_recorded_params``: the model's (irradiance) colours from a PLY's (with ``sh_rest``
    the same fit through the inverse curve: a round trip within the two fits' errors)."""
    if _curve(response) is None:
        return params
    if params.get("sh_rest") is not None:
        return _refit_sh(params, lambda c: model_colors(c, response))
    dc = params["colors"]
    irr = model_colors(0.5 + SH_C0 * dc.detach().double().numpy(), response)
    return {**params, "colors": torch.from_numpy((irr - 0.5) / SH_C0).to(dc.dtype)}


# --------------------------------------------------------------------------- rotations


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:  # [..., 3, 3] -> [..., 4] (w, x, y, z), w >= 0
    """Unit quaternions (real part first, non-negative) of rotation matrices, by
    ``scipy.spatial.transform.Rotation`` (whose quaternions are (x, y, z, w))."""
    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    xyzw = Rotation.from_matrix(flat).as_quat() if len(flat) else np.zeros((0, 4))
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=-1).reshape(*R.shape[:-2], 4)
    return np.where(q[..., :1] < 0, -q, q)


def _quat_to_rotmat_np(q: np.ndarray) -> np.ndarray:  # [N, 4] (w, x, y, z) -> [N, 3, 3]
    return quat_to_rotmat(torch.from_numpy(np.asarray(q, dtype=np.float64))).numpy()


def _check_poses(c2w: np.ndarray, name: str) -> np.ndarray:  # [C, 4, 4]
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4):
        raise ValueError(f"{name} must be [C, 4, 4], got {c2w.shape}")
    if not np.isfinite(c2w).all():
        raise ValueError(f"{name} has non-finite values")
    return c2w


# --------------------------------------------------------------------------- cameras.json


def write_cameras_json(
    path: str | Path,
    names: list[str],
    c2w: np.ndarray,  # [C, 4, 4]
    K: np.ndarray,
    width: int,
    height: int,
) -> Path:  # K [3, 3] or [C, 3, 3]
    """The 3DGS ``cameras.json`` (see module docstring) for cameras ``c2w`` (OpenCV axes)."""
    c2w = _check_poses(c2w, "c2w")
    C = c2w.shape[0]
    K = np.broadcast_to(np.asarray(K, dtype=np.float64), (C, 3, 3))
    if len(names) != C:
        raise ValueError(f"names has {len(names)} entries for {C} cameras")
    cams = [
        {
            "id": i,
            "img_name": str(names[i]),
            "width": int(width),
            "height": int(height),
            "position": c2w[i, :3, 3].tolist(),
            "rotation": c2w[i, :3, :3].tolist(),
            "fx": float(K[i, 0, 0]),
            "fy": float(K[i, 1, 1]),
            "cx": float(K[i, 0, 2]),
            "cy": float(K[i, 1, 2]),
        }
        for i in range(C)
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cams, indent=1) + "\n")
    return path


def read_cameras_json(path: str | Path) -> dict:
    """Read a 3DGS ``cameras.json``: ``{"names": [C], "c2w": [C, 4, 4], "K": [C, 3, 3],
    "width": [C], "height": [C]}`` (principal point at the image centre when absent)."""
    path = Path(path)
    try:
        cams = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(cams, list) or not cams:
        raise UserError(f"{path}: expected a non-empty list of cameras")
    names, c2w, K, W, H = [], [], [], [], []
    for i, cam in enumerate(cams):
        missing = [k for k in ("img_name", "width", "height", "position", "rotation", "fx", "fy") if k not in cam]
        if missing:
            raise UserError(f"{path}: camera {i} lacks field(s) {missing}")
        R, t = np.asarray(cam["rotation"], np.float64), np.asarray(cam["position"], np.float64)
        if R.shape != (3, 3) or t.shape != (3,):
            raise UserError(f"{path}: camera {i}: rotation must be 3x3 and position 3 values")
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        w, h = int(cam["width"]), int(cam["height"])
        names.append(str(cam["img_name"]))
        c2w.append(T)
        K.append(
            [
                [float(cam["fx"]), 0.0, float(cam.get("cx", w / 2))],
                [0.0, float(cam["fy"]), float(cam.get("cy", h / 2))],
                [0.0, 0.0, 1.0],
            ]
        )
        W.append(w)
        H.append(h)
    return {"names": names, "c2w": np.stack(c2w), "K": np.asarray(K), "width": np.asarray(W), "height": np.asarray(H)}


# --------------------------------------------------------------------------- .splat


def write_splat(
    path: str | Path, params: dict[str, torch.Tensor], response=None, recorded: dict[str, torch.Tensor] | None = None
) -> Path:
    """The antimatter15 ``.splat`` file of a model's parameters (see module docstring), colours through
    the camera ``response`` (None: the identity). ``recorded``: ``to_recorded_params(params, response)``
    when the caller has it already (the PLY's fit), so the SH fit is not made twice."""
    act = {k: v.detach().double().cpu().numpy() for k, v in activate(params).items()}
    N = act["means"].shape[0]
    colors = recorded_colors(act["colors"], response)
    if params.get("sh_rest") is not None and _curve(response) is not None:  # the PLY's DC: R's mean over directions
        recorded = to_recorded_params(params, response) if recorded is None else recorded
        colors = np.clip(0.5 + SH_C0 * recorded["colors"].detach().double().numpy(), 0, 1)
    if colors.shape[1] == 1:
        colors = np.repeat(colors, 3, axis=1)
    elif colors.shape[1] != 3:
        raise ValueError(f"write_splat supports D = 1 or 3 colour channels, got {colors.shape[1]}")
    order = np.argsort(-(act["scales"].prod(1) * act["opacities"]), kind="stable")
    q = act["quats"] / np.maximum(np.linalg.norm(act["quats"], axis=1, keepdims=True), 1e-12)
    rec = np.zeros(N, _SPLAT_DTYPE)
    rec["position"] = act["means"]
    rec["scale"] = act["scales"]
    rec["rgba"][:, :3] = np.round(colors * 255)
    rec["rgba"][:, 3] = np.round(np.clip(act["opacities"], 0, 1) * 255)
    rec["rot"] = np.clip(np.round(q * _QUAT_BYTE_SCALE + _QUAT_BYTE_SCALE), 0, 255)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(rec[order].tobytes())
    return path


def read_splat(path: str | Path) -> dict[str, np.ndarray]:
    """Read a ``.splat`` file: activated values ``means`` [N, 3], ``scales`` [N, 3] (std),
    ``colors`` [N, 3] recorded values in [0, 1] (``byte / 255``), ``opacities`` [N] in [0, 1], ``quats`` [N, 4]
    unit (w, x, y, z)."""
    path = Path(path)
    blob = path.read_bytes()
    if len(blob) % SPLAT_BYTES:
        raise UserError(f"{path}: size {len(blob)} is not a multiple of {SPLAT_BYTES} bytes (not a .splat file)")
    rec = np.frombuffer(blob, _SPLAT_DTYPE)
    q = (rec["rot"].astype(np.float64) - _QUAT_BYTE_SCALE) / _QUAT_BYTE_SCALE
    return {
        "means": rec["position"].astype(np.float64),
        "scales": rec["scale"].astype(np.float64),
        "colors": rec["rgba"][:, :3] / 255.0,
        "opacities": rec["rgba"][:, 3] / 255.0,
        "quats": q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12),
    }


# --------------------------------------------------------------------------- TUM trajectories


def write_tum(path: str | Path, times: np.ndarray, c2w: np.ndarray) -> Path:  # [M], [M, 4, 4]
    """TUM trajectory file (see module docstring), poses in the order given."""
    c2w = _check_poses(c2w, "c2w")
    times = np.asarray(times, dtype=np.float64)
    if times.shape != (c2w.shape[0],) or not np.isfinite(times).all():
        raise ValueError(f"times must be [{c2w.shape[0]}] finite seconds, got {times.shape}")
    q = rotmat_to_quat(c2w[:, :3, :3])  # (w, x, y, z)
    t = c2w[:, :3, 3]
    lines = ["# timestamp tx ty tz qx qy qz qw  (camera-to-world, OpenCV camera axes, seconds)"]
    lines += [
        " ".join(f"{v:.9f}" for v in (times[i], *t[i], q[i, 1], q[i, 2], q[i, 3], q[i, 0])) for i in range(len(times))
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:  # -> [M], [M, 4, 4]
    """Read a TUM trajectory file (``#`` comments and blank lines skipped)."""
    path = Path(path)
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            vals = [float(v) for v in s.replace(",", " ").split()]
        except ValueError:
            raise UserError(f"{path}:{n}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw'") from None
        if len(vals) != 8:
            raise UserError(f"{path}:{n}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', got {len(vals)}")
        rows.append(vals)
    if not rows:
        raise UserError(f"{path}: no poses")
    a = np.asarray(rows)
    c2w = np.tile(np.eye(4), (len(a), 1, 1))
    c2w[:, :3, :3] = _quat_to_rotmat_np(a[:, [7, 4, 5, 6]])
    c2w[:, :3, 3] = a[:, 1:4]
    return a[:, 0], c2w


def exposure_samples(
    exposures: np.ndarray,
    poses: np.ndarray,  # [F, 2], [F, S, 4, 4]
    u: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # [S] -> [M], [M, 4, 4], M <= F*S
    """Timestamps ``t_start + u (t_end - t_start)`` and poses of the samples, sorted by time, one per
    timestamp: samples at an instant already taken (all of a sharp frame's, ``t_start == t_end``, or the
    end of an exposure touching the next one's start) are dropped, the first in time order kept."""
    ex = np.asarray(exposures, dtype=np.float64)
    t = (ex[:, :1] + np.asarray(u, np.float64)[None] * (ex[:, 1:] - ex[:, :1])).ravel()  # [F*S]
    order = np.argsort(t, kind="stable")
    t = t[order]
    keep = np.ones(len(t), bool)
    keep[1:] = t[1:] != t[:-1]
    return t[keep], np.asarray(poses).reshape(-1, 4, 4)[order][keep]


# --------------------------------------------------------------------------- run folder


def write_exports(run, out: str | Path, recorded: dict[str, torch.Tensor] | None = None) -> list[Path]:
    """``cameras.json`` (training cameras at mid-exposure), ``point_cloud.splat`` and the TUM
    trajectories of a ``Run`` into the run folder ``out`` (``recorded``: as ``write_splat``'s)."""
    out = Path(out)
    mid = run.trajectories.mid_poses().numpy()
    poses, u = run.exposure_poses(_TUM_SAMPLES)
    times, flat = exposure_samples(run.exposures, poses, u)
    return [
        write_cameras_json(out / CAMERAS_JSON, run.names, mid, run.K, run.width, run.height),
        write_splat(out / SPLAT_FILE, run.params, run.response, recorded),
        write_tum(out / TUM_FILE, times, flat),
    ]
