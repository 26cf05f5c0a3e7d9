"""A re-initialised filter that then diverges: the run's status is ``diverged`` at the time the
tail's state became non-finite, counted from the run's start (not the tail's), after one recovery.

Reference: the construction. The fixes jump 20 m east at ``t_jump``; the filter rejects them,
the NIS alarm re-initialises it at the first jumped fix, and the stand-in model returns NaN east
of a line that only the re-initialised state crosses, so the tail diverges at its first step.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sindy_ekf.benchmark.health import guarded_ekf_batch
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel
from tests.support.estimation_helpers import PolyBody, clean_dgnss, fitted_oracle, inputs_at, simulate_truth

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


class NanEastOf(PolyBody):
    """PolyBody whose accelerations are NaN east of ``x_max_m`` (world x)."""

    def __init__(self, x_max_m: float):
        self.x_max_m = x_max_m

    def accel_and_jacobians(self, x6, u, t=0.0):
        f, J_x, J_u = super().accel_and_jacobians(x6, u, t)
        east = np.asarray(x6, float)[..., 0] > self.x_max_m
        return np.where(east[..., None], np.nan, f), J_x, J_u


def test_a_tail_that_diverges_after_a_reset_is_diverged_at_its_time_since_the_run_start():
    fitted = fitted_oracle()
    truth = simulate_truth(fitted, 30.0, np.random.default_rng(7))
    gnss = clean_dgnss(truth, seed=1)
    t_jump = truth.t[0] + 15.0
    p = gnss.p_local.copy()
    p[gnss.t_valid >= t_jump, 0] += 20.0
    gnss = replace(gnss, p_local=p)
    t = estimation_grid(truth.t, gnss.t_valid)
    run = EkfRun("jumpy", t, inputs_at(truth, t), truth.x6[0], P0, gnss)
    plain = run_ekf_batch(fitted, [run])[0]
    x_max_m = plain.x[:, 0].max() + 5.0  # the filter that rejects the jumped fixes never gets there
    assert np.interp(t_jump, truth.t, truth.x6[:, 0]) + 20.0 > x_max_m + 5.0  # the reset does
    model = ProcessModel(NanEastOf(x_max_m), name="nan_east")
    model.Q_rate_ = fitted.Q_rate_
    assert run.t[0] > 100.0  # run time is not time since the start: the two must not be confused
    [(res, status)] = guarded_ekf_batch(model, [run], step_test=False)  # the reset alone (the step test would keep the filter)
    t_first = gnss.t_valid[gnss.t_valid >= t_jump][0]
    assert status.status == "diverged" and status.recoveries == 1
    # the reset is at the first jumped fix; the tail's first step already is non-finite
    assert t_first - run.t[0] <= status.t_s <= t_first - run.t[0] + 0.1
    assert res is not None and np.all(np.isfinite(res.x))
    assert res.t[-1] <= t_first + 0.1
    np.testing.assert_array_equal(res.x[res.t < t_first - 1.0], plain.x[plain.t < t_first - 1.0])
