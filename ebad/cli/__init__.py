"""The ``ebad`` command line.

Each subcommand lives in its own module in this package and exposes::

    NAME: str                      # the subcommand, e.g. "deblur"
    HELP: str                      # one line for ``ebad --help``
    def add_arguments(parser): ... # fill an argparse parser
    def run(args) -> int: ...      # do the work, return an exit code

or, for a command whose options are generated from dataclasses (``reconstruct``, by tyro),
``def main(argv: list[str]) -> int`` that parses its own arguments.

Modules are discovered, so adding a command touches no other file. User mistakes raise a
subclass of ``ebad.errors.EbadError`` whose message names the file, field or argument, and
file-system failures raise ``OSError`` with the path; ``main`` prints those as one line and
exits 2. Anything else is a bug and shows its traceback.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from ..errors import EbadError
from ..threads import configure as configure_threads  # called first thing in main(), never on import


def _commands():
    mods = []
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "NAME") and (hasattr(mod, "run") or hasattr(mod, "main")):
            mods.append(mod)
    return mods


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ebad",
        description="Sharp 3D Gaussian scenes, novel views and frames from blurry event-camera captures.",
    )
    parser.add_argument("--traceback", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _commands():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           add_help=not hasattr(mod, "main"))
        if hasattr(mod, "main"):  # parses its own arguments: ``main`` hands it everything after its name
            p.set_defaults(_run=lambda args, m=mod: m.main(args.rest))
        else:
            mod.add_arguments(p)
            p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    configure_threads()  # OMP_WAIT_POLICY before any command loads torch, numba's layer (ebad.threads)
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    own = {m.NAME for m in _commands() if hasattr(m, "main")}
    cut = next((i for i, a in enumerate(argv) if not a.startswith("-")), len(argv))
    if cut < len(argv) and argv[cut] in own:  # argparse cannot pass "--option ..." through: split here
        args = parser.parse_args(argv[:cut + 1])
        args.rest = argv[cut + 1:]
    else:
        args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("ebad: interrupted", file=sys.stderr)
        return 130
    except (EbadError, OSError) as exc:
        if args.traceback:
            raise
        print(f"ebad {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _one_line(exc: BaseException) -> str:
    """The message of a user mistake or an OSError, with the path an OSError carries."""
    if isinstance(exc, OSError) and not isinstance(exc, EbadError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return str(exc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
