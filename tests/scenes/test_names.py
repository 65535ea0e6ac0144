"""Frame and test-view names become output file names: only plain file names are accepted (issue 32)."""

import json

import pytest

from scenes import CaptureError, load, save
from scenes.capture import check_file_name, file_in

from .test_format import _capture

BAD_NAMES = ["../../x/evil_0", "/tmp/evil_0", "a/b", "a\\b", "..", ".", "", "evil\0.png"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_check_file_name_refuses_anything_but_a_plain_name(name):
    with pytest.raises(CaptureError) as e:
        check_file_name(name, "capture.json", "frames[0].name")
    assert e.value.field == "frames[0].name" and e.value.file == "capture.json"


@pytest.mark.parametrize("name", ["f0", "frame_0001", "a.b", "..x", "test_00-1"])
def test_check_file_name_keeps_plain_names(name):
    assert check_file_name(name, None, "name") == name


@pytest.mark.parametrize("name", BAD_NAMES)
def test_file_in_never_leaves_its_folder(tmp_path, name):
    with pytest.raises(CaptureError):
        file_in(tmp_path / "out", name, ".png")
    assert file_in(tmp_path / "out", "f0", ".png") == tmp_path / "out" / "f0.png"


@pytest.fixture
def saved(tmp_path):
    save(_capture(), tmp_path / "c")
    root = tmp_path / "c"
    return root, json.loads((root / "capture.json").read_text())


@pytest.mark.parametrize("name", ["../../x/evil_0", "/tmp/evil_0", "..", "a\0b"])
def test_capture_json_frame_name_escaping_the_folder_is_refused(saved, name):
    root, doc = saved
    doc["frames"][1]["name"] = name
    (root / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError) as e:
        load(root)
    assert e.value.field == "frames[1].name" and str(root / "capture.json") in str(e.value)
    assert len(str(e.value).splitlines()) == 1


def test_capture_json_duplicate_evil_names_are_refused_too(saved):
    root, doc = saved
    for fr in doc["frames"]:
        fr["name"] = "../evil"  # duplicates used to be renamed 0000, 0001, ... before any check
    (root / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError) as e:
        load(root)
    assert e.value.field == "frames[0].name"


@pytest.mark.parametrize("name", ["../evil_test", "/abs/evil", ""])
def test_capture_json_test_view_name_escaping_the_folder_is_refused(saved, name):
    root, doc = saved
    doc["test_views"][0]["name"] = name
    (root / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError) as e:
        load(root)
    assert e.value.field == "test_views[0].name" and "capture.json" in str(e.value)


def test_validate_refuses_names_of_an_in_memory_capture():
    cap = _capture()
    cap.names[2] = "../../evil"
    with pytest.raises(CaptureError) as e:
        cap.validate("mem")
    assert e.value.field == "frames[2].name"
    cap = _capture()
    cap.test_views[1].name = "x/y"
    with pytest.raises(CaptureError) as e:
        cap.validate("mem")
    assert e.value.field == "test_views[1].name"
