"""Holding frames out as test views (``scenes.convert --test-every/--test-frames``, ``ebad reconstruct``,
and readers whose layout names its test views)."""

from __future__ import annotations

import dataclasses

import numpy as np

from edi import EbadError

from .capture import POSE_TRUST, Capture, TestView

__all__ = ["hold_out"]


def hold_out(
    cap: Capture, test_every: int = 0, test_frames: list[str] | tuple[str, ...] = (), pose_trust: str | None = None
) -> Capture:
    """``cap`` with frames held out as test views and its pose trust stated (``cap`` is not changed).

    ``test_every`` N > 0 holds out frames 0, N, 2N, ... (the LLFF / EBAD-NeRF split), ``test_frames``
    the frames of those names (``Capture.frame_names``: the index in 5 digits when unnamed). Each held-out frame
    leaves the frames and becomes a ``TestView`` named as the frame, at its mid-exposure, with its
    recorded image and its pose (when the capture has poses). ``pose_trust`` (one of
    ``POSE_TRUST``) replaces the capture's; None keeps it.

    Raises:
        EbadError: naming the option (``--test-every``, ``--test-frames``, ``--pose-trust``).
    """
    if test_every < 0:
        raise EbadError(f"--test-every must be >= 0 (0: none held out), got {test_every}")
    if pose_trust is not None:
        if pose_trust not in POSE_TRUST:
            raise EbadError(f"--pose-trust must be one of {', '.join(POSE_TRUST)}, got {pose_trust!r}")
        if pose_trust != "none" and cap.c2w is None:
            raise EbadError(f"--pose-trust {pose_trust}: the capture's frames carry no poses (c2w)")
    names = cap.frame_names()
    held = set(range(0, cap.num_frames, test_every)) if test_every > 0 else set()
    unknown = [n for n in test_frames if n not in names]
    if unknown:
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        raise EbadError(f"--test-frames: no frame named {', '.join(unknown)} (the frames are {shown})")
    held |= {names.index(n) for n in test_frames}
    out = dataclasses.replace(cap, pose_trust=cap.pose_trust if pose_trust is None else pose_trust)
    if not held:
        return out
    keep = [i for i in range(cap.num_frames) if i not in held]
    if not keep:
        raise EbadError(f"--test-every / --test-frames hold out all {cap.num_frames} frames: none is left to train on")
    taken = {v.name for v in cap.test_views} & {names[i] for i in held}
    if taken:
        raise EbadError(f"--test-frames: the capture already has a test view named {', '.join(sorted(taken))}")
    c2w = None if cap.c2w is None else np.asarray(cap.c2w)
    views = [
        TestView(
            name=names[i],
            t=float(np.mean(cap.exposures[i])),
            c2w=None if c2w is None else c2w[i].copy(),
            image=np.asarray(cap.frames[i]).copy(),
        )
        for i in sorted(held)
    ]
    meta = {**cap.meta, "held_out_frames": [*cap.meta.get("held_out_frames", []), *(names[i] for i in sorted(held))]}
    return dataclasses.replace(
        out,
        frames=cap.frames[keep],
        exposures=np.asarray(cap.exposures)[keep],
        c2w=None if c2w is None else c2w[keep],
        split=[cap.split[i] for i in keep] if cap.split else [],
        names=[names[i] for i in keep],
        test_views=[*cap.test_views, *views],
        meta=meta,
    )
