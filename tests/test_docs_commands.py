"""Every command the README and docs/ show parses: each ``ebad SUBCOMMAND ...`` (by ``ebad.cli.parse``,
tyro's parser of every subcommand) and ``python -m benchmarks.NAME ...`` in backticks is handed to its own
argument parser (nothing runs), so a renamed or removed option fails here instead of in a user's shell."""

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


def _ebad_parse_error(cmd: str) -> str | None:
    """Why ``cmd`` (``ebad SUBCOMMAND ...``) does not parse with ``ebad``'s parser, or None when it parses
    (``--help`` included); ``reconstruct`` also resolves its config (preset, ranges)."""
    from ebad.cli import parse
    from ebad.cli.reconstruct import resolve
    from ebad.errors import EbadError

    try:
        parsed = parse(shlex.split(cmd)[1:])
        if parsed.command.NAME == "reconstruct":
            resolve(parsed.args)
    except SystemExit as exc:
        return None if exc.code == 0 else f"exit {exc.code}"
    except EbadError as exc:
        return str(exc)
    return None


@pytest.mark.parametrize("doc, cmd", EBAD, ids=[c for _, c in EBAD])
def test_ebad_command_parses(doc, cmd, capsys):
    error = _ebad_parse_error(cmd)
    assert error is None, f"{doc}: `{cmd}` does not parse: {error} {capsys.readouterr().err.strip()}"


def _misspelt(cmd: str) -> str | None:
    """``cmd`` with its first ``--option`` misspelt (two letters swapped) and without ``--help`` (which
    would print the help before the parser looks further), or None if it has no option."""
    words = [w for w in cmd.split() if w not in ("--help", "-h")]
    i = next((i for i, w in enumerate(words) if w.startswith("--") and len(w) > 4), None)
    if i is None:
        return None
    w = words[i]
    words[i] = w[:2] + w[3] + w[2] + w[4:]
    return " ".join(words)


@pytest.mark.parametrize("doc, cmd", EBAD, ids=[c for _, c in EBAD])
def test_a_misspelt_option_fails(doc, cmd):
    # the check above can fail: the same command with one option misspelt does not parse
    bad = _misspelt(cmd)
    if bad is None:
        pytest.skip(f"`{cmd}` has no --option to misspell")
    error = _ebad_parse_error(bad)
    assert error is not None, bad


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
