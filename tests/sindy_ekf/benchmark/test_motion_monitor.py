"""The NIS monitor on the seven-state EKF (gyro and odometry fused): fixes that drift away from a
filter that keeps trusting its model end the run as ``diverged`` where the innovations leave their
band (before, such a filter was reported ``ok``); a step of the fixes that returns is told apart
(``fix_steps``) as for the six-state EKFs; a consistent run stays ``ok`` and uncut.

Reference: the simulator of the estimation tests (its truth and GNSS), the fixes altered by hand.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sindy_ekf.benchmark.health import RunStatus
from sindy_ekf.benchmark.motion_source import monitored
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid
from sindy_ekf.estimation.ekf_motion import MotionSensors, run_ekf_motion
from tests.support.estimation_helpers import clean_dgnss, fitted_oracle, inputs_at, simulate_truth

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


@pytest.fixture(scope="module")
def setting():
    model = fitted_oracle()
    truth = simulate_truth(model, 90.0, np.random.default_rng(5))
    gnss = clean_dgnss(truth, seed=5)
    t = estimation_grid(truth.t, gnss.t_valid)
    return model, truth, gnss, t, inputs_at(truth, t)


def _monitored(setting, p_local):
    model, truth, gnss, t, u = setting
    run = EkfRun("r", t, u, truth.x6[0], P0, replace(gnss, p_local=p_local))
    res = run_ekf_motion(model, run, MotionSensors())
    return res, monitored(model, run, res, RunStatus(), 0.999, None)


def test_a_consistent_run_stays_ok_and_whole(setting):
    res, (out, status) = _monitored(setting, setting[2].p_local)
    assert status.status == "ok" and status.fix_steps == 0
    assert out is res


def test_fixes_drifting_away_end_the_run_as_diverged_where_they_leave(setting):
    _, _, gnss, t, _ = setting
    drift = gnss.p_local.copy()
    late = gnss.t_valid > t[0] + 40.0
    drift[late, 0] += 1.5 * (gnss.t_valid[late] - t[0] - 40.0)  # 1.5 m/s away from the robot
    res, (out, status) = _monitored(setting, drift)
    assert status.status == "diverged"
    assert 40.0 < status.t_s < 50.0
    assert out.t[-1] < t[0] + status.t_s and len(out.x) == len(out.t) == len(out.gyro_bias) == len(out.gyro_bias_std)
    assert np.all(out.nis_t < t[0] + status.t_s)


def test_a_step_of_the_fixes_that_returns_is_not_a_divergence(setting):
    _, _, gnss, t, _ = setting
    stepped = gnss.p_local.copy()
    during = (gnss.t_valid > t[0] + 40.0) & (gnss.t_valid < t[0] + 52.0)
    stepped[during, 1] += 4.0  # a wrong ambiguity fix for 12 s
    res, (out, status) = _monitored(setting, stepped)
    assert status.status == "ok" and status.fix_steps >= 1
