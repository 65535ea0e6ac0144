"""Writing a file under a temporary name and renaming it into place: one helper for scenes and ebad.

``atomic_path(path)`` yields a unique temporary sibling of ``path`` (same folder, so the rename
is atomic on one file system; the same suffix, for writers that choose the format by it); the
block writes it, and on success it is renamed onto ``path``, on failure removed. A reader never
sees a half-written file under the final name, and two writers (processes or threads) never
share a temporary. ``write_text_atomic`` and ``write_bytes_atomic`` are the common cases.

Standard library only: ``ebad`` imports it without loading anything heavy.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_text_atomic", "write_bytes_atomic"]


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a unique temporary sibling of ``path`` (``.NAME.XXXX.tmp.SUFFIX``), renamed onto
    ``path`` when the block succeeds and removed when it raises. Creates ``path``'s folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """``Path(path).write_text(text)`` through ``atomic_path``; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """``Path(path).write_bytes(data)`` through ``atomic_path``; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)
