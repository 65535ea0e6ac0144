"""The one exception every capture reader and writer raises for bad input."""

from __future__ import annotations

from edi.errors import EbadError

__all__ = ["CaptureError", "EbadError"]


class CaptureError(EbadError, ValueError):
    """A capture on disk or in memory is malformed.

    The message names the file and the field (``capture.json: frames[3].t_end: missing``);
    both are also kept as attributes for programs.
    """

    def __init__(self, file: str | None, field: str | None, problem: str):
        self.file = None if file is None else str(file)
        self.field = field
        self.problem = problem
        where = ": ".join(s for s in (self.file, None if field is None else f"field '{field}'") if s)
        super().__init__(f"{where}: {problem}" if where else problem)
