"""The ``ebad-capture/1`` folder format: reader and atomic, lossless writer.

See docs/conventions.md for the layout. Extra keys this writer adds (ignored by other
readers, read back here so that save -> load is lossless): per frame ``name``; top level
``events.t0_us`` (the stream's t0), ``meta`` (JSON-serialisable entries of Capture.meta).
Frames are written as 8-bit PNG when every value is k/255, 16-bit PNG (grey or RGB) when k/65535,
and float32 ``.npy`` otherwise.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from edi import EventError, EventStream

from .capture import Capture, TestView, check_rigid
from .errors import CaptureError
from .images import read_image, write_image

__all__ = ["FORMAT", "load_capture_folder", "save", "read_event_file"]

FORMAT = "ebad-capture/1"
_T_UNITS = {"us": 1, "ns": None, "s": None, "ms": None}


def _req(d: dict, key: str, file: str, where: str) -> Any:
    if not isinstance(d, dict):
        raise CaptureError(file, where, f"must be an object, got {type(d).__name__}")
    if key not in d:
        raise CaptureError(file, f"{where}.{key}" if where else key, "missing")
    return d[key]


def _num(v: Any, file: str, field: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CaptureError(file, field, f"must be a number, got {v!r}")
    x = float(v)
    if not math.isfinite(x):
        raise CaptureError(file, field, f"must be finite, got {v!r}")
    return x


def _times_to_us(t: np.ndarray, unit: str, file: str) -> np.ndarray:
    if unit == "us":
        if t.dtype.kind == "f":
            if not np.isfinite(t).all():
                raise CaptureError(file, "t", "non-finite timestamp")
            return np.round(t).astype(np.int64)
        return t.astype(np.int64)
    if t.dtype.kind == "f" and not np.isfinite(t).all():
        raise CaptureError(file, "t", "non-finite timestamp")
    if unit == "ns":
        return (t.astype(np.int64) + 500) // 1000 if t.dtype.kind in "iu" else np.round(t / 1e3).astype(np.int64)
    if unit == "ms":
        return np.round(t.astype(np.float64) * 1e3).astype(np.int64)
    if unit == "s":
        return np.round(t.astype(np.float64) * 1e6).astype(np.int64)
    raise CaptureError(file, "t_unit", f"must be one of us, ns, ms, s; got {unit!r}")


def read_event_file(path: Path, t_unit: str, width: int, height: int, t0_us: int = 0) -> EventStream:
    """Read events from a .npz or .h5 file with arrays x, y, t, p (an h5 may keep them under
    an ``events/`` group). Raises CaptureError naming the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), "events.file", "file not found")
    arrays: dict[str, np.ndarray] = {}
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                for k in ("t", "x", "y", "p"):
                    if k in z.files:
                        arrays[k] = z[k]
        elif path.suffix in (".h5", ".hdf5"):
            import h5py

            with h5py.File(path, "r") as h:
                g = h["events"] if "events" in h and isinstance(h["events"], h5py.Group) else h
                for k in ("t", "x", "y", "p"):
                    if k in g:
                        arrays[k] = g[k][()]
        else:
            raise CaptureError(str(path), "events.file", "events must be a .npz or .h5 file")
    except CaptureError:
        raise
    except Exception as exc:
        raise CaptureError(str(path), "events.file", f"unreadable ({type(exc).__name__}: {exc})") from None
    for k in ("t", "x", "y", "p"):
        if k not in arrays:
            raise CaptureError(str(path), k, "missing array")
    t = _times_to_us(np.asarray(arrays["t"]).reshape(-1), t_unit, str(path))
    try:
        return EventStream(t, arrays["x"].reshape(-1), arrays["y"].reshape(-1), arrays["p"].reshape(-1),
                           width, height, t0=t0_us)
    except EventError as exc:
        raise CaptureError(str(path), "events", str(exc)) from None


def _matrix(v: Any, file: str, field: str) -> np.ndarray:
    try:
        a = np.array(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise CaptureError(file, field, "must be a 4x4 list of numbers") from None
    return check_rigid(a, file, field)


def load_capture_folder(path: Path) -> Capture:
    """Read an ``ebad-capture/1`` folder (``path`` is the folder or its capture.json)."""
    path = Path(path)
    root = path.parent if path.is_file() else path
    js = root / "capture.json"
    jf = str(js)
    if not js.is_file():
        raise CaptureError(jf, None, "file not found")
    try:
        doc = json.loads(js.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(jf, None, f"not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise CaptureError(jf, None, "top level must be an object")
    fmt = _req(doc, "format", jf, "")
    if fmt != FORMAT:
        raise CaptureError(jf, "format", f"expected {FORMAT!r}, got {fmt!r}")
    width = _req(doc, "width", jf, "")
    height = _req(doc, "height", jf, "")
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise CaptureError(jf, name, f"must be a positive integer, got {v!r}")
    intr = _req(doc, "intrinsics", jf, "")
    fx, fy, cx, cy = (_num(_req(intr, k, jf, "intrinsics"), jf, f"intrinsics.{k}") for k in ("fx", "fy", "cx", "cy"))
    if fx <= 0 or fy <= 0:
        raise CaptureError(jf, "intrinsics.fx", "focal lengths must be positive")
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    distortion = None
    if doc.get("distortion") is not None:
        dv = doc["distortion"]
        if not isinstance(dv, list) or len(dv) != 5:
            raise CaptureError(jf, "distortion", "must be a list of 5 numbers k1 k2 p1 p2 k3")
        distortion = np.array([_num(x, jf, f"distortion[{i}]") for i, x in enumerate(dv)])

    evd = _req(doc, "events", jf, "")
    ev_file = _req(evd, "file", jf, "events")
    t_unit = evd.get("t_unit", "us")
    if t_unit not in _T_UNITS:
        raise CaptureError(jf, "events.t_unit", f"must be one of us, ns, ms, s; got {t_unit!r}")
    t0_us = evd.get("t0_us", 0)
    if isinstance(t0_us, bool) or not isinstance(t0_us, int):
        raise CaptureError(jf, "events.t0_us", f"must be an integer, got {t0_us!r}")
    # t0_us is the stream's reference: stored times are relative, so t0 is re-attached, not subtracted
    events = read_event_file(root / str(ev_file), t_unit, width, height)
    if t0_us:
        object.__setattr__(events, "t0", int(t0_us))

    frames_doc = _req(doc, "frames", jf, "")
    if not isinstance(frames_doc, list) or not frames_doc:
        raise CaptureError(jf, "frames", "must be a non-empty list")
    frames, exposures, c2ws, split, names = [], [], [], [], []
    have_pose = ["c2w" in fr for fr in frames_doc if isinstance(fr, dict)]
    if any(have_pose) and not all(have_pose):
        i = have_pose.index(False)
        raise CaptureError(jf, f"frames[{i}].c2w", "missing (either every frame has a pose or none has)")
    for i, fr in enumerate(frames_doc):
        where = f"frames[{i}]"
        file = _req(fr, "file", jf, where)
        t0 = _num(_req(fr, "t_start", jf, where), jf, f"{where}.t_start")
        t1 = _num(_req(fr, "t_end", jf, where), jf, f"{where}.t_end")
        if t1 < t0:
            raise CaptureError(jf, f"{where}.t_end", f"{t1} is before t_start {t0}")
        img = read_image(root / str(file), f"{where}.file")
        if img.shape[:2] != (height, width):
            raise CaptureError(str(root / str(file)), f"{where}.file",
                               f"frame is {img.shape[1]}x{img.shape[0]}, capture.json says {width}x{height}")
        if frames and img.shape[2] != frames[0].shape[2]:
            raise CaptureError(str(root / str(file)), f"{where}.file",
                               f"has {img.shape[2]} channels, frame 0 has {frames[0].shape[2]}")
        frames.append(img)
        exposures.append((t0, t1))
        if "c2w" in fr:
            c2ws.append(_matrix(fr["c2w"], jf, f"{where}.c2w"))
        s = fr.get("split", "train")
        if not isinstance(s, str):
            raise CaptureError(jf, f"{where}.split", f"must be a string, got {s!r}")
        split.append(s)
        nm = fr.get("name", Path(str(file)).stem)
        names.append(str(nm))
    test_views = []
    for j, tv in enumerate(doc.get("test_views", []) or []):
        where = f"test_views[{j}]"
        name = str(_req(tv, "name", jf, where))
        t = _num(_req(tv, "t", jf, where), jf, f"{where}.t")
        has_pose = tv.get("c2w") is not None or not tv.get("file")  # a test view needs a c2w, a file or both
        c2w = _matrix(_req(tv, "c2w", jf, where), jf, f"{where}.c2w") if has_pose else None
        image = None
        if tv.get("file"):
            image = read_image(root / str(tv["file"]), f"{where}.file")
            if image.shape[:2] != (height, width):
                raise CaptureError(str(root / str(tv["file"])), f"{where}.file",
                                   f"image is {image.shape[1]}x{image.shape[0]}, capture.json says {width}x{height}")
        test_views.append(TestView(name=name, t=t, c2w=c2w, image=image))
    meta = dict(doc.get("meta", {}) or {})
    if len(set(names)) != len(names):
        names = [f"{i:04d}" for i in range(len(names))]
    cap = Capture(frames=np.stack(frames).astype(np.float32), exposures=np.array(exposures, dtype=np.float64),
                  events=events, K=K, distortion=distortion, c2w=np.stack(c2ws) if c2ws else None,
                  split=split, test_views=test_views, names=names, meta=meta, pose_trust=doc.get("pose_trust"))
    return cap.validate(jf)


def _jsonable(meta: dict) -> dict:
    out = {}
    for k, v in meta.items():
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, np.generic):
            v = v.item()
        try:
            json.dumps(v, allow_nan=False)
        except (TypeError, ValueError):
            continue  # not representable: dropped (documented: only JSON-serialisable meta survives)
        out[str(k)] = v
    return out


def _safe_name(name: str) -> str:
    keep = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
    return keep.strip(".") or "frame"


def save(capture: Capture, path: str | os.PathLike, overwrite: bool = False) -> None:
    """Write ``capture`` as an ``ebad-capture/1`` folder at ``path``, atomically: everything is
    written to a temporary sibling folder which is renamed into place at the end, so a failure
    leaves nothing behind. ``path`` must not exist (or be an empty folder) unless ``overwrite``.

    Raises:
        CaptureError: the capture is invalid (names the field), or ``path`` exists.
    """
    capture.validate("capture")
    path = Path(path)
    if path.exists() and not (path.is_dir() and not any(path.iterdir())) and not overwrite:
        raise CaptureError(str(path), None, "already exists and is not empty (pass overwrite=True)")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        _write(capture, tmp)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
            os.replace(path, old / "c")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _write(cap: Capture, root: Path) -> None:
    (root / "frames").mkdir()
    names = cap.names or [f"{i:04d}" for i in range(cap.num_frames)]
    split = cap.split or ["train"] * cap.num_frames
    frames = []
    used: set[str] = set()
    for i in range(cap.num_frames):
        stem = _safe_name(names[i])
        if stem in used:
            stem = f"{i:04d}_{stem}"
        used.add(stem)
        out = write_image(root / "frames" / stem, cap.frames[i])
        fr: dict[str, Any] = {"file": out.relative_to(root).as_posix(), "name": names[i],
                              "t_start": float(cap.exposures[i, 0]), "t_end": float(cap.exposures[i, 1]),
                              "split": split[i]}
        if cap.c2w is not None:
            fr["c2w"] = np.asarray(cap.c2w[i], dtype=np.float64).tolist()
        frames.append(fr)
    tvs = []
    if cap.test_views:
        (root / "test").mkdir()
    for j, tv in enumerate(cap.test_views):
        d: dict[str, Any] = {"name": tv.name, "t": float(tv.t)}
        if tv.c2w is not None:
            d["c2w"] = np.asarray(tv.c2w, dtype=np.float64).tolist()
        if tv.image is not None:
            out = write_image(root / "test" / f"{j:04d}_{_safe_name(tv.name)}", tv.image)
            d["file"] = out.relative_to(root).as_posix()
        tvs.append(d)
    ev = cap.events
    np.savez(root / "events.npz", t=ev.t.astype(np.int64), x=ev.x.astype(np.int16 if max(cap.width, cap.height) < 32767 else np.int32),
             y=ev.y.astype(np.int16 if max(cap.width, cap.height) < 32767 else np.int32), p=ev.p.astype(np.int8))
    K = np.asarray(cap.K, dtype=np.float64)
    doc: dict[str, Any] = {
        "format": FORMAT, "width": cap.width, "height": cap.height,
        "intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])},
        "events": {"file": "events.npz", "t_unit": "us", "t0_us": int(ev.t0)},
        "frames": frames, "test_views": tvs, "meta": _jsonable(cap.meta),
    }
    if cap.pose_trust is not None:
        doc["pose_trust"] = cap.pose_trust
    if cap.distortion is not None:
        doc["distortion"] = [float(v) for v in np.asarray(cap.distortion)]
    (root / "capture.json").write_text(json.dumps(doc, indent=1, allow_nan=False))
