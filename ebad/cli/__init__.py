"""The ``ebad`` command line: one tyro parser, one subcommand per module of this package.

Each subcommand lives in its own module and exposes::

    NAME: str                   # the subcommand, e.g. "deblur"
    HELP: str                   # one line: the command's description in ``ebad --help`` and its own ``--help``
    Args                        # a dataclass of its arguments, one docstring per field (the option's help)
    def run(args: Args) -> int  # do the work, return an exit code

and optionally ``def default_args(argv: list[str]) -> Args``: the defaults its options show and
start from, read from the command line before it is parsed (``reconstruct``: ``--preset``,
``--config`` or the run being resumed choose the defaults of the generated config options).

Modules are discovered, so adding a command touches no other file. ``parse`` builds one tyro
parser: the subcommands are a ``Union`` of the ``Args`` dataclasses (``tyro.conf.subcommand``),
positional arguments are ``tyro.conf.Positional``, an option without a default is required.
Options are shown with hyphens (``--max-frames``, ``--train.max-seconds``); tyro accepts
underscores as well (``--train.max_seconds``).

User mistakes raise a subclass of ``ebad.errors.EbadError`` whose message names the file, field
or argument (a command line that does not parse: ``UsageError``), and file-system failures
raise ``OSError`` with the path; ``main`` prints those as one line and exits 2 (``--traceback``
shows the traceback instead). Anything else is a bug and shows its traceback.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import importlib
import pkgutil
import sys
import typing
from types import ModuleType
from typing import Annotated, Any, NamedTuple, Union

from ..errors import EbadError, UserError
from ..threads import configure as configure_threads  # called first thing in main(), never on import

PROG = "ebad"
DESCRIPTION = "Sharp 3D Gaussian scenes, novel views and frames from blurry event-camera captures."


class UsageError(UserError):
    """A command line that does not parse (unknown option, missing or bad value); the message says which."""


class Parsed(NamedTuple):
    command: ModuleType  # the subcommand's module (``run(args)`` does the work)
    args: Any  # its ``Args``, filled from the command line
    traceback: bool  # ``--traceback``: show tracebacks of user mistakes too


def _commands() -> list[ModuleType]:
    """The subcommand modules of this package, by name."""
    mods = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "Args") and hasattr(mod, "run"):
            mods.append(mod)
    return mods


def _command_name(argv: list[str], names: set[str]) -> str | None:
    """The subcommand named on the command line: its first word (``ebad`` itself takes only flags)."""
    word = next((a for a in argv if not a.startswith("-")), None)
    return word if word in names else None


def _root_type(mods: list[ModuleType], selected: str | None, argv: list[str]) -> type:
    """``ebad``'s arguments: ``--traceback`` and one subcommand of ``mods``."""
    import tyro

    options = []
    for mod in mods:
        default = tyro.MISSING_NONPROP
        if mod.NAME == selected and hasattr(mod, "default_args"):
            default = mod.default_args(argv[argv.index(mod.NAME) + 1 :])
        options.append(
            Annotated[
                mod.Args, tyro.conf.subcommand(mod.NAME, description=mod.HELP, default=default, prefix_name=False)
            ]
        )
    root = dataclasses.make_dataclass(
        "Ebad",
        [
            ("command", Annotated[Union[tuple(options)], tyro.conf.arg(name="")]),  # noqa: UP007
            (
                "traceback",
                Annotated[bool, tyro.conf.arg(help="show the full traceback of a user mistake too")],
                dataclasses.field(default=False),
            ),
        ],
    )
    root.__doc__ = DESCRIPTION
    return root


def parse(argv: list[str]) -> Parsed:
    """The subcommand and its arguments from ``argv`` (without the program name); runs nothing.

    ``--help`` prints the help and raises ``SystemExit(0)``; a command line that does not parse
    raises ``UsageError`` (with tyro's own message box and ``SystemExit(2)`` where tyro offers no
    hook for its errors)."""
    import tyro

    mods = _commands()
    by_name = {m.NAME: m for m in mods}
    selected = _command_name(argv, set(by_name))
    root = _root_type(mods, selected, argv)
    with _one_line_errors(by_name.get(selected or ""), mods):
        ns: Any = tyro.cli(
            root, prog=PROG, args=argv, config=(tyro.conf.FlagCreatePairsOff, tyro.conf.CascadeSubcommandArgs)
        )
    mod = next(m for m in mods if isinstance(ns.command, m.Args))
    return Parsed(mod, ns.command, bool(ns.traceback))


def main(argv: list[str] | None = None) -> int:
    configure_threads()  # OMP_WAIT_POLICY before any command loads torch, numba's layer (ebad.threads)
    argv = list(sys.argv[1:] if argv is None else argv)
    name = _command_name(argv, {m.NAME for m in _commands()})
    prog = f"{PROG} {name}" if name else PROG
    show_traceback = "--traceback" in argv  # until the command line is parsed
    try:
        try:
            parsed = parse(argv)
        except SystemExit as exc:  # --help (0), or a parse error tyro printed itself (2)
            return 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 2
        show_traceback = parsed.traceback
        return int(parsed.command.run(parsed.args) or 0)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except (EbadError, OSError) as exc:
        if show_traceback:
            raise
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _one_line(exc: BaseException) -> str:
    """The message of a user mistake or an OSError, with the path an OSError carries."""
    if isinstance(exc, OSError) and not isinstance(exc, EbadError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return " ".join(str(exc).split())


# --------------------------------------------------------------------------- parse errors


def _option_names(cls: type, prefix: str = "") -> list[str]:
    """The ``--options`` of a dataclass of arguments (nested dataclasses as ``--section.field``)."""
    import tyro

    positional = typing.get_args(tyro.conf.Positional[int])[1:]
    names = []
    hints = typing.get_type_hints(cls, include_extras=True)
    for f in dataclasses.fields(cls):
        t = hints[f.name]
        extras: tuple[Any, ...] = ()
        if typing.get_origin(t) is Annotated:
            t, extras = typing.get_args(t)[0], typing.get_args(t)[1:]
        if any(e in positional for e in extras):
            continue
        if isinstance(t, type) and dataclasses.is_dataclass(t):
            merged = any(getattr(e, "name", None) == "" for e in extras)
            names += _option_names(t, prefix if merged else f"{prefix}{f.name}.")
        else:
            names.append(f"--{prefix}{f.name}".replace("_", "-"))
    return names


def _describe(event: Any, mod: ModuleType | None, mods: list[ModuleType]) -> str | None:
    """One line for a tyro parse-error event on the command line of ``mod`` (None: no subcommand
    named), or None to leave it to tyro's own message."""
    from tyro import _errors as ev

    prog = f"{PROG} {mod.NAME}" if mod else PROG

    def name(arg) -> str:
        if arg.is_positional() and arg.lowered.metavar:
            return str(arg.lowered.metavar)
        return arg.display_name()

    def unrecognized(tokens: list[str]) -> str:
        options = [t for t in tokens if t.startswith("-")] or list(tokens)
        known = (_option_names(mod.Args) if mod else []) + ["--traceback", "--help"]
        return ", ".join(
            f"{o} (did you mean {' or '.join(close)}?)"
            if (close := difflib.get_close_matches(o.split("=")[0].replace("_", "-"), known, n=2, cutoff=0.7))
            else o
            for o in options
        )

    if isinstance(event, ev.UnrecognizedArgs):
        if mod is None and not any(t.startswith("-") for t in event.tokens):
            return f"unknown command {' '.join(event.tokens)}; choose one of {', '.join(m.NAME for m in mods)}"
        return f"unrecognized argument(s): {unrecognized(event.tokens)}; see {prog} --help"
    if isinstance(event, ev.MissingArgs):
        missing = ", ".join(name(a.arg) for a in event.missing_arguments)
        extra = f" (and unrecognized: {unrecognized(event.unrecognized_tokens)})" if event.unrecognized_tokens else ""
        return f"missing required argument(s): {missing}{extra}; see {prog} --help"
    if isinstance(event, ev.MissingSubcommand):
        return f"choose a command: {', '.join(m.NAME for m in mods)} ({PROG} --help describes them)"
    if isinstance(event, ev.InvalidChoice):
        return (
            f"{name(event.argument)}: invalid choice {event.value!r}, choose one of "
            f"{', '.join(str(c) for c in event.choices)}"
        )
    if isinstance(event, ev.BadValue):
        if event.reason == "too_few_values":
            return f"{name(event.argument)}: expected {event.argument.lowered.nargs} value(s)"
        return f"{name(event.argument)}: cannot take the value {event.offending_value!r}"
    if isinstance(event, ev.InstantiationFailure):
        message = " ".join(str(event.message).replace("[bold]", "").replace("[/bold]", "").split())
        return f"{name(event.argument)}: {message}" if event.argument is not None else message
    return None


@contextlib.contextmanager
def _one_line_errors(mod: ModuleType | None, mods: list[ModuleType]):
    """Parse errors as ``UsageError`` with one line instead of tyro's message box (tyro's
    ``_errors.on_parse_error`` hook; without it, tyro prints its box and exits 2)."""
    try:
        from tyro import _errors

        hook_into = _errors.on_parse_error
    except (ImportError, AttributeError):  # a tyro without the hook
        yield
        return

    def hook(event) -> None:
        try:
            line = _describe(event, mod, mods)
        except (AttributeError, TypeError):  # a payload of another tyro version: tyro's own message
            line = None
        if line is not None:
            raise UsageError(line)

    with hook_into(hook):
        yield


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
