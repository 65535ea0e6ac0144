"""User-facing messages (issue 30): ``ebad deblur``'s unreliable-c warning is a short first line with
the reasons wrapped below (it was one 834-character line), and errors print no 16-digit floats."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

LONG_FLOAT = re.compile(r"\d\.\d{10,}")


def test_unreliable_c_warning_is_a_short_line_then_the_reasons(capsys):
    from ebad.cli.deblur import _say_unreliable

    why = "c = 0.03001 is at an end of the bracket (0.03, 1.5): the energy has no interior minimum; " * 9
    rep = SimpleNamespace(reliable=False, c=SimpleNamespace(pos=0.0300123, neg=0.0300123), message="estimate_c: " + why)
    _say_unreliable(rep, "keyboard")
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "ebad deblur: warning: keyboard: estimated c 0.03001 is unreliable; give --c (DAVIS: 0.1 to 0.5) "
        "or more frames; why:"
    )
    assert len(lines) > 3 and all(line.startswith("  ") and len(line) <= 100 for line in lines[1:])
    assert " ".join(line.strip() for line in lines[1:]) == why.strip()  # every word of the reasons kept
    rep.c = SimpleNamespace(pos=0.2, neg=0.25)
    _say_unreliable(rep, "f")
    assert "estimated c_pos 0.2, c_neg 0.25 is unreliable" in capsys.readouterr().out
    rep.reliable = True
    _say_unreliable(rep, "f")
    assert capsys.readouterr().out == ""


@pytest.fixture(scope="module")
def capture():
    import scenes

    return scenes.make_scene("boxes", "tiny", n_frames=3, n_test=0).capture


def test_exposure_order_error_prints_short_floats(capture):
    import dataclasses

    from scenes.errors import CaptureError

    e = capture.exposures.copy()
    e[1] = (0.1 + 0.2, 0.3)  # 0.30000000000000004 then 0.3: t_end before t_start by 5.6e-17 s
    with pytest.raises(CaptureError) as info:
        dataclasses.replace(capture, exposures=e).validate("cap")
    msg = str(info.value)
    assert "exposures[1]" in msg and "t_end 0.300000 s is 5.55e-17 s before t_start 0.300000 s" in msg
    assert not LONG_FLOAT.search(msg), msg


def test_a_pose_with_a_bad_last_row_prints_short_floats():
    from scenes.capture import check_rigid, nearest_rigid
    from scenes.errors import CaptureError

    m = np.eye(4)
    m[3] = [0.1 + 0.2, 0.0, 0.0, 1.0]
    for check in (check_rigid, nearest_rigid):
        with pytest.raises(CaptureError, match=r"got \[0\.3, 0, 0, 1\]") as info:
            check(m, "poses.json", "c2w")
        assert not LONG_FLOAT.search(str(info.value))


def test_capture_json_exposure_order_prints_short_floats(tmp_path, capture):
    import json

    import scenes
    from scenes.errors import CaptureError

    scenes.save(capture, tmp_path / "c")
    doc = json.loads((tmp_path / "c" / "capture.json").read_text())
    doc["frames"][2]["t_start"] = 0.1 + 0.2
    doc["frames"][2]["t_end"] = 0.3
    (tmp_path / "c" / "capture.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError, match=r"frames\[2\]\.t_end.*0\.300000 s is 5\.55e-17 s before") as info:
        scenes.load(tmp_path / "c")
    assert not LONG_FLOAT.search(str(info.value))
