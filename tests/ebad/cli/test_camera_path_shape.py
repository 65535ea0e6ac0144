"""A camera-path JSON of the wrong shape is one line naming the file and field (no traceback, no huge
allocation)."""

from __future__ import annotations

import json

import pytest

from ebad.cli.video import MAX_RENDER_SIDE, camera_path_fps, read_camera_path
from ebad.errors import UserError


@pytest.mark.parametrize(
    "doc,match",
    [
        (5, "must be a JSON object"),
        ("a string", "must be a JSON object"),
        ([1, 2], "must be a JSON object"),
        ({"render_width": "wide", "render_height": 48, "camera_path": [{}]}, "'render_width' must be an integer"),
        ({"render_width": 10**6, "render_height": 10**6, "camera_path": [{}]}, "'render_width' must be an integer"),
        ({"render_width": 64, "render_height": 0, "camera_path": [{}]}, "'render_height' must be an integer"),
        ({"render_width": 64, "render_height": 48, "camera_path": "x"}, "'camera_path' must be a non-empty list"),
    ],
)
def test_wrong_shapes_are_named(tmp_path, doc, match):
    p = tmp_path / "path.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(UserError, match=match) as info:
        read_camera_path(p)
    assert str(p) in str(info.value)
    if not isinstance(doc, dict):
        with pytest.raises(UserError, match="must be a JSON object"):
            camera_path_fps(p)


def test_binary_and_nested_files_are_named(tmp_path):
    for content in (b"\xff\xfe\x00\x81", b"[" * 100000 + b"]" * 100000):
        p = tmp_path / "path.json"
        p.write_bytes(content)
        with pytest.raises(UserError, match="path.json"):
            read_camera_path(p)
    assert MAX_RENDER_SIDE == 16384
