"""Independent tasks mapped in parallel: local processes or a Dask cluster, through joblib.

Every parallel site of the package (grid search, preprocessing runs, benchmark runs, the
diagnosis families, the Monte Carlo and bench suites) goes through :func:`parallel_map`, so one
switch moves all of them: ``Workers(jobs=N)`` runs ``N`` local processes (joblib's loky backend),
``Workers(dask="tcp://host:8786")`` sends the same tasks to a Dask scheduler (joblib's dask
backend). Results come back in task order and every task carries its own seed, so the answer
does not depend on how many workers ran it or where.
"""

from __future__ import annotations

import logging
import os
import traceback
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence, TypeVar

from threadpoolctl import threadpool_limits

from groundfloor.errors import InputError
from groundfloor.progress import progress

T = TypeVar("T")
R = TypeVar("R")

CONNECT_TIMEOUT_S = 20.0  # how long to wait for a Dask scheduler to answer


@dataclass(frozen=True)
class Workers:
    """Where parallel tasks run: ``jobs`` local processes, or the Dask scheduler at ``dask``.

    ``jobs <= 1`` without ``dask`` runs in this process, one task after the other. With ``dask``
    the cluster decides the concurrency and ``jobs`` is ignored.
    """

    jobs: int = 1
    dask: str | None = None

    @classmethod
    def of(cls, workers: "Workers | int | None") -> "Workers":
        """Return ``workers`` as :class:`Workers` (an int is a number of local processes)."""
        if workers is None:
            return cls()
        return workers if isinstance(workers, Workers) else cls(jobs=int(workers))

    @property
    def parallel(self) -> bool:
        """Return True when tasks run outside this process."""
        return self.dask is not None or self.jobs > 1

    def describe(self) -> str:
        """Return where the tasks run, in words (for logs and reports)."""
        if self.dask is not None:
            return f"Dask scheduler {self.dask}"
        return f"{self.jobs} local processes" if self.jobs > 1 else "this process"


@dataclass(frozen=True)
class TaskFailure:
    """A task that raised, kept in place of its result when the caller asked to keep going."""

    name: str
    error: BaseException
    traceback: str

    def __str__(self) -> str:
        return f"{self.name}: {type(self.error).__name__}: {self.error}"


class _Call:
    """The task function wrapped for a worker: BLAS threads limited, an exception returned, not raised.

    An exception comes back as a :class:`TaskFailure` naming the task, so that the parent decides
    whether it stops the map (and says which task) or stands in for that one result.
    """

    def __init__(self, fn: Callable, blas_threads: int | None):
        self.fn = fn
        self.blas_threads = blas_threads
        # the command line's logging (level, format), for workers that start without it
        root = logging.getLogger()
        self.log_level = root.getEffectiveLevel()
        fmt = root.handlers[0].formatter if root.handlers else None
        self.log_format = getattr(fmt, "_fmt", None)
        self.parent_pid = os.getpid()

    def __call__(self, name: str, task):
        root = logging.getLogger()
        if os.getpid() != self.parent_pid and not root.handlers:  # a fresh worker: log as the parent does
            logging.basicConfig(level=self.log_level, format=self.log_format)
        try:
            if self.blas_threads is None:
                return self.fn(task)
            # The tasks are small linear algebra each; with several worker processes on few cores
            # multi-threaded BLAS only contends (six times slower measured in the grid search).
            # Limited in the serial case too, so that jobs=1 sums in the same order as jobs=N.
            with threadpool_limits(limits=self.blas_threads, user_api="blas"):
                return self.fn(task)
        except Exception as exc:  # noqa: BLE001 - handed back to the parent with the task's name
            return TaskFailure(name, exc, traceback.format_exc())


def parallel_map(fn: Callable[[T], R], tasks: Sequence[T], workers: Workers | int | None = 1, *,
                 names: Sequence[str] | None = None, desc: str = "tasks", keep_going: bool = False,
                 blas_threads: int | None = 1) -> list[R | TaskFailure]:
    """Return ``[fn(task) for task in tasks]``, computed where ``workers`` says, in task order.

    Parameters
    ----------
    fn : callable
        A module-level function of one task (pickled by reference to the workers).
    tasks : sequence
        One argument of ``fn`` each; everything a task needs (its seed too) is in it.
    workers : Workers or int
        Local processes (an int), or :class:`Workers` with a Dask scheduler address.
    names : sequence of str, optional
        Each task's name, for the message when it fails (default ``"{desc} #{i}"``).
    desc : str
        What the tasks are, for the progress bar.
    keep_going : bool
        False (default): the first failing task (in task order) raises its own exception, with a
        note naming the task. True: a failed task's place holds a :class:`TaskFailure` and the
        others still run.
    blas_threads : int or None
        BLAS threads inside each task (None: leave them alone).
    """
    return list(parallel_iter(fn, tasks, workers, names=names, desc=desc, keep_going=keep_going,
                              blas_threads=blas_threads))


def parallel_iter(fn: Callable[[T], R], tasks: Sequence[T], workers: Workers | int | None = 1, *,
                  names: Sequence[str] | None = None, desc: str = "tasks", keep_going: bool = False,
                  blas_threads: int | None = 1) -> Iterator[R | TaskFailure]:
    """Yield ``fn(task)`` for each task in task order, each as soon as it and those before it are done.

    As :func:`parallel_map` (same parameters), for a caller that writes results as they come.
    """
    workers = Workers.of(workers)
    tasks = list(tasks)
    names = [f"{desc} #{i}" for i in range(len(tasks))] if names is None else list(names)
    if len(names) != len(tasks):
        raise ValueError(f"parallel_map: {len(names)} names for {len(tasks)} tasks")
    call = _Call(fn, blas_threads)
    if not workers.parallel or (workers.dask is None and len(tasks) < 2):
        results = (call(n, t) for n, t in zip(names, tasks))
        yield from _checked(progress(results, desc, total=len(tasks)), keep_going)
        return
    from joblib import Parallel, delayed

    with _backend(workers), warnings.catch_warnings():
        # stopping at a failure cancels the tasks not yet collected; joblib warns that results
        # went unused, which says nothing the raised error does not
        warnings.filterwarnings("ignore", message=r".*executed\s+but not used", category=UserWarning)
        # loky's reused executor retires workers idle longer than its timeout between two maps
        # (identify's serial stretches) and starts new ones, warning of a "memory leak" it did not see
        warnings.filterwarnings("ignore", message=r"A worker stopped while some jobs were given to the executor",
                                category=UserWarning)
        n_jobs = -1 if workers.dask is not None else min(workers.jobs, len(tasks))
        # generator: results arrive in order as they finish, and the first failure stops the rest
        run = Parallel(n_jobs=n_jobs, return_as="generator")(delayed(call)(n, t) for n, t in zip(names, tasks))
        try:
            yield from _checked(progress(run, desc, total=len(tasks)), keep_going)
        finally:
            run.close()


def _checked(results: Iterator, keep_going: bool) -> Iterator:
    """Yield the results; raise the first failure unless ``keep_going``."""
    for r in results:
        if isinstance(r, TaskFailure) and not keep_going:
            r.error.add_note(f"in parallel task {r.name}")
            raise r.error
        yield r


@contextmanager
def _backend(workers: Workers):
    """Select joblib's backend for ``workers``: loky locally, dask with a client of the scheduler."""
    from joblib import parallel_config

    if workers.dask is None:
        with parallel_config(backend="loky"):
            yield
        return
    # Imported here, not at the top: Dask is an optional extra (pip install sindy-ekf[dask]);
    # only a run that asks for a scheduler needs it.
    try:
        from distributed import Client
    except ImportError as exc:
        raise ImportError("--dask needs Dask: pip install 'sindy-ekf[dask]'") from exc
    try:  # a client per map: a scheduler that went away is not left behind in a cache
        client = Client(workers.dask, set_as_default=False, timeout=CONNECT_TIMEOUT_S)
    except OSError as exc:
        raise InputError(f"--dask {workers.dask}: no Dask scheduler answered ({exc})") from exc
    with client, parallel_config(backend="dask", client=client):
        yield
