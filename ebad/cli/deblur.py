"""``ebad deblur``: sharp frames (and sharp video) from blurry frames and their events (EDI)."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from ..errors import UserError

NAME = "deblur"
HELP = "deblur frames with their events (EDI): sharp frames, sharp instants, side-by-side images"
DESCRIPTION = """Deblur APS frames with the events of their exposures (Event-based Double Integral).

INPUT is one of
  * a capture folder (ebad-capture/1, with capture.json),
  * an AEDAT4 recording (.aedat4): its frames and events,
  * a frame image (.png ...) with --events FILE and, optionally, --exposure T0 T1 (seconds
    on the events' clock; default: the span of the events, as for the ni-joint data).

Writes DIR/sharp/NAME.png (mid-exposure), DIR/instants/NAME_KK.png (with --times N: N
instants per exposure at the centres of N equal sub-intervals), DIR/side_by_side/NAME.png
(blurry | sharp) and DIR/c.json (the contrast threshold used per frame). PNG values are
linear intensity; the sharp frames and instants are 16-bit (``--bits 8`` for 8-bit), the
side-by-side images 8-bit."""

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="capture folder, .aedat4 file, or a frame image (with --events)")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument("--c", default="auto", help="contrast threshold: 'auto' (estimated), a float, or 'c_pos,c_neg'")
    p.add_argument("--times", type=int, default=0, metavar="N", help="also write N sharp instants per exposure")
    p.add_argument("--events", help="event file for a frame image (.npz, .h5, .txt, .mat, .aedat4)")
    p.add_argument("--exposure", type=float, nargs=2, metavar=("T0", "T1"), help="exposure of a frame image, seconds")
    p.add_argument("--t-unit", choices=["s", "ms", "us", "ns"], help="time unit of --events (default: inferred)")
    p.add_argument("--max-frames", type=int, default=0, help="deblur only the first N frames (0: all)")
    p.add_argument("--skip-sharp", action="store_true", help="skip frames without events or with t_start == t_end")
    p.add_argument("--bits", type=int, choices=(8, 16), default=16,
                   help="bit depth of the sharp frames and instants (default 16; side-by-side images are 8-bit)")


def _parse_c(s: str):
    s = s.strip().lower()
    if s == "auto":
        return None
    try:
        vals = [float(v) for v in s.split(",")]
    except ValueError:
        raise UserError(f"--c must be 'auto', a float or 'c_pos,c_neg', got {s!r}") from None
    if len(vals) not in (1, 2) or not all(math.isfinite(v) and v > 0 for v in vals):
        raise UserError(f"--c must be 'auto', a positive float or 'c_pos,c_neg', got {s!r}")
    return vals[0] if len(vals) == 1 else (vals[0], vals[1])


def _read_image(path: Path) -> np.ndarray:
    from skimage import io

    img = io.imread(str(path))
    if img.dtype == np.uint8:
        a = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        a = img.astype(np.float32) / 65535.0
    else:
        a = np.clip(img.astype(np.float32), 0, 1)
    if a.ndim == 2:
        a = a[..., None]
    elif a.ndim == 3 and a.shape[-1] == 4:
        a = a[..., :3]
    if a.ndim != 3 or a.shape[-1] not in (1, 3):
        raise UserError(f"{path}: expected a grey or RGB image, got shape {img.shape}")
    return a


def _load_input(args):
    """-> frames [F, H, W, D], exposures [F, 2], events, names."""
    import edi

    path = Path(args.input)
    if not path.exists():
        raise FileNotFoundError(f"INPUT not found: {path}")
    if path.is_dir():
        try:
            from scenes import load  # the capture reader (scenes package)
        except ImportError:
            raise UserError(f"{path}: reading capture folders needs scenes.load, which this install lacks") from None
        cap = load(path)
        names = list(cap.names) or [f"{i:04d}" for i in range(cap.num_frames)]
        return np.asarray(cap.frames), np.asarray(cap.exposures, np.float64), cap.events, names
    ext = path.suffix.lower()
    if ext == ".aedat4":
        rec = edi.read_aedat4(path)
        if rec.frames.shape[0] == 0:
            raise UserError(f"{path}: the recording has no frames")
        return rec.frames, rec.exposures, rec.events, [f"{i:04d}" for i in range(rec.frames.shape[0])]
    if ext in _IMAGE_EXT:
        if not args.events:
            raise UserError(f"{path}: a frame image needs --events FILE (and optionally --exposure T0 T1)")
        img = _read_image(path)
        H, W = img.shape[:2]
        ev = edi.read_events(args.events, t_unit=args.t_unit, width=W, height=H)
        if args.exposure is not None:
            t0, t1 = args.exposure
            if not (math.isfinite(t0) and math.isfinite(t1)) or t1 < t0:
                raise UserError(f"--exposure must be T0 <= T1 in seconds, got {t0} {t1}")
        else:
            if len(ev) == 0:
                raise UserError(f"{args.events}: no events, and no --exposure given")
            t0, t1 = float(ev.t[0]) * 1e-6, (float(ev.t[-1]) + 1.0) * 1e-6
            print(f"ebad deblur: exposure from the events' span: {t0:.6f} .. {t1:.6f} s")
        return img[None], np.array([[t0, t1]]), ev, [path.stem]
    raise UserError(f"{path}: INPUT must be a capture folder, an .aedat4 file or a frame image")


def _save(path: Path, img: np.ndarray, bits: int = 8) -> None:
    from skimage import io

    path.parent.mkdir(parents=True, exist_ok=True)
    a = np.clip(np.asarray(img, np.float64), 0, 1)
    if bits == 16:
        from scenes.images import write_png16

        write_png16(path, a)
        return
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    io.imsave(str(path), (a * 255.0 + 0.5).astype(np.uint8), check_contrast=False)


def run(args) -> int:
    import edi
    from tqdm import tqdm

    c_arg = _parse_c(args.c)
    if args.times < 0:
        raise UserError(f"--times must be >= 0, got {args.times}")
    frames, exposures, events, names = _load_input(args)
    if args.max_frames and args.max_frames > 0:
        frames, exposures, names = frames[: args.max_frames], exposures[: args.max_frames], names[: args.max_frames]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    c_global = None
    c_source = "given"
    if c_arg is None and frames.shape[0] >= 2:
        try:
            c_global, rep = edi.estimate_c(frames, exposures, events, return_report=True)
            c_source = f"estimated jointly ({rep.method}, bracket {rep.bracket[0]:.4f}..{rep.bracket[1]:.4f})"
        except ValueError:
            c_global = None  # no events between frames: fall back to one estimate per frame
    per_frame = []
    bar = tqdm(range(frames.shape[0]), desc="deblur", unit="frame")
    for i in bar:
        t_s, t_e = (float(v) for v in exposures[i])
        n_ev = len(events.slice_time(t_s, t_e)) if t_e > t_s else 0
        sharp_frame = t_e <= t_s or n_ev == 0
        if sharp_frame and args.skip_sharp:
            continue
        c_i = c_arg if c_arg is not None else c_global
        src = c_source if c_arg is not None or c_global is not None else "estimated on this frame"
        lat, rep = edi.deblur(frames[i], (t_s, t_e), events, c=c_i, return_report=True)
        _save(out / "sharp" / f"{names[i]}.png", lat, args.bits)
        _save(out / "side_by_side" / f"{names[i]}.png", np.concatenate([frames[i], lat], axis=1))
        if args.times > 0 and t_e > t_s:
            ts = t_s + (np.arange(args.times) + 0.5) * (t_e - t_s) / args.times
            lats = edi.deblur(frames[i], (t_s, t_e), events, times=ts, c=rep.c)
            for k in range(args.times):
                _save(out / "instants" / f"{names[i]}_{k:02d}.png", lats[k], args.bits)
        per_frame.append({
            "name": names[i],
            "t_start": t_s,
            "t_end": t_e,
            "num_events": rep.num_events,
            "c_pos": None if sharp_frame else rep.c[0],
            "c_neg": None if sharp_frame else rep.c[1],
            "c_source": "unused (sharp frame or no events)" if sharp_frame else src,
            "c_at_bracket_end": bool(rep.c_report.at_bound) if rep.c_report is not None else None,
            "saturated_pixels": int(rep.saturated.sum()),
            "notes": rep.notes,
        })
        bar.set_postfix(events=rep.num_events, c=f"{rep.c[0]:.3f}")
    with open(out / "c.json", "w") as f:
        json.dump({"input": str(args.input), "frames": per_frame}, f, indent=2)
    print(f"ebad deblur: {len(per_frame)} frame(s) written to {out}")
    return 0
