"""Lines about the phases before the first step (what each does, how far it is)."""

from __future__ import annotations

import logging
import sys
import time

__all__ = ["say", "Ticker", "progress_log"]

progress_log = logging.getLogger("ebad.progress")


def say(show: bool, msg: str) -> None:
    """A line about a phase before the first step (what it does, how far it is): logged at INFO on
    ``ebad.progress``; with ``show`` (``train.progress``) printed to stderr as well when no handler
    shows that log."""
    if progress_log.isEnabledFor(logging.INFO) and progress_log.hasHandlers():
        progress_log.info(msg)
    elif show:
        print(f"ebad: {msg}", file=sys.stderr, flush=True)


class Ticker:
    """``say`` for a loop of ``total`` items: its first and last item (once each), and one in between at
    most every ``every`` seconds, with the seconds so far. It may be called again with the same count."""

    def __init__(self, show: bool, what: str, total: int, every: float = 5.0):
        self.show, self.what, self.total, self.every = show, what, total, every
        self.t0 = self.last = time.perf_counter()
        self.shown = -1  # the count last said

    def __call__(self, done: int) -> None:
        now = time.perf_counter()
        if (done in (1, self.total) and done != self.shown) or now - self.last >= self.every:
            self.last, self.shown = now, done
            say(self.show, f"{self.what}: {done}/{self.total} ({now - self.t0:.1f} s)")
