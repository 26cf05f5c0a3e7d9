"""The batch EKF's wall time shared among its runs by their step counts (EkfResult.runtime_s)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from sindy_ekf.estimation.ekf import EkfRun, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, simulate_truths

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def test_runtime_of_a_batch_is_shared_by_the_runs_step_counts():
    model = ProcessModel(PolyBody(), name="poly")
    truths = simulate_truths(model, 6.0, np.random.default_rng(3), n_runs=2)
    model = fit_process_noise(model, truths)
    long_run = EkfRun("long", truths[0].t, truths[0].u, truths[0].x6[0], P0, None)
    short_run = EkfRun("short", truths[1].t[:100], truths[1].u[:100], truths[1].x6[0], P0, None)
    start = time.perf_counter()
    res = run_ekf_batch(model, [long_run, short_run])
    wall = time.perf_counter() - start
    assert all(r.runtime_s > 0 for r in res)
    assert sum(r.runtime_s for r in res) <= wall
    assert res[0].runtime_s / res[1].runtime_s == pytest.approx(len(long_run.t) / 100, rel=1e-9)
