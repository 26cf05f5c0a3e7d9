"""Progress bars for long steps; only on a terminal, and only when the command line switches them on.

The library never prints: it logs through :mod:`logging` and reports progress through
:func:`progress`, which shows a tqdm bar on stderr only when :func:`enable` was called (the CLI
does, unless ``--quiet``) and stderr is a terminal: a bar redrawn with carriage returns is
noise in a log file or a pipe.
"""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

T = TypeVar("T")
_enabled = False


def enable(on: bool = True) -> None:
    """Switch progress bars on or off for this process."""
    global _enabled
    _enabled = on


def shown() -> bool:
    """Return True when progress bars are drawn: enabled, and stderr is a terminal."""
    isatty = getattr(sys.stderr, "isatty", None)
    return _enabled and callable(isatty) and bool(isatty())


def progress(iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap ``iterable`` in a tqdm bar named ``desc`` when progress bars are :func:`shown`."""
    if not shown():
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, leave=False, dynamic_ncols=True)
