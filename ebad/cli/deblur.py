"""``ebad deblur``: sharp frames (and sharp video) from blurry frames and their events (EDI, mEDI)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

from ..errors import UserError

NAME = "deblur"
HELP = "deblur frames with their events (EDI or mEDI): sharp frames, sharp instants, side-by-side images"

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".npy"}


@dataclass
class Args:
    input: Annotated[tyro.conf.Positional[str], tyro.conf.arg(metavar="INPUT")]
    (
        "a capture folder (ebad-capture/1, with capture.json), an AEDAT4 recording (.aedat4: its frames and events), "
        "or a frame image (.png ...) with --events FILE and, optionally, --exposure T0 T1"
    )
    out: str
    (
        "output folder (created): sharp/NAME.png (mid-exposure), instants/NAME_KK.png (with --times), "
        "side_by_side/NAME.png (blurry | sharp), c.json (the contrast thresholds used, per frame, and how they were "
        "found); PNG values are linear intensity"
    )
    c: str = "auto"
    (
        "contrast threshold: a float, 'c_pos,c_neg', or 'auto': estimated jointly from consecutive frames when there "
        "are two or more (c_pos and c_neg), else from the one frame (brightness constancy of the latent video); when "
        "that estimate has no interior minimum the command says so: give --c (DAVIS sensors: 0.1 to 0.5) or more frames"
    )
    gamma: str = "1"
    (
        "the frames' response, recorded = irradiance ** GAMMA (1: linear); the frames are linearised for EDI and the "
        "output mapped back. With linear frames assumed on a non-linear camera the estimated c is in the frames' units "
        "(about G x c): it deblurs those frames as well as the true c and response do, but is not the events' "
        "threshold (the frames and events do not tell G apart from c); give --gamma for c in the events' units"
    )
    medi: bool = False
    (
        "solve all frames jointly (mEDI, two or more frames: each pixel's log intensities follow the events between "
        "frames; saturated pixels are carried by their neighbours in time) instead of one by one"
    )
    times: Annotated[int, tyro.conf.arg(metavar="N")] = 0
    """also write N sharp instants per exposure, at the centres of N equal sub-intervals"""
    events: Annotated[str | None, tyro.conf.arg(metavar="FILE")] = None
    """event file for a frame image (.npz, .h5, .txt, .mat, .aedat4)"""
    exposure: Annotated[tuple[float, float] | None, tyro.conf.arg(metavar="T0 T1")] = None
    """exposure of a frame image, seconds on the events' clock (None: the span of the events, as for ni-joint data)"""
    t_unit: Literal["s", "ms", "us", "ns"] | None = None
    """time unit of --events (None: inferred from the timestamps' magnitude and span)"""
    max_frames: Annotated[int, tyro.conf.arg(metavar="N")] = 0
    """deblur only the first N frames (0: all)"""
    skip_sharp: bool = False
    """skip frames without events or with t_start == t_end"""
    bits: Literal[8, 16] = 16
    """bit depth of the sharp frames and instants (side-by-side images are 8-bit)"""
    cfa: Annotated[str | None, tyro.conf.arg(metavar="PATTERN")] = None
    (
        "Bayer pattern of a colour DAVIS (RGGB, BGGR, GRBG, GBRG: the filters of pixels (0,0), (1,0), (0,1), (1,1)) "
        "for an input that does not say it (a frame image, a recording); a capture's own cfa (capture.json) is used "
        "otherwise. With it each pixel's events follow its own channel: EDI runs per pixel of the mosaic, RGB frames "
        "get the demosaiced per-pixel latents, raw mosaics raw latents"
    )


def _parse_c(s: str):
    """'auto' -> None; 'C' or 'C_POS,C_NEG' -> edi.Contrast (validated by edi.parse_c)."""
    from edi import InputError, parse_c

    s = s.strip().lower()
    if s == "auto":
        return None
    try:
        vals = [float(v) for v in s.split(",")]
        return parse_c(vals[0] if len(vals) == 1 else vals, "--c")
    except (ValueError, InputError):
        raise UserError(f"--c must be 'auto', a positive float or 'c_pos,c_neg', got {s!r}") from None


def _parse_gamma(s: str) -> float:
    """A number in edi.model.GAMMA_RANGE (validated by edi.model.check_gamma)."""
    from edi import InputError
    from edi.model import GAMMA_RANGE, check_gamma

    try:
        return check_gamma(float(s), "--gamma")
    except (ValueError, InputError):
        raise UserError(
            f"--gamma must be a number in [{GAMMA_RANGE[0]}, {GAMMA_RANGE[1]}] (1: linear), got {s!r}"
        ) from None


def _frame_names(n: int) -> list[str]:
    """Names of n frames that carry none: ``scenes.capture.frame_name``, as scenes' readers name a recording's
    frames (so ``scenes.convert`` of the same recording and this command write the same file names)."""
    from scenes.capture import frame_name

    return [frame_name(i) for i in range(n)]


def _load_input(args):
    """-> frames [F, H, W, D], exposures [F, 2], events, names, the time unit note, the input's cfa (or None)."""
    import edi

    path = Path(args.input)
    if not path.exists():
        raise FileNotFoundError(2, "INPUT not found", str(path))
    if path.is_dir():
        from scenes import load  # the capture reader

        cap = load(path)
        names = cap.frame_names()
        unit = f"capture.json's t_unit ({path / 'capture.json'})"
        return np.asarray(cap.frames), np.asarray(cap.exposures, np.float64), cap.events, names, unit, cap.cfa
    ext = path.suffix.lower()
    if ext == ".aedat4":
        rec = edi.read_aedat4(path)
        if rec.frames.shape[0] == 0:
            raise UserError(f"{path}: the recording has no frames")
        names = _frame_names(rec.frames.shape[0])
        return rec.frames, rec.exposures, rec.events, names, "us (AEDAT4)", getattr(rec, "cfa", None)
    if ext in _IMAGE_EXT:
        from scenes.images import read_image

        if not args.events:
            raise UserError(f"{path}: a frame image needs --events FILE (and optionally --exposure T0 T1)")
        img = read_image(path, "INPUT")
        H, W = img.shape[:2]
        ev, unit, reason = edi.read_events(args.events, t_unit=args.t_unit, width=W, height=H, return_unit=True)
        note = f"{unit} ({reason})"
        print(f"ebad deblur: {args.events}: {len(ev)} events, time unit {note}")
        if args.exposure is not None:
            t0, t1 = args.exposure
            if not (math.isfinite(t0) and math.isfinite(t1)) or t1 < t0:
                raise UserError(f"--exposure must be T0 <= T1 in seconds, got {t0:g} {t1:g}")
        else:
            if len(ev) == 0:
                raise UserError(f"{args.events}: no events, and no --exposure given")
            t0, t1 = float(ev.t[0]) * 1e-6, (float(ev.t[-1]) + 1.0) * 1e-6
            print(f"ebad deblur: exposure from the events' span: {t0:.6f} .. {t1:.6f} s")
        return img[None], np.array([[t0, t1]]), ev, [path.stem], note, None
    raise UserError(f"{path}: INPUT must be a capture folder, an .aedat4 file or a frame image")


def _event_counts(events, exposures: np.ndarray) -> np.ndarray:
    import edi

    return np.array(
        [np.subtract(*edi.events_in_window(events, t0, t1)[::-1]) if t1 > t0 else 0 for t0, t1 in exposures]
    )


def _check_events_reach_the_frames(events, exposures: np.ndarray, counts: np.ndarray, unit: str) -> None:
    """No blurry exposure with events: stop, showing the exposures next to the events' times."""
    blurry = exposures[:, 1] > exposures[:, 0]
    if not blurry.any() or counts[blurry].any():
        return
    ev_range = (
        "no events at all"
        if len(events) == 0
        else f"events from {events.t[0] * 1e-6:.6f} to {events.t[-1] * 1e-6:.6f} s"
    )
    raise UserError(
        f"no exposure has events: exposures from {exposures[:, 0].min():.6f} to {exposures[:, 1].max():.6f} s, "
        f"{ev_range}, time unit assumed {unit}; check the time unit (--t-unit) or the exposure times"
    )


def _resolve_cfa(given: str | None, recorded: str | None, source: str, channels: int) -> str | None:
    """--cfa checked (``edi.cfa.check_pattern``) against what the input records and its frames'
    channels; the pattern in use."""
    from edi import InputError
    from edi.cfa import check_pattern

    cfa = recorded
    if given is not None:
        try:
            cfa = check_pattern(given, "--cfa")
        except InputError as exc:
            raise UserError(str(exc)) from None
        if recorded is not None and recorded != cfa:
            raise UserError(f"--cfa {cfa} disagrees with {source}, which records cfa {recorded}")
    if cfa is not None and channels not in (1, 3):
        raise UserError(f"{source}: with cfa {cfa} frames must be RGB or raw mosaics, got {channels} channels")
    return cfa


def _cfa_note(cfa: str | None, channels: int) -> str:
    """What the summary line says about a colour DAVIS capture ("" without a cfa)."""
    if cfa is None:
        return ""
    out = "raw latents" if channels == 1 else "RGB latents demosaiced"
    return f"; colour DAVIS (cfa {cfa}): per-pixel EDI on the Bayer mosaic, {out}"


def _medi(frames: np.ndarray, exposures: np.ndarray, events, c, gamma: float, cfa: str | None) -> np.ndarray:
    """mEDI latents of all frames in the frames' recorded units (with a cfa: per pixel of the mosaic,
    RGB frames demosaiced in recorded units as ``edi.deblur`` does)."""
    import edi
    from edi.cfa import demosaic
    from edi.model import linearize_saturated, to_mosaic, to_unit_range

    lin, sat = linearize_saturated(to_unit_range(frames, "frames"), gamma)  # the rule on the recorded values
    if cfa is not None:
        lin = to_mosaic(lin, cfa, "frames")
    lat = edi.apply_gamma(edi.medi(lin, exposures, events, c=c, saturation=sat, cfa=cfa), gamma)
    if cfa is not None and frames.shape[-1] == 3:
        lat = np.clip(demosaic(lat[..., 0], cfa), 0.0, 1.0)
    return lat


def _estimate(frames, exposures, events, counts, c_arg, gamma, cfa=None):
    """-> (c for the frames or None to estimate per frame, source text, the report or None)."""
    import edi

    if c_arg is not None:
        return c_arg, "given (--c)", None
    use = counts > 0
    if frames.shape[0] >= 2:
        try:
            rep = edi.estimate_contrast(frames, exposures, events, pair=True, gamma=gamma, cfa=cfa)
            c = rep.c
        except edi.InputError:
            return None, "estimated on each frame", None
        return c, f"estimated jointly ({rep.method}, {rep.energy_name})", rep
    if not use.any():
        return None, "unused (no events)", None
    return None, "estimated on this frame", None


def _save(path: Path, img: np.ndarray, bits: int = 8) -> None:
    from PIL import Image

    from scenes.images import write_png16

    path.parent.mkdir(parents=True, exist_ok=True)
    a = np.clip(np.asarray(img, np.float64), 0, 1)
    if bits == 16:
        write_png16(path, a)
        return
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    Image.fromarray((a * 255.0 + 0.5).astype(np.uint8)).save(path, format="PNG")


def _say_unreliable(rep, where: str) -> None:
    """An unreliable estimate: one short line (what is wrong, what to do), then the estimator's reasons
    wrapped and indented (c.json keeps them whole)."""
    import textwrap

    if rep is None or rep.reliable:
        return
    c = rep.c
    cs = f"c {c.pos:.4g}" if c.pos == c.neg else f"c_pos {c.pos:.4g}, c_neg {c.neg:.4g}"
    print(
        f"ebad deblur: warning: {where}: estimated {cs} is unreliable; "
        "give --c (DAVIS: 0.1 to 0.5) or more frames; why:"
    )
    why = rep.message.removeprefix("estimate_c: ")
    print(textwrap.fill(why, width=100, initial_indent="  ", subsequent_indent="  ", break_on_hyphens=False))


def run(args: Args) -> int:
    import logging

    from tqdm import tqdm

    import edi
    from scenes.capture import file_in  # output paths from frame names: never outside their folder

    # estimate_c logs a warning when its estimate is unreliable; this command prints that
    # message itself (with what to do), so the library's copy would repeat it
    logging.getLogger("edi.contrast").addHandler(logging.NullHandler())

    c_arg = _parse_c(args.c)
    gamma = _parse_gamma(args.gamma)
    if args.times < 0:
        raise UserError(f"--times must be >= 0, got {args.times}")
    if args.max_frames < 0:
        raise UserError(f"--max-frames must be >= 0, got {args.max_frames}")
    frames, exposures, events, names, unit, recorded_cfa = _load_input(args)
    cfa = _resolve_cfa(args.cfa, recorded_cfa, str(args.input), frames.shape[-1])
    cfa_note = _cfa_note(cfa, frames.shape[-1])
    if args.max_frames:
        frames, exposures, names = frames[: args.max_frames], exposures[: args.max_frames], names[: args.max_frames]
    if args.medi and frames.shape[0] < 2:
        raise UserError(f"--medi needs two or more frames; {args.input} has {frames.shape[0]}")
    counts = _event_counts(events, exposures)
    _check_events_reach_the_frames(events, exposures, counts, unit)
    blurry = exposures[:, 1] > exposures[:, 0]
    n_empty = int((blurry & (counts == 0)).sum())
    if n_empty:
        print(
            f"ebad deblur: {n_empty} of {int(blurry.sum())} blurry exposure(s) have no events: written "
            "unchanged (listed in c.json)"
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    c_all, c_source, c_rep = _estimate(frames, exposures, events, counts, c_arg, gamma, cfa)
    if cfa_note:
        print(f"ebad deblur: the capture has a colour filter array (cfa {cfa}){cfa_note.split(':', 1)[1]}")
    units = (
        f"log-irradiance units, frames linearised with gamma {gamma:g}"
        if gamma != 1.0
        else "frames taken as linear: if they are not, c is in the frames' units; give --gamma"
    )
    if c_all is not None:
        print(f"ebad deblur: c_pos {c_all[0]:.4f}, c_neg {c_all[1]:.4f} ({c_source}; {units})")
    _say_unreliable(c_rep, "the joint estimate")
    medi_lat = None
    if args.medi:
        medi_lat = _medi(frames, exposures, events, c_all, gamma, cfa)
        c_source += ", mEDI"
        print(f"ebad deblur: mEDI: {frames.shape[0]} frames solved jointly")
    per_frame = []
    for i in tqdm(range(frames.shape[0]), desc="deblur", unit="frame"):
        t_s, t_e = (float(v) for v in exposures[i])
        sharp_frame = t_e <= t_s or counts[i] == 0
        if sharp_frame and args.skip_sharp:
            continue
        lat, rep = edi.deblur_with_report(frames[i], (t_s, t_e), events, c=c_all, gamma=gamma, cfa=cfa)
        if rep.c_report is not None:
            print(f"ebad deblur: {names[i]}: c {rep.c.mean:.4f} ({c_source})")
            _say_unreliable(rep.c_report, names[i])
        if medi_lat is not None:
            lat = medi_lat[i]
        _save(file_in(out / "sharp", names[i], ".png"), lat, args.bits)
        _save(file_in(out / "side_by_side", names[i], ".png"), np.concatenate([frames[i], lat], axis=1))
        if args.times > 0 and not sharp_frame:
            ts = t_s + (np.arange(args.times) + 0.5) * (t_e - t_s) / args.times
            lats = edi.deblur(frames[i], (t_s, t_e), events, times=ts, c=rep.c, gamma=gamma, cfa=cfa)
            for k in range(args.times):
                _save(file_in(out / "instants", f"{names[i]}_{k:02d}", ".png"), lats[k], args.bits)
        c_report = rep.c_report or c_rep
        per_frame.append(
            {
                "name": names[i],
                "t_start": t_s,
                "t_end": t_e,
                "num_events": rep.num_events,
                "c_pos": None if sharp_frame else rep.c.pos,
                "c_neg": None if sharp_frame else rep.c.neg,
                "c_source": "unused (sharp frame or no events)" if sharp_frame else c_source,
                "c_at_bracket_end": None if sharp_frame or c_report is None else bool(c_report.at_bound),
                "c_reliable": None if sharp_frame or c_report is None else bool(c_report.reliable),
                "c_message": None if sharp_frame or c_report is None else c_report.message,
                "saturated_pixels": int(rep.saturated.sum()),
                "notes": rep.notes,
            }
        )
    with open(out / "c.json", "w") as f:
        json.dump(
            {
                "input": str(args.input),
                "time_unit": unit,
                "medi": bool(args.medi),
                "cfa": cfa,
                "gamma": gamma,
                "gamma_source": "given (--gamma)"
                if gamma != 1.0
                else "assumed linear (default: c in the frames' units)",
                "frames": per_frame,
            },
            f,
            indent=2,
        )
    unreliable = [fr["name"] for fr in per_frame if fr["c_reliable"] is False]
    tail = (
        f"; {len(unreliable)} of them with an unreliable c, not deblurred reliably "
        f"({', '.join(unreliable[:3])}{', ...' if len(unreliable) > 3 else ''}): give --c (c.json has the reports)"
        if unreliable
        else ""
    )
    print(f"ebad deblur: {len(per_frame)} frame(s) written to {out}{cfa_note}{tail}")
    return 0
