"""Deeply nested or binary JSON where ebad reads a JSON file: one error naming the file, no traceback."""

from __future__ import annotations

import pytest

from ebad.config import ConfigError, load_config
from scenes.errors import CaptureError
from scenes.jsonio import read_json_object

NESTED = "[" * 200000 + "]" * 200000
BINARY = b"\xff\xfe\x00garbage\x80\x81"


@pytest.mark.parametrize("content", [NESTED.encode(), BINARY], ids=["nested", "binary"])
def test_capture_json(tmp_path, content):
    (tmp_path / "capture.json").write_bytes(content)
    with pytest.raises(CaptureError, match="capture.json.*not valid JSON"):
        read_json_object(tmp_path / "capture.json")


@pytest.mark.parametrize("content", [NESTED.encode(), BINARY], ids=["nested", "binary"])
def test_config_json(tmp_path, content):
    (tmp_path / "config.json").write_bytes(content)
    with pytest.raises(ConfigError, match="config.json: not valid JSON"):
        load_config(tmp_path / "config.json")
