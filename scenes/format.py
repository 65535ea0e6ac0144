"""The ``ebad-capture/1`` folder format: reader and atomic, lossless writer.

See docs/conventions.md for the layout. Extra keys this writer adds (ignored by other
readers, read back here so that save -> load is lossless): per frame ``name``; top level
``events.t0_us`` (the stream's t0), ``meta`` (JSON-serialisable entries of Capture.meta).
Frames are written as 8-bit PNG when every value is k/255, 16-bit PNG (grey or RGB) when k/65535,
and float32 ``.npy`` otherwise.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

import numpy as np

from edi import CorruptFileError, EbadError, EventStream, read_events

from .capture import (
    EXACT_RIGID_TOL,
    ROTATION_REPAIR_TOL,
    Capture,
    TestView,
    check_file_name,
    frame_name,
    nearest_rigid,
)
from .e2nerf import ground_truth_blur
from .errors import CaptureError
from .images import read_image, write_image
from .jsonio import read_json_object
from .truth import GT_FILE, GroundTruth

# nearest_rigid, ROTATION_REPAIR_TOL (scenes.capture), read_json_object (scenes.jsonio) and GroundTruth
# (scenes.truth) are re-exported under their old import paths
__all__ = [
    "FORMAT",
    "load_capture_folder",
    "save",
    "read_event_file",
    "nearest_rigid",
    "ROTATION_REPAIR_TOL",
    "EXACT_RIGID_TOL",
    "read_json_object",
    "read_ground_truth",
    "GroundTruth",
    "GT_FILE",
]

log = logging.getLogger(__name__)

FORMAT: Final = "ebad-capture/1"
T_UNITS = ("us", "ns", "ms", "s")
US_PER_UNIT = {"s": 1e6, "ms": 1e3, "us": 1.0, "ns": 1e-3}
# Without events.t_unit, the unit whose events' span is within this factor of the frames' span wins
# (the units are 1000x apart, so at most one can be); none within it is refused as ambiguous.
T_UNIT_SPAN_FACTOR = 30.0
EVENT_SUFFIXES = (".npz", ".h5", ".hdf5")
# What numpy, zipfile and h5py raise on a truncated or corrupt file (h5py raises OSError).
CORRUPT_FILE_ERRORS = (OSError, EOFError, ValueError, zipfile.BadZipFile)


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


def decode_events(
    path: Path,
    t_unit: str | None,
    width: int,
    height: int,
    field: str,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
) -> EventStream:
    """``edi.read_events`` (the one event-file reader) with its failures as a CaptureError naming
    the file and ``field``: an undecodable file is "unreadable", any other problem says what.
    ``infer``: how ``edi.read_events`` tells the time unit when ``t_unit`` is None."""
    try:
        return read_events(path, t_unit=t_unit, width=width, height=height, infer=infer)
    except CaptureError:
        raise
    except CorruptFileError as exc:
        raise CaptureError(str(path), field, f"unreadable: {str(exc).replace(f'{path}: ', '')}") from None
    except EbadError as exc:
        raise CaptureError(str(path), field, str(exc).replace(f"{path}: ", "")) from None
    except CORRUPT_FILE_ERRORS as exc:
        raise CaptureError(str(path), field, f"unreadable ({type(exc).__name__}: {exc})") from None


def read_event_file(
    path: Path,
    t_unit: str,
    width: int,
    height: int,
    t0_us: int = 0,
    infer: Callable[[np.ndarray], tuple[str, str]] | None = None,
) -> EventStream:
    """Read events from a .npz or .h5 file with arrays x, y, t, p (an h5 may keep them under an
    ``events/`` group) through ``edi.read_events``, the project's one event-file reader and
    seconds-to-microseconds conversion. Raises CaptureError naming the file and the field.
    ``t_unit`` "infer": the unit ``infer(t_raw) -> (unit, reason)`` gives."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), "events.file", "file not found")
    if path.suffix.lower() not in EVENT_SUFFIXES:
        raise CaptureError(str(path), "events.file", f"events must be a {' or '.join(EVENT_SUFFIXES)} file")
    if t_unit not in T_UNITS and not (t_unit == "infer" and infer is not None):
        raise CaptureError(str(path), "events.t_unit", f"must be one of {', '.join(T_UNITS)}; got {t_unit!r}")
    events = decode_events(path, None if t_unit == "infer" else t_unit, width, height, "events.file", infer)
    if t0_us:
        object.__setattr__(events, "t0", int(t0_us))
    return events


def _matrix(v: Any, file: str, field: str) -> np.ndarray:
    return nearest_rigid(v, file, field)


def _str(v: Any, file: str, field: str) -> str:
    if not isinstance(v, str) or not v:
        raise CaptureError(file, field, f"must be a non-empty string, got {v!r}")
    return v


def load_capture_folder(path: str | os.PathLike) -> Capture:
    """Read an ``ebad-capture/1`` folder (``path`` is the folder or its capture.json).

    Raises:
        CaptureError: a missing or malformed field, naming capture.json (or the frame's file) and the field.
    """
    path = Path(path)
    root = path.parent if path.is_file() else path
    js = root / "capture.json"
    jf = str(js)
    doc = read_json_object(js)
    width, height = _read_size(doc, jf)
    K, distortion = _read_camera(doc, jf)
    frames, exposures, c2ws, split, names = _read_frames(doc, root, jf, width, height)
    inferred: list[str] = []
    events = _read_events_entry(doc, root, jf, width, height, np.array(exposures, dtype=np.float64), inferred)
    test_views = _read_test_views(doc, root, jf, width, height)
    meta = doc.get("meta", {}) or {}
    if not isinstance(meta, dict):
        raise CaptureError(jf, "meta", f"must be an object, got {type(meta).__name__}")
    meta = dict(meta)
    if inferred:
        meta["events_t_unit_inferred"] = inferred[0]
    if len(set(names)) != len(names):
        names = [frame_name(i) for i in range(len(names))]
    cap = Capture(
        frames=np.stack(frames).astype(np.float32),
        exposures=np.array(exposures, dtype=np.float64),
        events=events,
        K=K,
        distortion=distortion,
        c2w=np.stack(c2ws) if c2ws else None,
        split=split,
        test_views=test_views,
        names=names,
        meta=meta,
        pose_trust=doc.get("pose_trust"),
        cfa=doc.get("cfa"),
    )
    return cap.validate(jf)


def _read_size(doc: dict, jf: str) -> tuple[int, int]:
    """capture.json's format (must be ``FORMAT``), width and height (positive integers)."""
    fmt = _req(doc, "format", jf, "")
    if fmt != FORMAT:
        raise CaptureError(jf, "format", f"expected {FORMAT!r}, got {fmt!r}")
    width = _req(doc, "width", jf, "")
    height = _req(doc, "height", jf, "")
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise CaptureError(jf, name, f"must be a positive integer, got {v!r}")
    return width, height


def _read_camera(doc: dict, jf: str) -> tuple[np.ndarray, np.ndarray | None]:
    """K [3, 3] from ``intrinsics`` and the optional ``distortion`` [5] (k1 k2 p1 p2 k3)."""
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
    return K, distortion


def infer_t_unit(t: np.ndarray, exposures: np.ndarray, jf: str) -> tuple[str, str]:
    """(unit, reason) of raw event times t [M] for a capture.json without ``events.t_unit``: the
    unit that puts the events' time span on the frames' (exposures [F, 2] seconds, first start to
    last end), within ``T_UNIT_SPAN_FACTOR``. Raises CaptureError (events.t_unit) when no unit
    does or the spans cannot be compared."""
    if len(t) == 0:
        return "us", "no events"
    if t.dtype.kind not in "iuf":
        raise CaptureError(jf, "events.t_unit", f"missing, and event times of dtype {t.dtype} tell no unit")
    frames_span = float(exposures[:, 1].max() - exposures[:, 0].min()) if len(exposures) else 0.0
    raw_span = float(np.max(t)) - float(np.min(t))
    ask = f'add "t_unit" (one of {", ".join(T_UNITS)}) to the events entry'
    if not (math.isfinite(raw_span) and raw_span > 0 and frames_span > 0):
        raise CaptureError(
            jf,
            "events.t_unit",
            f"missing, and cannot be inferred: the events span {raw_span:.6g} (raw) and the frames "
            f"{frames_span:.6g} s; {ask}",
        )
    ratios = {u: raw_span * US_PER_UNIT[u] * 1e-6 / frames_span for u in T_UNITS}
    unit = min(ratios, key=lambda u: abs(math.log(ratios[u])))
    spans = ", ".join(f"{raw_span * US_PER_UNIT[u] * 1e-6:.4g} s in {u}" for u in ("s", "ms", "us", "ns"))
    if not 1 / T_UNIT_SPAN_FACTOR <= ratios[unit] <= T_UNIT_SPAN_FACTOR:
        raise CaptureError(
            jf,
            "events.t_unit",
            f"missing, and no unit puts the events' span ({spans}) on the frames' {frames_span:.4g} s; {ask}",
        )
    reason = (
        f"events.t_unit missing: inferred {unit!r}, the unit that puts the events' span "
        f"({raw_span * US_PER_UNIT[unit] * 1e-6:.4g} s) on the frames' ({frames_span:.4g} s)"
    )
    return unit, reason


def _read_events_entry(
    doc: dict,
    root: Path,
    jf: str,
    width: int,
    height: int,
    exposures: np.ndarray | None = None,  # [F, 2] seconds: without t_unit, the unit is inferred against them
    inferred: list[str] | None = None,  # receives the inferred unit
) -> EventStream:
    """The stream the ``events`` entry names (file, t_unit, t0_us). Without ``t_unit`` the unit is
    ``infer_t_unit``'s (said as a warning), never assumed."""
    evd = _req(doc, "events", jf, "")
    ev_file = _str(_req(evd, "file", jf, "events"), jf, "events.file")
    t_unit = evd.get("t_unit")
    if t_unit is None:
        if exposures is None:
            raise CaptureError(jf, "events.t_unit", f"missing (one of {', '.join(T_UNITS)})")
        found: list[tuple[str, str]] = []

        def infer(t: np.ndarray) -> tuple[str, str]:
            found.append(infer_t_unit(t, exposures, jf))
            return found[-1]

        events = read_event_file(root / ev_file, "infer", width, height, t0_us=_t0_us(evd, jf), infer=infer)
        if found:
            log.warning("%s: %s", jf, found[0][1])
            if inferred is not None:
                inferred.append(found[0][0])
        return events
    if t_unit not in T_UNITS:
        raise CaptureError(jf, "events.t_unit", f"must be one of {', '.join(T_UNITS)}; got {t_unit!r}")
    return read_event_file(root / ev_file, t_unit, width, height, t0_us=_t0_us(evd, jf))


def _t0_us(evd: dict, jf: str) -> int:
    """``events.t0_us``, the stream's reference: stored times are relative, so t0 is re-attached, not subtracted."""
    t0_us = evd.get("t0_us", 0)
    if isinstance(t0_us, bool) or not isinstance(t0_us, int):
        raise CaptureError(jf, "events.t0_us", f"must be an integer, got {t0_us!r}")
    return t0_us


def _read_frames(
    doc: dict, root: Path, jf: str, width: int, height: int
) -> tuple[list[np.ndarray], list[tuple[float, float]], list[np.ndarray], list[str], list[str]]:
    """The ``frames`` entries: images [H, W, D], exposures (t_start, t_end), poses [4, 4] (every
    frame has one or none does), splits and names."""
    frames_doc = _req(doc, "frames", jf, "")
    if not isinstance(frames_doc, list) or not frames_doc:
        raise CaptureError(jf, "frames", "must be a non-empty list")
    frames: list[np.ndarray] = []
    exposures: list[tuple[float, float]] = []
    c2ws: list[np.ndarray] = []
    split: list[str] = []
    names: list[str] = []
    have_pose = ["c2w" in fr for fr in frames_doc if isinstance(fr, dict)]
    if any(have_pose) and not all(have_pose):
        i = have_pose.index(False)
        raise CaptureError(jf, f"frames[{i}].c2w", "missing (either every frame has a pose or none has)")
    for i, fr in enumerate(frames_doc):
        where = f"frames[{i}]"
        file = _str(_req(fr, "file", jf, where), jf, f"{where}.file")
        t0 = _num(_req(fr, "t_start", jf, where), jf, f"{where}.t_start")
        t1 = _num(_req(fr, "t_end", jf, where), jf, f"{where}.t_end")
        if t1 < t0:
            raise CaptureError(jf, f"{where}.t_end", f"{t1:.6f} s is {t0 - t1:.3g} s before t_start {t0:.6f} s")
        img = _read_frame_image(root, file, where, width, height, frames[0] if frames else None)
        frames.append(img)
        exposures.append((t0, t1))
        if "c2w" in fr:
            c2ws.append(_matrix(fr["c2w"], jf, f"{where}.c2w"))
        s = fr.get("split", "train")
        if not isinstance(s, str):
            raise CaptureError(jf, f"{where}.split", f"must be a string, got {s!r}")
        split.append(s)
        # a name becomes an output file name (sharp/NAME.png): a plain file name only
        names.append(check_file_name(_str(fr.get("name", Path(file).stem), jf, f"{where}.name"), jf, f"{where}.name"))
    return frames, exposures, c2ws, split, names


def _read_frame_image(
    root: Path, file: str, where: str, width: int, height: int, first: np.ndarray | None
) -> np.ndarray:  # -> [H, W, D]
    """A frame's image, of the capture's size and of the first frame's channels."""
    img = read_image(root / file, f"{where}.file")
    if img.shape[:2] != (height, width):
        raise CaptureError(
            str(root / file),
            f"{where}.file",
            f"frame is {img.shape[1]}x{img.shape[0]}, capture.json says {width}x{height}",
        )
    if first is not None and img.shape[2] != first.shape[2]:
        raise CaptureError(
            str(root / file), f"{where}.file", f"has {img.shape[2]} channels, frame 0 has {first.shape[2]}"
        )
    return img


def _read_test_views(doc: dict, root: Path, jf: str, width: int, height: int) -> list[TestView]:
    """The ``test_views`` entries: a name, a time and a c2w, an image file or both."""
    test_views = []
    tv_doc = doc.get("test_views", []) or []
    if not isinstance(tv_doc, list):
        raise CaptureError(jf, "test_views", f"must be a list, got {type(tv_doc).__name__}")
    for j, tv in enumerate(tv_doc):
        where = f"test_views[{j}]"
        name = check_file_name(_str(_req(tv, "name", jf, where), jf, f"{where}.name"), jf, f"{where}.name")
        t = _num(_req(tv, "t", jf, where), jf, f"{where}.t")
        has_pose = tv.get("c2w") is not None or not tv.get("file")  # a test view needs a c2w, a file or both
        c2w = _matrix(_req(tv, "c2w", jf, where), jf, f"{where}.c2w") if has_pose else None
        image = None
        if tv.get("file") is not None:
            tv_file = root / _str(tv["file"], jf, f"{where}.file")
            image = read_image(tv_file, f"{where}.file")
            if image.shape[:2] != (height, width):
                raise CaptureError(
                    str(tv_file),
                    f"{where}.file",
                    f"image is {image.shape[1]}x{image.shape[0]}, capture.json says {width}x{height}",
                )
        test_views.append(TestView(name=name, t=t, c2w=c2w, image=image))
    return test_views


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
    names = cap.frame_names()
    split = cap.split or ["train"] * cap.num_frames
    frames = []
    used: set[str] = set()
    for i in range(cap.num_frames):
        stem = _safe_name(names[i])
        if stem in used:
            stem = f"{frame_name(i)}_{stem}"
        used.add(stem)
        out = write_image(root / "frames" / stem, cap.frames[i])
        fr: dict[str, Any] = {
            "file": out.relative_to(root).as_posix(),
            "name": names[i],
            "t_start": float(cap.exposures[i, 0]),
            "t_end": float(cap.exposures[i, 1]),
            "split": split[i],
        }
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
            out = write_image(root / "test" / f"{frame_name(j)}_{_safe_name(tv.name)}", tv.image)
            d["file"] = out.relative_to(root).as_posix()
        tvs.append(d)
    ev = cap.events
    # stored as held (edi.EventStream: t int32 relative us when the span fits, x/y uint16, p int8; 9 bytes an
    # event), uncompressed: edi.read_events maps the file and converts it block by block
    np.savez(root / "events.npz", t=ev.t, x=ev.x, y=ev.y, p=ev.p)
    K = np.asarray(cap.K, dtype=np.float64)
    doc: dict[str, Any] = {
        "format": FORMAT,
        "width": cap.width,
        "height": cap.height,
        "intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])},
        "events": {"file": "events.npz", "t_unit": "us", "t0_us": int(ev.t0)},
        "frames": frames,
        "test_views": tvs,
        "meta": _jsonable(cap.meta),
    }
    if cap.pose_trust is not None:
        doc["pose_trust"] = cap.pose_trust
    if cap.cfa is not None:
        doc["cfa"] = cap.cfa
    if cap.distortion is not None:
        doc["distortion"] = [float(v) for v in np.asarray(cap.distortion)]
    (root / "capture.json").write_text(json.dumps(doc, indent=1, allow_nan=False))


# --------------------------------------------------------------------------- ground truth


def read_ground_truth(gt_dir: str | os.PathLike) -> GroundTruth:
    """Parse ``gt_dir/gt.json`` (the one parser of that file; ``scenes.write_scene`` writes it),
    or, for an EBAD-NeRF folder without one, map its training frames to ``images_gt_blur/``.

    Raises:
        CaptureError: the file is missing or malformed; names the file and the field.
    """
    root = Path(gt_dir)
    path = root / GT_FILE
    jf = str(path)
    if not path.is_file() and (root / "images_gt_blur").is_dir():
        return ground_truth_blur(root)
    doc = read_json_object(path)
    frames_doc = doc.get("frames", []) or []
    if not isinstance(frames_doc, list):
        raise CaptureError(jf, "frames", f"must be a list, got {type(frames_doc).__name__}")
    gt = GroundTruth(root=root, meta=dict(doc.get("meta", {}) or {}))
    for i, fr in enumerate(frames_doc):
        where = f"frames[{i}]"
        name = _str(_req(fr, "name", jf, where), jf, f"{where}.name")
        if fr.get("file") is not None:
            gt.frame_files[name] = root / _str(fr["file"], jf, f"{where}.file")
        if fr.get("trajectory") is not None:
            traj = fr["trajectory"]
            try:
                t = np.array(_req(traj, "t", jf, f"{where}.trajectory"), dtype=np.float64)
                c2w = np.array(_req(traj, "c2w", jf, f"{where}.trajectory"), dtype=np.float64)
            except (TypeError, ValueError):
                raise CaptureError(jf, f"{where}.trajectory", "t and c2w must be numeric arrays") from None
            if t.ndim != 1 or c2w.shape != (len(t), 4, 4) or not (np.isfinite(t).all() and np.isfinite(c2w).all()):
                raise CaptureError(
                    jf, f"{where}.trajectory", f"needs t [S] and c2w [S, 4, 4], finite; got {t.shape} and {c2w.shape}"
                )
            gt.trajectories[name] = (t, c2w)
    return gt
