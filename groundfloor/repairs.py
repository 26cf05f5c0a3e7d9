"""Expected, counted repairs of the input, summarised once per command instead of warned per run.

Some repairs belong to normal data: a prism lost for a moment leaves a hole in the poses (a
``gaps`` repair; splines, windows and figures stop at it). A warning on every run of every read
would bury the real problems, so readers report such repairs with :func:`note` (logged at INFO)
and the command line prints :func:`summary` once when the command ends. A campaign read twice
in one command counts once: the last count per run is kept. Repairs that mean something is
wrong with the data (rows dropped, stamps merged) stay warnings where they happen.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

_noted: dict[str, dict[str, int]] = {}  # what -> run -> count


def note(what: str, run: str, count: int) -> None:
    """Record ``count`` expected repairs ``what`` (e.g. ``"pose gaps"``) in ``run``."""
    if count:
        _noted.setdefault(what, {})[run] = int(count)
        log.info("run %s: %d %s", run, count, what)


def summary() -> list[str]:
    """Return one line per kind of repair noted so far: the count of each run and the total."""
    lines = []
    for what, runs in _noted.items():
        per_run = ", ".join(f"{run} {n}" for run, n in runs.items())
        lines.append(f"{what}: {sum(runs.values())} in {len(runs)} runs ({per_run})")
    return lines


def clear() -> None:
    """Forget the repairs noted so far (a new command, a new test)."""
    _noted.clear()
