"""The one reader of JSON documents whose top level is an object: the capture layouts' (capture.json,
gt.json, transforms) and, through its ``error`` argument, ebad's (config.json, model.json,
metrics.json, camera paths)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from .errors import CaptureError

__all__ = ["MAX_JSON_BYTES", "read_json_object"]

#: the largest JSON document read (a run's metrics.json with its history is a few MB)
MAX_JSON_BYTES = 256 << 20


def read_json_object(
    path: str | Path,
    error: Callable[[str], Exception] | None = None,
    what: str = "",
) -> dict:
    """A JSON file whose top level is an object. Anything else (a missing or unreadable file, one
    over ``MAX_JSON_BYTES``, binary or invalid JSON, nesting deeper than the parser follows, another
    top level) raises ``error("{file}: {problem}")`` (e.g. ``ebad.errors.UserError``), by default
    ``CaptureError(file, None, problem)``: one line naming the file. ``what`` says in the message
    what the object is, e.g. ``"a nerfstudio camera path"``."""
    path = Path(path)
    file = str(path)

    def fail(problem: str) -> Exception:
        return CaptureError(file, None, problem) if error is None else error(f"{file}: {problem}")

    if not path.is_file():
        raise fail("file not found")
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise fail(f"too large for a JSON document ({size} bytes; at most {MAX_JSON_BYTES})")
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise fail(f"cannot be read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise fail(f"not valid JSON ({str(exc)[:120]})") from None
    except RecursionError:  # nested deeper than Python's parser follows
        raise fail("not valid JSON (nested too deeply)") from None
    if not isinstance(doc, dict):
        raise fail(f"must be a JSON object{f' ({what})' if what else ''}, got {type(doc).__name__}")
    return doc
