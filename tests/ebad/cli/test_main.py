"""The ``ebad`` dispatcher: user mistakes are one line and exit 2; bugs are not disguised."""

from __future__ import annotations

import dataclasses
import re

import pytest

import ebad.cli.eval as eval_cmd
from ebad.cli import UsageError, _commands, main, parse
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


@pytest.mark.parametrize(
    "exc",
    [ValueError("operands could not be broadcast together"), KeyError("x"), IndexError("index 3 is out of bounds")],
)
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


# --------------------------------------------------------------------------- one parser, one usage block

NAMES = [m.NAME for m in _commands()]


def test_every_module_is_a_subcommand():
    assert set(NAMES) == {"deblur", "demo", "eval", "reconstruct", "render", "synth", "video", "view"}


@pytest.mark.parametrize(
    "argv",
    [["--help"], *([n, "--help"] for n in NAMES), ["reconstruct", "--preset", "bad", "-h"]],
    ids=lambda a: " ".join(a),
)
def test_help_is_one_usage_block_and_exits_0(argv, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert out.count("usage:") == 1 and out.startswith(f"usage: ebad {argv[0] if argv[0] in NAMES else ''}".rstrip())
    assert err == ""


REQUIRED = {
    "deblur": ["INPUT", "--out"],
    "demo": [],
    "eval": ["RUN", "CAPTURE"],
    "reconstruct": ["CAPTURE", "--out"],
    "render": ["RUN", "--out"],
    "synth": ["NAME", "--out"],
    "video": ["RUN", "--out"],
    "view": ["RUN"],
}


@pytest.mark.parametrize("name", NAMES)
def test_required_options_show_as_required(name, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    assert main([name, "--help"]) == 0
    text = capsys.readouterr().out
    usage = re.sub(r"\[[^\]]*\]", "", text.splitlines()[0]).split()  # the usage line without [optional] parts
    assert all(p in usage for p in REQUIRED[name] if not p.startswith("--")), usage  # positionals
    for option in REQUIRED[name]:
        if option.startswith("--"):  # not [--option] in the usage line, and its help says required
            assert f"[{option}" not in text.splitlines()[0]
            entry = text[text.index(f"{option} ") :]
            assert "(required)" in entry[: entry.find("│ --", 1)], option
    mod = next(m for m in _commands() if m.NAME == name)
    assert len(REQUIRED[name]) == sum(
        f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        for f in dataclasses.fields(mod.Args)
    )


# --------------------------------------------------------------------------- mistakes on the command line


@pytest.mark.parametrize(
    "argv, expected",
    [
        (
            ["render", "RUN", "--out", "o", "--splt", "train"],
            "unrecognized argument(s): --splt (did you mean --split?)",
        ),
        (["reconstruct", "CAP", "--out", "o", "--trian.iters", "3"], "--trian.iters (did you mean --train.iters?)"),
        (["render", "RUN"], "missing required argument(s): --out"),
        (["eval", "RUN"], "missing required argument(s): CAPTURE"),
        (["render", "RUN", "--out", "o", "--bits", "12"], "--bits: invalid choice '12', choose one of 8, 16"),
        (["reconstruct", "CAP", "--out", "o", "--train.iters", "x"], "--train.iters: invalid literal for int()"),
        (["reconstruct", "CAP", "--out", "o", "--preset", "nope"], "unknown preset 'nope'"),
        (["frobnicate"], "unknown command frobnicate; choose one of deblur,"),
        ([], "choose a command: deblur,"),
    ],
)
def test_a_bad_command_line_is_one_line_and_exits_2(argv, expected, capsys):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert expected in err


def test_a_bad_command_line_raises_usage_error_from_parse():
    with pytest.raises(UsageError, match="--splt"):
        parse(["render", "RUN", "--out", "o", "--splt", "train"])


@pytest.mark.parametrize("where", ["before", "after"])
def test_traceback_shows_the_traceback_of_a_user_mistake(tmp_path, where):
    args = ["eval", str(tmp_path / "no_run"), str(tmp_path / "no_capture")]
    with pytest.raises(EbadError, match="no_run"):
        main(["--traceback", *args] if where == "before" else [*args, "--traceback"])


def test_parse_runs_nothing_and_names_the_command(monkeypatch):
    def fail(args):
        raise AssertionError("parse ran the command")

    monkeypatch.setattr(eval_cmd, "run", fail)
    parsed = parse(["eval", "RUN", "CAP", "--refine-poses", "--refine_iters", "7"])  # hyphens or underscores
    assert parsed.command is eval_cmd and not parsed.traceback
    assert (parsed.args.run, parsed.args.capture, parsed.args.refine_poses, parsed.args.refine_iters) == (
        "RUN",
        "CAP",
        True,
        7,
    )
