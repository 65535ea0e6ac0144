"""Where ebad reads a JSON object (capture.json, config.json, model.json, metrics.json, camera paths): one reader,
and a missing, oversized, binary, deeply nested or non-object file is one error naming the file, no traceback."""

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


# --- one reader (scenes.jsonio.read_json_object) for every JSON object ebad reads ------------------------------

CASES = {
    "missing": (None, "file not found"),
    "a list": (b"[1, 2]", "must be a JSON object"),
    "a number": (b"5", "must be a JSON object"),
    "binary": (BINARY, "not valid JSON"),
    "nested": (NESTED.encode(), "not valid JSON"),
    "over the size cap": (b'{"a": "' + b"x" * 64 + b'"}', "too large"),
}


def _readers():
    from ebad.cli.video import read_camera_path
    from ebad.errors import UserError
    from ebad.runfolder import _read_metrics, _read_model

    return {
        "capture": (read_json_object, CaptureError),
        "config": (load_config, ConfigError),
        "model": (_read_model, UserError),
        "metrics": (_read_metrics, UserError),
        "camera path": (read_camera_path, UserError),
    }


@pytest.mark.parametrize("reader", ["capture", "config", "model", "metrics", "camera path"])
@pytest.mark.parametrize("case", list(CASES))
def test_every_json_reader_gives_one_line_naming_the_file(tmp_path, monkeypatch, reader, case):
    import scenes.jsonio

    if case == "over the size cap":
        monkeypatch.setattr(scenes.jsonio, "MAX_JSON_BYTES", 64)  # the cap, small here
    read, error = _readers()[reader]
    content, match = CASES[case]
    path = tmp_path / "doc.json"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(error, match=rf"doc\.json: {match}") as info:
        read(path)
    assert "\n" not in str(info.value)
    assert type(info.value) is error  # the caller's own class, not a CaptureError (nor a bare OSError)


def test_the_camera_path_message_says_what_the_object_is(tmp_path):
    from ebad.cli.video import read_camera_path
    from ebad.errors import UserError

    (tmp_path / "p.json").write_text("[]")
    with pytest.raises(UserError, match=r"p\.json: must be a JSON object \(a nerfstudio camera path\), got list"):
        read_camera_path(tmp_path / "p.json")
