"""The project's exceptions, as ``ebad`` users see them.

``EbadError`` is the one base (defined in ``edi.errors``, the package every other imports);
``ConfigError`` is a bad option or config field; ``UserError`` is any other user mistake
the reconstruction finds (a capture that cannot work, a run folder in the wrong state).
Capture, event and SfM errors come from ``scenes.CaptureError``, ``edi.EventError`` and
``scenes.colmap.SfMError``, all subclasses of ``EbadError``.
"""

from __future__ import annotations

from edi.errors import EbadError, EventError

__all__ = ["EbadError", "EventError", "UserError", "ConfigError"]


class UserError(EbadError, ValueError):
    """Bad input from a user; the message names the file, field or argument."""


class ConfigError(UserError):
    """A configuration field or command-line option that cannot work; the message names it."""
