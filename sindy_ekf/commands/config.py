"""``sindy-ekf config --defaults``: the benchmark's filter settings, as YAML.

``--defaults`` prints the file shipped with the package verbatim (``sindy_ekf/data/filters.yaml``),
to be redirected into a file, edited and given to ``sindy-ekf benchmark --config FILE``.
``sindy-ekf config FILE`` checks a settings file (one-line error naming the key, exit 2) and
prints every setting it gives, merged over the defaults (itself a valid settings file).
``docs/configuration.md`` describes the keys.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from sindy_ekf.config import defaults_text, load_config


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``config`` arguments to its parser."""
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--defaults", action="store_true",
                       help="print the shipped defaults verbatim (redirect them to a file and edit it)")
    which.add_argument("file", nargs="?", type=Path, default=None, metavar="FILE",
                       help="check a settings file and print the settings it gives, merged over the defaults")


def run(args) -> int:
    """Print the defaults, or check ``args.file`` and print its merged settings."""
    if args.defaults:
        sys.stdout.write(defaults_text())
        return 0
    config = load_config(args.file)
    print(f"# the settings of {args.file}, merged over the defaults (sindy-ekf config --defaults)")
    sys.stdout.write(yaml.safe_dump(config.to_dict(), sort_keys=False, default_flow_style=None, width=100))
    return 0
