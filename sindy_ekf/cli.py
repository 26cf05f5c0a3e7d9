"""The ``sindy-ekf`` command line: parses arguments, calls the library, prints.

No algorithm lives here. Each command is a module in :mod:`sindy_ekf.commands` with
``add_arguments(parser)`` and ``run(args) -> int``; :data:`COMMANDS` lists them with their
one-line help, so that ``sindy-ekf --help`` imports none of them and only the module of the
command being run is imported (with its library). Bad input (``InputError``) ends with a
one-line message on stderr and exit code 2; a traceback is shown only with ``--verbose``.
Commands write figures only to files, so the command line sets matplotlib's backend once, to
Agg (no display needed); the library never switches the backend of a notebook that imports it.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from types import ModuleType
from typing import Iterable

from groundfloor import __version__, progress, repairs
from groundfloor.errors import InputError

COMMANDS = {  # name -> help line; the module sindy_ekf.commands.<name> is imported only to run it
    "simulate": "write a simulated tracker campaign",
    "preprocess": "raw bags to synchronised poses and body-frame states",
    "identify": "identify a SINDy model on the train runs",
    "evaluate": "multi-step prediction error on the test runs",
    "benchmark": "EKFs, factor graph and dead reckoning against the laser-tracker poses with degraded GNSS "
                 "and outages",
    "diagnose": "what the model gets wrong, its cause and the gain of a fix",
    "inject": "hide an input-side effect (delay, deadband, asymmetry, gain decay) in a campaign's recorded inputs",
    "report": "the whole chain as one HTML report with figures",
    "demo": "the whole chain on a built-in simulated campaign",
    "config": "print the benchmark's default filter settings (YAML), or check a settings file",
}


def command_module(name: str) -> ModuleType:
    """Return the module of command ``name`` (imported now, with the library it calls)."""
    return importlib.import_module(f"sindy_ekf.commands.{name}")


def build_parser(load: Iterable[str] = tuple(COMMANDS)) -> tuple[argparse.ArgumentParser, dict[str, ModuleType]]:
    """Return the top-level parser and the modules of the commands in ``load``.

    Every command is listed with its help line; only those in ``load`` get their arguments
    (their module imported), which is all that parsing one command line needs.
    """
    parser = argparse.ArgumentParser(prog="sindy-ekf", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"sindy-ekf {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", action="store_true",
                        help="no progress bars, logged warnings or repair counts (the summary and errors still print)")
    common.add_argument("--verbose", action="store_true", help="debug logging and tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = {}
    load = set(load)
    for name, help_line in COMMANDS.items():
        if name not in load:
            sub.add_parser(name, parents=[common], help=help_line)
            continue
        module = command_module(name)
        p = sub.add_parser(name, parents=[common], help=help_line, description=module.__doc__.splitlines()[0])
        module.add_arguments(p)
        modules[name] = module
    return parser, modules


def command_of(argv: list[str]) -> str | None:
    """Return the command named on the command line (its first word that is not an option), or None."""
    return next((a for a in argv if not a.startswith("-")), None)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    name = command_of(argv)
    parser, modules = build_parser(load=(name,) if name in COMMANDS else ())
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    verbose = args.verbose
    quiet = args.quiet
    logging.basicConfig(
        level=logging.DEBUG if verbose else (logging.ERROR if quiet else logging.WARNING),
        format="%(levelname)s %(name)s: %(message)s",
    )
    progress.enable(not quiet)
    repairs.clear()
    import matplotlib  # 0.3 s to import: only when a command runs, never for --help

    matplotlib.use("Agg")  # figures go to files; never open a window, even where a display exists
    try:
        code = int(modules[args.command].run(args) or 0)
        if not quiet:  # expected repairs, summed once for the command (groundfloor.repairs)
            for line in repairs.summary():
                print(f"sindy-ekf {args.command}: {line}", file=sys.stderr)
        return code
    except InputError as exc:
        if verbose:
            raise
        print(f"sindy-ekf {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sindy-ekf {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - last resort: one line unless --verbose
        if verbose:
            raise
        print(f"sindy-ekf {args.command}: internal error: {type(exc).__name__}: {exc} "
              "(rerun with --verbose for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
