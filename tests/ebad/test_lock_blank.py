"""A lock file that names no holder (a writer that died, or could not write it on a full disk) does not
refuse every later run; a lock that cannot be written leaves nothing behind."""

from __future__ import annotations

import errno
import os
import time

import pytest

from ebad.errors import UserError
from ebad.runfolder import BLANK_LOCK_SECONDS, RunLock


def test_an_old_empty_lock_is_taken_over_with_a_message(tmp_path):
    lock = tmp_path / ".lock"
    lock.write_text("")
    old = time.time() - BLANK_LOCK_SECONDS - 1
    os.utime(lock, (old, old))
    said: list[str] = []
    with RunLock(tmp_path, say=said.append):
        assert lock.read_text().split()[0] == str(os.getpid())
    assert said and "names no holder" in said[0]
    assert not lock.exists()


def test_a_fresh_empty_lock_is_respected(tmp_path):
    (tmp_path / ".lock").write_text("")  # a writer between creating and writing it
    with pytest.raises(UserError, match="in use by another process"):
        RunLock(tmp_path).acquire()


def test_a_lock_that_cannot_be_written_is_removed(tmp_path, monkeypatch):
    real = os.fdopen

    class Full:
        def __init__(self, fd, *a, **k):
            self.f = real(fd, *a, **k)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, s):
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fdopen", Full)
    with pytest.raises(UserError, match="cannot write the lock file.*No space left"):
        RunLock(tmp_path).acquire()
    assert not (tmp_path / ".lock").exists()
