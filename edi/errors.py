"""The project's exception hierarchy, at its root.

Every mistake a user can make (a malformed file, a bad field, an argument out of range,
structure from motion that cannot work on the given frames) raises a subclass of
``EbadError``; its message names the file, field or argument. The command line catches
``EbadError`` (and ``OSError``, with the path) and prints one line; anything else is a bug
and shows its traceback.

It lives in ``edi`` because ``edi`` is the package every other one may import (DESIGN.md:
``scenes`` and ``ebad`` use ``edi``; ``edi`` uses none of them). ``ebad.errors`` and
``scenes.errors`` re-export it.

The subclasses also derive from ``ValueError`` where they did before, so code that caught
``ValueError`` from the Python API keeps working.
"""

from __future__ import annotations

__all__ = ["EbadError", "EventError", "InputError"]


class EbadError(Exception):
    """Base of every user-facing error of ebad, edi, scenes and splat_cpu's callers."""


class EventError(EbadError, ValueError):
    """An event array or event file is malformed; the message names the field and the first bad index."""


class InputError(EbadError, ValueError):
    """An argument of a public edi function that cannot work (shape, range, unit, exposure);
    the message names the argument and what was found."""


class CorruptFileError(EventError):
    """An event file or recording that cannot be decoded (truncated, corrupt, not that format)."""
