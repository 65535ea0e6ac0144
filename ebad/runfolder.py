"""The run folder: what ``ebad reconstruct`` leaves behind, and how ``render``/``eval`` read it.

Layout::

    RUN/config.json            resolved Config (written once, when the run starts)
    RUN/checkpoints/last.pt    resumable TrainState (every train.checkpoint_every steps and at the end)
    RUN/point_cloud.ply        standard 3DGS layout (see ebad.io), colours in the capture's recorded domain
    RUN/model.json             K, image size, frame names, exposures, V per frame, trajectories
    RUN/history.json           one StepStats per step
    RUN/trajectories.json      camera-to-world poses sampled over every exposure
    RUN/trajectories.png       their plot
    RUN/trajectories_tum.txt   the same poses in TUM format (timestamp tx ty tz qx qy qz qw), for evo
    RUN/cameras.json           training cameras at mid-exposure, 3DGS/SIBR layout
    RUN/point_cloud.splat      the Gaussians for web splat viewers (antimatter15 layout, the PLY's colours)
    RUN/point_cloud/iteration_N/point_cloud.ply   INRIA's layout: the same file (a hard link), N = the steps run
    RUN/cfg_args               INRIA's saved arguments (one line, a Python ``Namespace(...)``): sh_degree 3,
                               source_path and model_path = RUN, white_background, eval
    RUN/deblurred/NAME.png     every training frame rendered sharp at mid-exposure (16-bit, round(65535 v))

Every image and exported colour is in the capture's own recorded domain: the run's camera response
applied once, no other curve (``ebad.export``'s docstring); ``load_run`` inverts the response on the
PLY's colours to get the model's irradiance colours back.
    RUN/metrics.json           RunMetrics; written LAST: its "complete" says whether the run finished
    RUN/.lock                  while a process writes the run: its pid and host

Every file is written to a temporary name and renamed into place, so a crash never leaves a
half-written file under a final name; ``metrics.json`` is written after every other file, so a
folder without it (or with ``"complete": false``) is an unfinished run, which ``load_run``
refuses with the command that resumes it.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import Tensor, nn

from scenes._atomic import atomic_path, write_text_atomic
from scenes.capture import file_in
from scenes.jsonio import read_json_object

from .config import Config, load_config, save_config
from .errors import UserError
from .export import from_recorded_params, to_recorded_params, write_exports
from .io import PLY_SH_DEGREE, plot_trajectories, read_ply, write_ply, write_png16, write_trajectories
from .response import RESPONSES, Response
from .run import Run, RunMetrics
from .trajectory import TRAJECTORIES, ExposureTrajectories

__all__ = [
    "write_run",
    "load_run",
    "json_safe",
    "write_text_atomic",
    "RunLock",
    "check_out_dir",
    "resume_config",
    "write_inria_layout",
]

LOCK_NAME = ".lock"
BLANK_LOCK_SECONDS = 5.0  # an empty lock file older than this names no live writer
INRIA_PLY_DIR = "point_cloud"  # INRIA's RUN/point_cloud/iteration_N/point_cloud.ply
CFG_ARGS = "cfg_args"


def json_safe(x):
    """Numbers, lists and dicts only (numpy scalars and arrays, dataclasses converted)."""
    import dataclasses

    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return json_safe(dataclasses.asdict(x))
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def check_out_dir(out: Path) -> None:
    """``out`` can be a run folder: not an existing file, and writable."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a folder")
    probe = out if out.exists() else next((p for p in out.parents if p.exists()), Path("."))
    if not os.access(probe, os.W_OK):
        raise UserError(f"--out {out}: {probe} is not writable")


def resume_config(out: Path) -> Config | None:
    """The settings of the run ``--resume`` continues in ``out`` (its ``config.json``); None when ``out``
    holds no run yet (no checkpoint, no metrics). Checked before anything of the run is touched.

    Raises:
        UserError: ``out`` holds a run (a checkpoint or metrics.json) whose config.json is missing.
        ConfigError: config.json is not valid JSON or not a config of this version (names the file).
    """
    cfg_path = out / "config.json"
    if cfg_path.is_file():
        return load_config(cfg_path)
    held = [n for n in ("checkpoints/last.pt", "metrics.json") if (out / n).exists()]
    if held or cfg_path.exists():
        raise UserError(
            f"--resume: {cfg_path} is missing or not a file, so the settings of the run in {out} (it holds "
            f"{', '.join(held) or 'config.json'}) are unknown; restore it, or start a new run in another --out"
        )
    return None


class RunLock:
    """An advisory lock on a run folder: ``RUN/.lock`` holds the pid and host of the writer.

    A second process is refused with a message naming the holder; a lock left by a process of
    this host that no longer exists (killed, even by SIGKILL) is taken over, with a message.

    Not filelock: its ``FileLock`` (flock) records no holder to name, and a waiting process
    truncates its file; its ``SoftFileLock`` records and reclaims holders as this does only
    since filelock 3.22, in its own format, and filelock is not a dependency of ours (only of
    torch's, at any version). This is the same O_EXCL marker in a few lines."""

    def __init__(self, folder: Path, say=print):
        self.path = Path(folder) / LOCK_NAME
        self.say = say
        self.held = False

    def _holder(self) -> tuple[int, str] | None:
        try:
            pid, host = self.path.read_text().split()[:2]
            return int(pid), host
        except (OSError, ValueError):
            return None

    def _blank_and_old(self) -> bool:
        """The lock file holds no pid/host and was made over ``BLANK_LOCK_SECONDS`` ago (a writer that
        died between creating and writing it, or could not write it: a full disk)."""
        import time

        try:
            return not self.path.read_text().strip() and time.time() - self.path.stat().st_mtime > BLANK_LOCK_SECONDS
        except OSError:
            return False

    def acquire(self) -> RunLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        me = f"{os.getpid()} {socket.gethostname()}\n"
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None and self._blank_and_old():
                    self.say(
                        f"ebad: taking over the lock of {self.path.parent}: it names no holder "
                        "(left by a writer that failed)"
                    )
                    self.path.unlink(missing_ok=True)
                    continue
                if holder is not None and holder[1] == socket.gethostname() and not _alive(holder[0]):
                    self.say(
                        f"ebad: taking over the lock of {self.path.parent} left by process {holder[0]}, "
                        "which no longer runs"
                    )
                    self.path.unlink(missing_ok=True)
                    continue
                who = f"process {holder[0]} on {holder[1]}" if holder else "another process"
                raise UserError(
                    f"{self.path.parent} is in use by {who} (lock file {self.path}); wait for it to "
                    "finish or choose another --out"
                ) from None
            try:
                with os.fdopen(fd, "w") as fh:
                    fh.write(me)
            except OSError as exc:  # a full disk: leave no lock that names nobody
                self.path.unlink(missing_ok=True)
                raise UserError(f"cannot write the lock file {self.path}: {exc.strerror or exc}") from None
            self.held = True
            return self
        raise UserError(f"could not lock {self.path.parent} (lock file {self.path})")

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc) -> Literal[False]:
        self.release()
        return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def write_run(run: Run, out: str | Path, gt_trajectories: np.ndarray | None = None) -> Path:
    """Write every file of the run folder except the checkpoint (written while training);
    ``config.json`` only when the run start did not already write it, ``metrics.json`` last."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "config.json").exists():
        save_config(run.config, out / "config.json")
    write_text_atomic(out / "history.json", json.dumps(json_safe([h.to_dict() for h in run.history])) + "\n")
    recorded = to_recorded_params(run.params, run.response)  # the colours the PLY and the .splat show
    with atomic_path(out / "point_cloud.ply") as tmp:
        write_ply(tmp, recorded)
    model = {
        "K": run.K.tolist(),
        "width": run.width,
        "height": run.height,
        "names": run.names,
        "exposures": run.exposures.tolist(),
        "views": run.V.tolist(),
        "kind": run.trajectories.kind,
        "anchored": run.trajectories.anchored,
        "scale": run.trajectories.scale,
        "c2w_mid": run.trajectories.c2w_mid.tolist(),
        "knots": run.trajectories.knots.detach().tolist(),
        "moving": run.trajectories.moving.tolist(),
        "channels": run.channels,
        "pose_source": run.pose_source,
        "test_c2w": {k: np.asarray(v).tolist() for k, v in run.test_c2w.items()},
        "response": {"kind": run.response.kind, "raw": run.response.raw.detach().tolist()},
    }
    write_text_atomic(out / "model.json", json.dumps(model) + "\n")
    poses, u = run.exposure_poses()
    with atomic_path(out / "trajectories.json") as tmp:
        write_trajectories(tmp, run.names, run.exposures, poses, u)
    with atomic_path(out / "trajectories.png") as tmp:
        plot_trajectories(tmp, poses, gt_trajectories)
    write_exports(run, out, recorded)  # cameras.json, point_cloud.splat, trajectories_tum.txt
    write_inria_layout(out, run.step, white_background=run.config.model.background >= 0.5, eval=bool(run.test_c2w))
    for name, img in zip(run.names, run.deblurred_frames()):
        write_png16(file_in(out / "deblurred", name, ".png"), img)  # atomic itself (scenes.images, scenes._atomic)
    metrics = json_safe(run.metrics.to_dict() if run.metrics is not None else {"complete": False})
    write_text_atomic(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return out


def write_inria_layout(out: Path, iteration: int, white_background: bool = False, eval: bool = False) -> list[Path]:
    """What INRIA's tools open beside ``cameras.json``: ``point_cloud/iteration_N/point_cloud.ply``
    (a hard link to ``RUN/point_cloud.ply``, a copy where links fail) and ``cfg_args``.

    Their loaders: ``searchForMaxIteration`` (``scene/__init__.py``, utils) takes the largest
    ``int(name.split("_")[-1])`` over every entry of ``point_cloud/``, so that folder holds only
    ``iteration_N`` (older ones are removed); N >= 1 since ``Scene`` reads iteration 0 as "none".
    ``get_combined_args`` (``arguments/__init__.py``) evaluates ``cfg_args`` as a ``Namespace``;
    the SIBR viewer reads its first line's ``source_path='...'``, ``sh_degree=`` and
    ``white_background=``, and loads cameras.json from the model folder. ``sh_degree`` is
    ``PLY_SH_DEGREE`` (3): the PLY always holds 45 ``f_rest_*`` (zero above the model's own degree),
    which ``GaussianModel.load_ply`` checks against ``3 (sh + 1)^2 - 3``.
    """
    import argparse
    import shutil

    out = Path(out)
    n = max(int(iteration), 1)
    folder = out / INRIA_PLY_DIR
    folder.mkdir(exist_ok=True)
    for old in folder.iterdir():
        if old.name.startswith("iteration_") and old.name != f"iteration_{n}":
            shutil.rmtree(old, ignore_errors=True)
    dest = folder / f"iteration_{n}" / "point_cloud.ply"
    dest.parent.mkdir(exist_ok=True)
    with atomic_path(dest) as tmp:
        tmp.unlink()  # atomic_path made it: os.link needs the name free
        try:
            os.link(out / "point_cloud.ply", tmp)
        except OSError:  # a file system without hard links
            shutil.copyfile(out / "point_cloud.ply", tmp)
    root = str(out.resolve())
    args = argparse.Namespace(
        sh_degree=PLY_SH_DEGREE,
        source_path=root,
        model_path=root,
        images="images",
        depths="",
        resolution=-1,
        white_background=bool(white_background),
        train_test_exp=False,
        data_device="cuda",
        eval=bool(eval),
    )
    write_text_atomic(out / CFG_ARGS, repr(args))
    return [dest, out / CFG_ARGS]


def _complete(metrics_path: Path) -> bool:
    """The ``complete`` field of a run's ``metrics.json`` as written (only JSON ``true`` is a finished run)."""
    doc = read_json_object(metrics_path, UserError)
    complete = doc.get("complete", False)
    if not isinstance(complete, bool):
        raise UserError(f"{metrics_path}: field 'complete' must be true or false, got {json.dumps(complete)}")
    return complete


MAX_SIDE = 1 << 16  # largest image side a run folder may state
MAX_VIEWS = 1024  # largest number of virtual views per exposure a run folder may state


class _ModelError(Exception):
    """A field of model.json that cannot be a run's (the message names it)."""


def _array(
    doc: dict, key: str, shape: tuple[int | None, ...] | None, dtype: type = float, field: str | None = None
) -> np.ndarray:
    """``doc[key]`` as a finite array of ``shape`` (None: any length; ``shape`` None: any shape)."""
    key_name = field or key
    try:
        a: np.ndarray = np.asarray(doc[key], dtype=dtype)
    except (TypeError, ValueError, OverflowError):
        raise _ModelError(f"field {key_name!r} must be an array of numbers of shape {shape}") from None
    if shape is not None and (a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape))):
        raise _ModelError(f"field {key_name!r} must have shape {shape}, got {a.shape}")
    if dtype is float and not np.isfinite(a).all():
        raise _ModelError(f"field {key_name!r} has a non-finite value")
    return a


def _int(doc: dict, key: str, lo: int, hi: int) -> int:
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise _ModelError(f"field {key!r} must be an integer in [{lo}, {hi}], got {json.dumps(v)[:40]}")
    return v


def _check_model(m: object) -> dict:
    """model.json's document, every field the loader reads checked for type, shape and range."""
    if not isinstance(m, dict):
        raise _ModelError(f"must be a JSON object, got {type(m).__name__}")
    need = ["K", "width", "height", "names", "exposures", "views", "kind", "anchored", "scale", "c2w_mid", "knots"]
    missing = [k for k in need + ["moving", "channels", "pose_source", "test_c2w", "response"] if k not in m]
    if missing:
        raise _ModelError(f"missing field(s) {missing}")
    K = _array(m, "K", (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise _ModelError("field 'K' must have positive focal lengths")
    _int(m, "width", 1, MAX_SIDE), _int(m, "height", 1, MAX_SIDE)
    names = m["names"]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise _ModelError("field 'names' must be a non-empty list of frame names")
    F = len(names)
    _array(m, "exposures", (F, 2))
    views = _array(m, "views", (F,))
    if (views != np.round(views)).any() or views.min() < 1 or views.max() > MAX_VIEWS:
        raise _ModelError(f"field 'views' must hold integers in [1, {MAX_VIEWS}], one per frame")
    _array(m, "c2w_mid", (F, 4, 4))
    _array(m, "moving", (F,), bool)
    _array(m, "knots", None)  # its size is checked against the trajectory kind when loaded
    if m["kind"] not in TRAJECTORIES:
        raise _ModelError(f"field 'kind' must be one of {list(TRAJECTORIES)}, got {json.dumps(m['kind'])[:40]}")
    if not isinstance(m["anchored"], bool):
        raise _ModelError("field 'anchored' must be true or false")
    scale = m["scale"]
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (np.isfinite(scale) and scale > 0):
        raise _ModelError("field 'scale' must be a positive number")
    if m["channels"] not in (1, 3) or isinstance(m["channels"], bool):
        raise _ModelError(f"field 'channels' must be 1 or 3, got {json.dumps(m['channels'])[:40]}")
    if not isinstance(m["pose_source"], str):
        raise _ModelError("field 'pose_source' must be a string")
    if not isinstance(m["test_c2w"], dict):
        raise _ModelError("field 'test_c2w' must be an object of 4x4 poses by test-view name")
    for k in m["test_c2w"]:
        _array(m["test_c2w"], k, (4, 4), field=f"test_c2w.{k}")
    r = m["response"]
    if not isinstance(r, dict) or r.get("kind") not in RESPONSES:
        raise _ModelError(f"field 'response' must be {{'kind': one of {list(RESPONSES)}, 'raw': [3 numbers]}}")
    _array(r, "raw", (3,), field="response.raw")
    return m


def _read_model(path: Path) -> dict:
    doc = read_json_object(path, UserError)
    try:
        return _check_model(doc)
    except _ModelError as exc:
        raise UserError(f"{path}: {exc}; the run folder is damaged (rerun 'ebad reconstruct')") from None


def _read_metrics(path: Path) -> RunMetrics:
    doc = read_json_object(path, UserError)
    try:
        metrics = RunMetrics.from_dict(doc)
    except (TypeError, KeyError, ValueError, AttributeError) as exc:
        raise UserError(f"{path}: not the metrics of a run of this version ({str(exc)[:120]})") from None
    steps = metrics.steps
    if isinstance(steps, bool) or not isinstance(steps, int) or not 0 <= steps < 1 << 40:
        raise UserError(f"{path}: field 'steps' must be a non-negative integer, got {json.dumps(steps)[:40]}")
    return metrics


def load_run(path: str | Path) -> Run:
    """A ``Run`` from a finished run folder (for rendering and evaluation)."""
    path = Path(path)
    if not path.is_dir():
        raise UserError(f"{path} is not a run folder (run 'ebad reconstruct CAPTURE --out {path}' first)")
    metrics_path = path / "metrics.json"
    if not metrics_path.exists() or _complete(metrics_path) is not True:
        hint = (
            f"resume it with 'ebad reconstruct CAPTURE --out {path} --resume'"
            if (path / "checkpoints" / "last.pt").exists()
            else f"run 'ebad reconstruct CAPTURE --out {path}'"
        )
        raise UserError(f"{path} holds an unfinished run: {hint}")
    for name in ("config.json", "model.json", "point_cloud.ply"):
        if not (path / name).exists():
            raise UserError(f"{path} is not a complete run folder: {name} is missing")
    cfg = load_config(path / "config.json")
    model = _read_model(path / "model.json")
    metrics = _read_metrics(metrics_path)
    try:
        ply = read_ply(path / "point_cloud.ply")
    except (ValueError, MemoryError, EOFError) as exc:  # the message names the file
        raise UserError(f"{path / 'point_cloud.ply'}: cannot be read ({str(exc)[:160]})") from None
    bad = [k for k, v in ply.items() if not torch.isfinite(v).all()]
    if bad:
        raise UserError(f"{path / 'point_cloud.ply'}: non-finite values in {bad}; the run folder is damaged")
    response = Response(model["response"]["kind"])
    with torch.no_grad():
        response.raw.copy_(torch.tensor(model["response"]["raw"]))
    if ply["colors"].shape[1] != model["channels"]:
        ply["colors"] = ply["colors"][:, : model["channels"]].contiguous()
    ply = from_recorded_params(ply, response)  # the PLY holds recorded colours, the model irradiance
    params: dict[str, Tensor] = {k: nn.Parameter(v) for k, v in ply.items()}
    traj = ExposureTrajectories(
        torch.tensor(model["c2w_mid"]),
        model["kind"],
        torch.tensor(model["moving"]),
        scale=model["scale"],
        anchored=model["anchored"],
    )
    knots = torch.tensor(model["knots"], dtype=traj.knots.dtype)
    if knots.numel() != traj.knots.numel():
        raise UserError(
            f"{path / 'model.json'}: field 'knots' holds {knots.numel()} numbers where a {model['kind']} trajectory "
            f"of {len(model['names'])} frames has {traj.knots.numel()}; the run folder is damaged"
        )
    with torch.no_grad():
        traj.knots.data = knots.reshape(traj.knots.shape)
    return Run(
        params=params,
        trajectories=traj,
        config=cfg,
        K=np.array(model["K"]),
        width=model["width"],
        height=model["height"],
        names=model["names"],
        exposures=np.array(model["exposures"]),
        V=np.array(model["views"]),
        pose_source=model["pose_source"],
        test_c2w={k: np.array(v) for k, v in model["test_c2w"].items()},
        response=response,
        metrics=metrics,
        step=metrics.steps,
    )
