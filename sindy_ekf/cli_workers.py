"""``--jobs N`` and ``--dask ADDRESS`` of the commands: where their parallel tasks run (:mod:`groundfloor.parallel`)."""

from __future__ import annotations

import argparse

from groundfloor.errors import InputError
from groundfloor.parallel import Workers


def add_worker_arguments(p: argparse.ArgumentParser, default_jobs: int = 1, what: str = "tasks") -> None:
    """Add ``--jobs`` and ``--dask`` to a command's parser; ``what`` says which tasks run in parallel."""
    p.add_argument("--jobs", type=int, default=default_jobs, metavar="N",
                   help=f"local worker processes for the {what} (default {default_jobs})")
    p.add_argument("--dask", default=None, metavar="SCHEDULER_ADDRESS",
                   help=f"run the {what} on the Dask cluster of this scheduler (e.g. tcp://10.0.0.5:8786; "
                        "needs pip install 'sindy-ekf[dask]'); the results equal a local run's")


def workers_of(args: argparse.Namespace) -> Workers:
    """Return the :class:`Workers` of ``--jobs`` and ``--dask``."""
    if args.jobs < 1:
        raise InputError(f"--jobs {args.jobs}: needs 1 or more worker processes")
    return Workers(jobs=args.jobs, dask=args.dask)
