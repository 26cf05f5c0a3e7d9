"""Progress bars for long steps; silent unless the command line switches them on.

The library never prints: it logs through :mod:`logging` and reports progress through
:func:`progress`, which shows a tqdm bar on stderr only when :func:`enable` was called (the CLI
does, unless ``--quiet``).
"""

from __future__ import annotations

from typing import Iterable, TypeVar

T = TypeVar("T")
_enabled = False


def enable(on: bool = True) -> None:
    """Switch progress bars on or off for this process."""
    global _enabled
    _enabled = on


def progress(iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap ``iterable`` in a tqdm bar named ``desc`` when progress is enabled."""
    if not _enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, leave=False, dynamic_ncols=True)
