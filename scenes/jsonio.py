"""The one reader of the JSON documents of the capture layouts (capture.json, gt.json, transforms)."""

from __future__ import annotations

import json
from pathlib import Path

from .errors import CaptureError

__all__ = ["read_json_object"]


def read_json_object(path: Path) -> dict:
    """A JSON file whose top level is an object; CaptureError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(str(path), None, "file not found")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CaptureError(str(path), None, f"not valid JSON ({str(exc)[:120]})") from None
    except RecursionError:  # nested deeper than Python's parser follows
        raise CaptureError(str(path), None, "not valid JSON (nested too deeply)") from None
    if not isinstance(doc, dict):
        raise CaptureError(str(path), None, "top level must be an object")
    return doc
