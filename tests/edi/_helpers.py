"""Shared by the edi tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Run before every ``run_python`` snippet: ``status("VmRSS")``, ``status("VmHWM")`` in kB
# (writing "5" to /proc/self/clear_refs resets VmHWM, the peak).
_STATUS = """
import re
def status(key):  # kB, from /proc/self/status
    return int(re.search(key + r":\\s+(\\d+)", open("/proc/self/status").read()).group(1))
"""


def run_python(code: str, *args: str) -> list[str]:
    """Run ``code`` in a fresh interpreter on this checkout (``python -c code args``); its stdout's
    whitespace-separated fields. A fresh process, so that its peak RSS (VmHWM) is its own; the
    snippet can read it with ``status(key)`` (``_STATUS``)."""
    r = subprocess.run(
        [sys.executable, "-c", _STATUS + code, *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.split()
