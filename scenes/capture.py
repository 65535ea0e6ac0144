"""The in-memory capture: what every reader returns and the reconstruction eats."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edi import EventStream

from .errors import CaptureError

__all__ = [
    "Capture",
    "TestView",
    "frame_name",
    "check_rigid",
    "check_file_name",
    "file_in",
    "nearest_rigid",
    "guess_K",
    "POSE_TRUST",
    "ROTATION_REPAIR_TOL",
    "EXACT_RIGID_TOL",
    "DAVIS_DEFAULT_HFOV_DEG",
]

RIGID_TOL = 1e-5  # max |R^T R - I| and |det R - 1| accepted for a camera pose
# How far a capture's poses can be trusted, as the capture states it (real captures state it
# too: motion capture -> "exact", SfM or another tool -> "approximate", nothing -> "none").
POSE_TRUST = ("exact", "approximate", "none")
# Largest deviation of a pose's rotation from orthonormal (|singular value - 1|) that is
# repaired (re-orthonormalised by SVD) instead of refused. Poses written with 5 decimals are
# off by ~1e-5; 1e-3 still refuses any real scale (a 0.1% zoom) and every reflection.
ROTATION_REPAIR_TOL = 1e-3
EXACT_RIGID_TOL = 1e-9  # a pose this close to rigid is kept bit for bit (float64 round trips of rigid poses)
DAVIS_DEFAULT_HFOV_DEG = 70.0  # used only when a recording comes with no K


def frame_name(i: int) -> str:
    """The name of frame ``i`` of a capture whose frames carry none: its index in 5 digits (``00042``), as
    every reader, ``scenes.convert``, ``save`` and ``ebad`` name them. Names already given (a capture written
    with 4-digit names, read back) are kept as they are."""
    return f"{int(i):05d}"


def check_file_name(name: Any, file: str | None, field_name: str) -> str:
    """``name`` if it is a plain file name (frame and test-view names become output file names:
    ``sharp/NAME.png``, ``deblurred/NAME.png``); raise CaptureError naming ``file`` and ``field_name``
    for a non-string, an empty name, ``.`` or ``..``, a path separator, a NUL or an absolute path."""
    if not isinstance(name, str):
        raise CaptureError(file, field_name, f"must be a string, got {name!r}")
    if not name:
        raise CaptureError(file, field_name, "must be a non-empty file name")
    bad = next((ch for ch in ("/", "\\", "\0") if ch in name), None)
    if bad is not None or name in (".", "..") or os.path.isabs(name):
        what = f"contains {bad!r}" if bad is not None else f"is {name!r}"
        raise CaptureError(
            file, field_name, f"must be a plain file name (no folder, '..' or absolute path); {name!r} {what}"
        )
    return name


def file_in(folder: str | os.PathLike, name: str, suffix: str = "", what: str = "name") -> Path:
    """``folder / (name + suffix)``, the one way an output path is built from a name that came
    from a capture or a run folder: refuses (CaptureError naming ``what``) a name that is not a
    plain file name, so whose path would leave ``folder`` (through ``..`` or an absolute path)."""
    check_file_name(name, str(folder), what)
    folder = Path(folder)
    path = folder / f"{name}{suffix}"
    if path.parent != folder:
        raise CaptureError(str(folder), what, f"{name + suffix!r} would write outside the folder")
    return path


def check_rigid(m: np.ndarray, file: str | None, field_name: str) -> np.ndarray:
    """Return ``m`` as a float64 [4, 4] rigid transform, or raise CaptureError naming the field."""
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CaptureError(file, field_name, f"not a numeric 4x4 matrix ({exc})") from None
    if a.shape != (4, 4):
        raise CaptureError(file, field_name, f"must be a 4x4 matrix, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise CaptureError(file, field_name, "has a non-finite entry")
    if np.abs(a[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > RIGID_TOL:
        raise CaptureError(
            file, field_name, f"last row must be [0, 0, 0, 1], got [{', '.join(f'{v:.4g}' for v in a[3])}]"
        )
    r = a[:3, :3]
    ortho = np.abs(r.T @ r - np.eye(3)).max()
    det = float(np.linalg.det(r))
    if ortho > RIGID_TOL or abs(det - 1.0) > RIGID_TOL:
        raise CaptureError(
            file, field_name, f"is not a rigid transform (max |R^T R - I| = {ortho:.2e}, det R = {det:.6f})"
        )
    return a


def nearest_rigid(
    m: Any,  # [4, 4]
    file: str | None,
    field_name: str,
    tol: float = ROTATION_REPAIR_TOL,
) -> np.ndarray:
    """A camera pose read from a file as a float64 [4, 4] rigid transform.

    A pose already orthonormal to ``EXACT_RIGID_TOL`` is returned unchanged (so save -> load
    stays lossless). A rotation block within ``tol`` of orthonormal (every singular value in [1 - tol, 1 + tol],
    det > 0; e.g. poses rounded to 5 decimals) is replaced by the nearest rotation (SVD:
    R = U V^T); a scale, a shear or a reflection is refused, as is a last row that is not
    [0, 0, 0, 1] within ``tol``.

    Raises:
        CaptureError: naming ``file`` and ``field_name`` and what is wrong.
    """
    try:
        a = np.array(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise CaptureError(file, field_name, "must be a 4x4 list of numbers") from None
    if a.shape != (4, 4):
        raise CaptureError(file, field_name, f"must be a 4x4 matrix, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise CaptureError(file, field_name, "has a non-finite entry")
    if np.abs(a[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > tol:
        raise CaptureError(
            file, field_name, f"last row must be [0, 0, 0, 1], got [{', '.join(f'{v:.4g}' for v in a[3])}]"
        )
    u, sv, vt = np.linalg.svd(a[:3, :3])
    det = float(np.linalg.det(a[:3, :3]))
    if det <= 0:
        raise CaptureError(
            file, field_name, f"is not a rigid transform: the rotation is a reflection (det R = {det:.6f})"
        )
    dev = float(np.abs(sv - 1.0).max())
    if dev > tol:
        raise CaptureError(
            file,
            field_name,
            f"is not a rigid transform: the rotation block scales by "
            f"{sv.min():.6f}..{sv.max():.6f} (repaired only within {tol:g} of 1)",
        )
    if dev > EXACT_RIGID_TOL or np.abs(a[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > EXACT_RIGID_TOL:
        a[:3, :3] = u @ vt
        a[3] = (0.0, 0.0, 0.0, 1.0)
    return check_rigid(a, file, field_name)


def guess_K(width: int, height: int) -> np.ndarray:  # -> [3, 3]
    """Pinhole intrinsics from a 70-degree horizontal field of view (DAVIS346 with its usual
    lens), for recordings that carry no calibration; callers set ``meta['K_guessed']``."""
    fx = 0.5 * width / math.tan(math.radians(DAVIS_DEFAULT_HFOV_DEG) / 2)
    return np.array([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1.0]])


@dataclass
class TestView:
    """A held-out view: a camera at time ``t`` (seconds) with pose ``c2w`` [4, 4] and/or
    its sharp image [H, W, D] float32 in [0, 1] (at least one of the two). A view with an
    image and no pose gets its pose from SfM (``scenes.colmap.estimate_poses``)."""

    __test__ = False  # not a pytest test class

    name: str
    t: float
    c2w: np.ndarray | None  # [4, 4], or None: unknown (then ``image`` is required)
    image: np.ndarray | None = None  # [H, W, D]


@dataclass
class Capture:
    """A blurry multi-view event capture.

    Convention: frames are linear intensity in [0, 1], D = 1 grey or 3 colour; exposures in
    seconds on the same clock as ``events`` (whose ``t`` is microseconds from the capture
    start); ``K`` in pixels with the top-left pixel centre at (0.5, 0.5); ``c2w`` OpenCV
    camera-to-world at mid-exposure.
    """

    frames: np.ndarray  # [F, H, W, D] float32 in [0, 1]
    exposures: np.ndarray  # [F, 2] float64 seconds (t_start, t_end)
    events: EventStream
    K: np.ndarray  # [3, 3] float64
    distortion: np.ndarray | None = None  # [5] k1 k2 p1 p2 k3, or None
    c2w: np.ndarray | None = None  # [F, 4, 4] float64, or None (no poses)
    split: list[str] = field(default_factory=list)  # per frame: "train" | "test" | ...
    test_views: list[TestView] = field(default_factory=list)
    names: list[str] = field(default_factory=list)  # per frame, for output file names
    meta: dict[str, Any] = field(default_factory=dict)  # free-form: source layout, time unit, ...
    # how far ``c2w`` (and the test views' poses) can be trusted: "exact", "approximate" or
    # "none" (not to be used even if present); None: unstated, read as ``effective_pose_trust``
    pose_trust: str | None = None
    # the colour filter array over the APS and event pixels of a colour DAVIS (``edi.cfa``:
    # "RGGB" | "BGGR" | "GRBG" | "GBRG", in the frames' pixel grid), or None: a grey sensor, or a
    # colour capture whose events are taken as luminance. With ``cfa`` frames are RGB (demosaiced
    # by the camera's software) or raw mosaics (D = 1); events always come from the mosaic.
    cfa: str | None = None

    @property
    def raw_mosaic(self) -> bool:
        """True when the frames are raw Bayer mosaics (``cfa`` set and one channel)."""
        return self.cfa is not None and self.channels == 1

    @property
    def effective_pose_trust(self) -> str:
        """``pose_trust`` when stated; else "approximate" when the capture has poses (poses from
        SfM or another tool are never exact) and "none" when it has none."""
        if self.pose_trust is not None:
            return self.pose_trust
        return "none" if self.c2w is None else "approximate"

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    def frame_names(self) -> list[str]:
        """``names``, or each frame's ``frame_name`` when the capture has none."""
        return list(self.names) if self.names else [frame_name(i) for i in range(self.num_frames)]

    @property
    def height(self) -> int:
        return int(self.frames.shape[1])

    @property
    def width(self) -> int:
        return int(self.frames.shape[2])

    @property
    def channels(self) -> int:
        return int(self.frames.shape[3])

    def validate(self, source: str | None = None) -> Capture:
        """Check every field (shapes, dtypes, ranges, rigid poses); raise CaptureError naming
        the field (and ``source``, the file it came from, when given). Returns ``self``."""
        self._check_frames(source)
        self._check_exposures(source)
        self._check_cfa(source)
        self._check_events(source)
        self._check_camera(source)
        self._check_poses(source)
        self._check_per_frame_lists(source)
        seen: set[str] = set()
        for j, tv in enumerate(self.test_views):
            if tv.name in seen:
                raise CaptureError(source, f"test_views[{j}].name", f"duplicate name {tv.name!r}")
            seen.add(tv.name)
            _check_test_view(tv, j, self.frames.shape[1:], source)
        return self

    def _check_frames(self, source: str | None) -> None:
        """frames: a float32 [F, H, W, D] array, D in (1, 3), F >= 1, finite, in [0, 1]."""
        f = self.frames
        if not isinstance(f, np.ndarray) or f.ndim != 4 or f.shape[3] not in (1, 3):
            raise CaptureError(
                source, "frames", f"must be a [F, H, W, D] array with D in (1, 3), got {getattr(f, 'shape', type(f))}"
            )
        if f.shape[0] == 0:
            raise CaptureError(source, "frames", "a capture needs at least one frame")
        if f.dtype != np.float32:
            raise CaptureError(source, "frames", f"must be float32, got {f.dtype}")
        if not np.isfinite(f).all() or f.min() < 0.0 or f.max() > 1.0:
            raise CaptureError(source, "frames", "must be finite linear intensity in [0, 1]")

    def _check_exposures(self, source: str | None) -> None:
        """exposures: [F, 2] finite, t_end >= t_start."""
        n = self.frames.shape[0]
        e = np.asarray(self.exposures)
        if e.shape != (n, 2):
            raise CaptureError(source, "exposures", f"must have shape ({n}, 2), got {e.shape}")
        if not np.isfinite(e).all():
            raise CaptureError(source, "exposures", "has a non-finite time")
        bad = np.flatnonzero(e[:, 1] < e[:, 0])
        if len(bad):
            t0, t1 = e[bad[0]]
            raise CaptureError(
                source,
                f"exposures[{bad[0]}]",
                f"t_end {t1:.6f} s is {t0 - t1:.3g} s before t_start {t0:.6f} s",
            )

    def _check_events(self, source: str | None) -> None:
        """events: an ``edi.EventStream`` of the frames' sensor size."""
        ev = self.events
        if not isinstance(ev, EventStream):
            raise CaptureError(source, "events", f"must be an edi.EventStream, got {type(ev).__name__}")
        if (ev.width, ev.height) != (self.width, self.height):
            raise CaptureError(
                source, "events", f"sensor {ev.width}x{ev.height} differs from the frames' {self.width}x{self.height}"
            )

    def _check_camera(self, source: str | None) -> None:
        """K: a finite pinhole [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], fx, fy > 0; distortion: 5 finite
        numbers or None."""
        k = np.asarray(self.K, dtype=np.float64)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise CaptureError(source, "K", f"must be a finite 3x3 matrix, got shape {k.shape}")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or np.abs(k[2] - [0, 0, 1]).max() > 0 or k[1, 0] != 0 or k[0, 1] != 0:
            raise CaptureError(source, "K", "must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        if self.distortion is not None:
            d = np.asarray(self.distortion, dtype=np.float64)
            if d.shape != (5,) or not np.isfinite(d).all():
                raise CaptureError(
                    source, "distortion", f"must be 5 finite numbers k1 k2 p1 p2 k3, got shape {d.shape}"
                )

    def _check_poses(self, source: str | None) -> None:
        """c2w: None or [F, 4, 4] rigid; pose_trust: unset or one of ``POSE_TRUST``, and not trusted without poses."""
        n = self.frames.shape[0]
        if self.c2w is not None:
            c = np.asarray(self.c2w)
            if c.shape != (n, 4, 4):
                raise CaptureError(source, "c2w", f"must have shape ({n}, 4, 4), got {c.shape}")
            for i in range(n):
                check_rigid(c[i], source, f"frames[{i}].c2w")
        if self.pose_trust is not None and self.pose_trust not in POSE_TRUST:
            raise CaptureError(
                source, "pose_trust", f"must be one of {list(POSE_TRUST)} or unset, got {self.pose_trust!r}"
            )
        if self.pose_trust in ("exact", "approximate") and self.c2w is None:
            raise CaptureError(source, "pose_trust", f"is {self.pose_trust!r} but the frames carry no c2w")

    def _check_cfa(self, source: str | None) -> None:
        """cfa: unset or a Bayer pattern of ``edi.cfa`` that fits the frames.

        A pattern fits when the frames are at least 2 x 2 and are the events' pixel grid (the
        same W x H: the pattern names the filters of the frames' pixels, and events always come
        from the mosaic, so one pattern must hold for both). Frames flipped or cropped from the
        sensor state the transformed pattern (``edi.cfa.transform_pattern``: a crop at an odd
        offset or a flip of an odd size moves which filter sits at (0, 0)). With ``cfa`` the
        frames are 3-channel (demosaiced) or 1-channel raw mosaics, which are the sensor's values
        themselves, so a raw frame of another size than the events' sensor is never right.
        """
        if self.cfa is None:
            return
        from edi.cfa import check_pattern

        try:
            self.cfa = check_pattern(self.cfa)
        except ValueError as exc:
            raise CaptureError(source, "cfa", str(exc).split(": ", 1)[-1]) from None
        if self.height < 2 or self.width < 2:
            raise CaptureError(
                source, "cfa", f"a 2x2 Bayer pattern needs frames of at least 2x2, got {self.width}x{self.height}"
            )
        ev = self.events
        if isinstance(ev, EventStream) and (ev.width, ev.height) != (self.width, self.height):
            kind = "raw Bayer mosaics" if self.channels == 1 else "demosaiced RGB frames"
            raise CaptureError(
                source,
                "frames" if self.channels == 1 else "cfa",
                f"{kind} of {self.width}x{self.height} under cfa {self.cfa}, but the events' sensor is "
                f"{ev.width}x{ev.height}: with a colour filter the frames must be the events' pixel grid "
                "(frames cropped or flipped from it state the transformed pattern, edi.cfa.transform_pattern, "
                "and the events are cropped or flipped alike)",
            )

    def _check_per_frame_lists(self, source: str | None) -> None:
        """split and names: empty or one entry per frame; names unique."""
        n = self.frames.shape[0]
        if self.split and len(self.split) != n:
            raise CaptureError(source, "split", f"needs one entry per frame ({n}), got {len(self.split)}")
        if self.names and len(self.names) != n:
            raise CaptureError(source, "names", f"needs one entry per frame ({n}), got {len(self.names)}")
        if self.names and len(set(self.names)) != n:
            raise CaptureError(source, "names", "frame names must be unique")
        for i, name in enumerate(self.names):
            check_file_name(name, source, f"frames[{i}].name")


def _check_test_view(tv: TestView, j: int, image_shape: tuple[int, ...], source: str | None) -> None:
    """Test view ``j``: a finite t, a rigid c2w and/or a float32 image of the frames' [H, W, D] in [0, 1]."""
    check_file_name(tv.name, source, f"test_views[{j}].name")
    if not np.isfinite(float(tv.t)):
        raise CaptureError(source, f"test_views[{j}].t", "must be finite")
    if tv.c2w is None and tv.image is None:
        raise CaptureError(source, f"test_views[{j}]", "needs a c2w, an image, or both")
    if tv.c2w is not None:
        check_rigid(tv.c2w, source, f"test_views[{j}].c2w")
    if tv.image is not None:
        im = tv.image
        if not isinstance(im, np.ndarray) or im.shape != image_shape or im.dtype != np.float32:
            raise CaptureError(
                source,
                f"test_views[{j}].image",
                f"must be float32 {image_shape}, got {getattr(im, 'dtype', None)} {getattr(im, 'shape', None)}",
            )
        if not np.isfinite(im).all() or im.min() < 0 or im.max() > 1:
            raise CaptureError(source, f"test_views[{j}].image", "must be finite and in [0, 1]")
