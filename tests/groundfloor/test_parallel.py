"""groundfloor.parallel: results in task order, failures named, the same answer however many workers."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.parallel import TaskFailure, Workers, parallel_map


def noisy_sum(task):
    """A task as the package's are: everything it needs, its seed too, is in its argument."""
    seed, n = task
    if n < 0:
        raise InputError(f"n = {n} is negative")
    x = np.random.default_rng(seed).normal(size=(n, 8))
    return float(np.linalg.norm(x.T @ x))


TASKS = [(seed, 200 + 10 * seed) for seed in range(7)]


@pytest.mark.parametrize("jobs", [1, 2])
def test_results_come_in_task_order_and_equal_the_serial_map(jobs):
    expected = [noisy_sum(t) for t in TASKS]
    assert parallel_map(noisy_sum, TASKS, jobs) == expected


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_failing_task_raises_its_own_error_named(jobs):
    with pytest.raises(InputError, match="negative") as info:
        parallel_map(noisy_sum, TASKS[:3] + [(9, -1)] + TASKS[3:], jobs, names=[f"run_{i}" for i in range(8)])
    assert info.value.__notes__ == ["in parallel task run_3"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_keep_going_keeps_the_other_results(jobs):
    out = parallel_map(noisy_sum, [TASKS[0], (9, -1), TASKS[1]], jobs, keep_going=True, desc="family")
    assert out[0] == noisy_sum(TASKS[0]) and out[2] == noisy_sum(TASKS[1])
    assert isinstance(out[1], TaskFailure) and out[1].name == "family #1"
    assert str(out[1]) == "family #1: InputError: n = -1 is negative"


def test_workers_of_an_int_and_in_words():
    assert Workers.of(3) == Workers(jobs=3) and Workers.of(None) == Workers()
    assert not Workers(1).parallel and Workers(2).parallel and Workers(1, "tcp://h:8786").parallel
    assert Workers(dask="tcp://h:8786").describe() == "Dask scheduler tcp://h:8786"


def test_names_must_match_the_tasks():
    with pytest.raises(ValueError, match="2 names for 7 tasks"):
        parallel_map(noisy_sum, TASKS, 1, names=["a", "b"])


def test_a_scheduler_that_does_not_answer_is_named(monkeypatch):
    import groundfloor.parallel as parallel

    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(InputError, match=r"--dask tcp://127.0.0.1:9: no Dask scheduler answered"):
        parallel_map(noisy_sum, TASKS, Workers(dask="tcp://127.0.0.1:9"))
