"""The ``sindy-ekf`` command line: parses arguments, calls the library, prints.

No algorithm lives here. Each command is a module in :mod:`sindy_ekf.commands` with
``add_parser(subparsers)`` and ``run(args) -> int``. Bad input (``InputError``) ends with a
one-line message on stderr and exit code 2; a traceback is shown only with ``--verbose``.
Commands write figures only to files, so the command line sets matplotlib's backend once, to
Agg (no display needed); the library never switches the backend of a notebook that imports it.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

import matplotlib

from groundfloor import __version__
from groundfloor.errors import InputError

COMMANDS = ["simulate", "preprocess", "identify", "evaluate", "benchmark", "diagnose", "report", "demo"]


def build_parser() -> tuple[argparse.ArgumentParser, dict]:
    """Return the top-level parser and the command modules that registered with it."""
    parser = argparse.ArgumentParser(prog="sindy-ekf", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"sindy-ekf {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--quiet", action="store_true", help="no progress bars, only errors")
    common.add_argument("--verbose", action="store_true", help="debug logging and tracebacks")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    modules = {}
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"sindy_ekf.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"sindy_ekf.commands.{name}":
                raise
            continue
        module.add_parser(sub, common)
        modules[name] = module
    return parser, modules


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    parser, modules = build_parser()
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    verbose = getattr(args, "verbose", False)
    quiet = getattr(args, "quiet", False)
    logging.basicConfig(
        level=logging.DEBUG if verbose else (logging.ERROR if quiet else logging.WARNING),
        format="%(levelname)s %(name)s: %(message)s",
    )
    from groundfloor import progress

    progress.enable(not quiet)
    matplotlib.use("Agg")  # figures go to files; never open a window, even where a display exists
    try:
        return int(modules[args.command].run(args) or 0)
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
