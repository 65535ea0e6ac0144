"""``ebad deblur`` names a recording's frames as ``scenes.convert`` does (issue 30: it wrote ``0000``
where the converted capture has ``00000``)."""

import numpy as np
import pytest

import edi
from ebad.cli import main


@pytest.fixture()
def fake_aedat4(tmp_path, monkeypatch):
    """An .aedat4 path whose reading (edi's and scenes' readers) gives a 3-frame moving texture."""
    import scenes.readers

    s = edi.moving_texture(num_frames=3, seed=0, c=0.2)
    rec = edi.AedatRecording(events=s.events, frames=np.asarray(s.frames, np.float32), exposures=s.exposures, t0=0)
    path = tmp_path / "rec.aedat4"
    path.write_bytes(b"#!AER-DAT4.0\r\n")
    monkeypatch.setattr(edi, "read_aedat4", lambda p: rec)
    monkeypatch.setattr(scenes.readers, "read_aedat4", lambda p: rec)
    return path


def test_deblur_names_a_recordings_frames_as_convert_does(tmp_path, fake_aedat4, capsys):
    import scenes.readers

    out = tmp_path / "o"
    assert main(["deblur", str(fake_aedat4), "--out", str(out), "--c", "0.2"]) == 0
    names = scenes.readers.load_aedat4(fake_aedat4).names  # what scenes.convert writes
    assert names == ["00000", "00001", "00002"]
    assert sorted(p.stem for p in (out / "sharp").iterdir()) == names
    assert sorted(p.stem for p in (out / "side_by_side").iterdir()) == names
