"""The ``ebad`` dispatcher: user mistakes are one line and exit 2; bugs are not disguised."""
from __future__ import annotations

import pytest

import ebad.cli.eval as eval_cmd
from ebad.cli import main
from edi.errors import EbadError


def test_user_mistake_prints_one_line_and_exits_2(tmp_path, capsys):
    rc = main(["eval", str(tmp_path / "no_run"), str(tmp_path / "no_capture")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("ebad eval: error: ") and len(err.strip().splitlines()) == 1
    assert "no_run" in err


def test_os_error_names_the_path(tmp_path, capsys, monkeypatch):
    def fail(args):
        raise PermissionError(13, "Permission denied", str(tmp_path / "locked"))

    monkeypatch.setattr(eval_cmd, "run", fail)
    assert main(["eval", "a", "b"]) == 2
    assert f"{tmp_path / 'locked'}: Permission denied" in capsys.readouterr().err


@pytest.mark.parametrize("exc", [ValueError("operands could not be broadcast together"), KeyError("x"),
                                 IndexError("index 3 is out of bounds")])
def test_internal_error_is_not_disguised(monkeypatch, exc):
    def fail(args):
        raise exc

    monkeypatch.setattr(eval_cmd, "run", fail)
    with pytest.raises(type(exc)):
        main(["eval", "a", "b"])


def test_every_project_error_is_an_ebad_error():
    import scenes
    import scenes.colmap
    from ebad.errors import ConfigError, UserError
    from edi import EventError

    for cls in (EventError, scenes.CaptureError, scenes.colmap.SfMError, UserError, ConfigError):
        assert issubclass(cls, EbadError), cls
