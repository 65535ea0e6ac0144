"""Every command the README and docs/ show parses: each ``ebad SUBCOMMAND ...`` and ``python -m
benchmarks.NAME ...`` in backticks is handed to its own argument parser (nothing runs), so a
renamed or removed option fails here instead of in a user's shell."""
from __future__ import annotations

import argparse
import importlib
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PLACEHOLDER = re.compile(r"\[|\||\bNAME\b|\bSUB\b|\.\.\.")  # synopses ("[--quick]", "a|b", NAME), not commands


def _commands(prefix: str) -> list[tuple[str, str]]:
    """(document name, command with its whitespace collapsed) for each command starting with
    ``prefix``: in inline backticks, or on a line of a fenced code block (after ``&&``, before a
    ``#`` comment)."""
    found = []
    for doc in DOCS:
        text = doc.read_text()
        candidates = [m.group(1) for m in re.finditer(r"`(" + re.escape(prefix) + r"[^`]*)`", text)]
        for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M):
            for line in block.splitlines():
                candidates += [part.split(" #")[0] for part in line.split("&&")]
        for cand in candidates:
            cmd = " ".join(cand.split())
            if cmd.startswith(prefix) and len(cmd.split()) > 2 and not PLACEHOLDER.search(cmd):
                found.append((doc.name, cmd))
    return sorted(set(found))


def _ebad_commands() -> list[tuple[str, str]]:
    """``_commands("ebad ")`` without lines of printed output ("ebad demo: building ...", "ebad is
    +5.69 dB ..."): the word after ``ebad`` must name a subcommand."""
    from ebad.cli import _commands as subcommands

    names = {m.NAME for m in subcommands()}
    return [(doc, cmd) for doc, cmd in _commands("ebad ") if cmd.split()[1] in names]


EBAD = _ebad_commands()
BENCHMARKS = _commands("python -m benchmarks.")


class _Parsed(Exception):
    """Raised by the patched ``parse_args`` once a benchmark's arguments parsed: main stops there."""


def test_the_documents_show_commands():
    # the scan itself can fail (a changed backtick style would find nothing and pass everything below)
    assert len(EBAD) >= 5 and len(BENCHMARKS) >= 30


@pytest.mark.parametrize("doc, cmd", EBAD, ids=[c for _, c in EBAD])
def test_ebad_command_parses(doc, cmd, capsys):
    from ebad.cli import build_parser
    from ebad.cli.reconstruct import parse

    argv = shlex.split(cmd)[1:]
    try:
        if argv[0] == "reconstruct":  # its own front parser and tyro's generated options
            parse(argv[1:])
        else:
            build_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code == 0:  # --help
            return
        pytest.fail(f"{doc}: `{cmd}` does not parse (exit {exc.code}): {capsys.readouterr().err.strip()}")


@pytest.mark.parametrize("doc, cmd", BENCHMARKS, ids=[c for _, c in BENCHMARKS])
def test_benchmark_command_parses(doc, cmd, capsys, monkeypatch):
    parts = shlex.split(cmd)
    module = importlib.import_module(parts[2])
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        original(self, args, namespace)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    try:
        module.main(parts[3:])
    except _Parsed:
        return
    except SystemExit as exc:
        pytest.fail(f"{doc}: `{cmd}` does not parse (exit {exc.code}): {capsys.readouterr().err.strip()}")
    pytest.fail(f"{doc}: `{cmd}`: main returned without parsing its arguments")
