"""Shared preamble of the benchmarks: environment header, seeding, JSON output.

Run every benchmark as a module from the repository root, ``python -m benchmarks.NAME``,
so the project's packages (not a benchmark file) are found first on ``sys.path``.
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import random
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

import ebad.threads

__all__ = ["RESULTS", "commit", "environment", "seed_all", "write_json", "config_spec"]

# Every benchmark imports this module first, before torch: OpenMP's idle threads sleep (ebad.threads).
ebad.threads.configure()

#: Where every benchmark writes its JSON.
RESULTS = Path(__file__).resolve().parent / "results"


def commit() -> str | None:
    """The repository's HEAD commit, with "+dirty" when a tracked file differs from it (new
    results files do not count), or None outside a git checkout."""
    root = str(Path(__file__).resolve().parents[1])
    try:
        head = subprocess.run(
            ["git", "-C", root, "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if head.returncode != 0:
            return None
        status = subprocess.run(
            ["git", "-C", root, "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if status.returncode == 0 and status.stdout.strip() else "")


def environment() -> dict[str, Any]:
    """CPU count, library versions, platform, the code's commit and UTC date of this run."""
    import numba
    import scipy
    import torch

    return {
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "commit": commit(),
    }


def seed_all(seed: int) -> None:
    """Seed Python's, numpy's legacy and torch's global RNGs (code under test should take a seed)."""
    import torch

    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def write_json(name: str, obj: dict[str, Any]) -> Path:
    """Write ``obj`` with an ``environment`` entry to ``benchmarks/results/NAME.json``; returns the path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    payload = {"environment": environment(), **obj}
    tmp = path.with_suffix(f".json.tmp{os.getpid()}")
    tmp.write_text(json.dumps(payload, indent=2, default=_default) + "\n")
    tmp.replace(path)
    return path


def config_spec(spec: str):
    """A preset with overrides: ``"ebad"``, ``"ebad+train.coarse_scale=1+trajectory.num_views=3"``
    (values as JSON, else strings); the config's name is the spec."""
    from ebad.config import config_from_dict, config_to_dict, preset

    name, *overrides = spec.split("+")
    d = config_to_dict(preset(name))
    for item in overrides:
        key, _, value = item.partition("=")
        section, _, fld = key.partition(".")
        if section not in d or not isinstance(d[section], dict) or fld not in d[section]:
            raise SystemExit(f"config spec {spec!r}: unknown option {key!r}")
        try:
            d[section][fld] = json.loads(value)
        except json.JSONDecodeError:
            d[section][fld] = value
    cfg = config_from_dict(d)
    cfg.name = spec
    return cfg


def memory_mb() -> tuple[float | None, float | None]:
    """This process's resident set and its peak so far, MB (``VmRSS``, ``VmHWM`` of /proc/self/status;
    None where there is no /proc).

    Not ``getrusage``'s ``ru_maxrss``: Linux carries it over ``exec``, so a child started by a process
    that once held 6 GB (this benchmark's parent, simulating a 40-view capture) reports 6 GB before it
    allocates anything. ``VmHWM`` belongs to the process's own address space, which ``exec`` replaces."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None, None
    kb = {k: int(v.split()[0]) for k, v in (ln.split(":", 1) for ln in text.splitlines() if ln.startswith("Vm"))}
    return kb["VmRSS"] / 1024, kb["VmHWM"] / 1024


def peak_rss_mb() -> float:
    """This process's peak resident set so far, MB: ``VmHWM`` (see ``memory_mb``), or ``ru_maxrss``
    where there is no /proc."""
    import resource

    hwm = memory_mb()[1]
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def reset_peak() -> bool:
    """Start this process's ``VmHWM`` again from its current resident set (Linux: /proc/self/clear_refs 5)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True
