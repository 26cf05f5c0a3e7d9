"""Factor graph with the gyro (bias variables) and wheel odometry: the gyro factor's Jacobians
against central differences, the bias variables against the simulator's true bias, the smoother
below its own filter's error, and Levenberg-Marquardt damping the 1-dof bias variables."""

from __future__ import annotations

import numpy as np
import pytest

from sindy_ekf.estimation.ekf import EkfRun
from sindy_ekf.estimation.ekf_motion import run_ekf_motion
from sindy_ekf.estimation.graph_motion import BIAS_SEGMENT_S, gyro_error, smooth_batch_motion
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.sindy_ekf.estimation.test_ekf_motion import P0, _imu, _run
from tests.support.estimation_helpers import PolyBody, simulate_truths, truth_on


@pytest.mark.parametrize("omega", [-0.8, 0.0, 0.5])
def test_gyro_factor_jacobians_match_central_differences(omega):
    v, b, wz, eps = np.array([0.7, -0.02, omega]), np.array([0.013]), 0.3, 1e-6
    e, J_v, J_b = gyro_error(v, b, wz)
    assert e[0] == pytest.approx(omega + 0.013 - wz)
    num_v = np.array([(gyro_error(v + d, b, wz)[0] - gyro_error(v - d, b, wz)[0]) / (2 * eps)
                      for d in np.eye(3) * eps]).T
    num_b = (gyro_error(v, b + eps, wz)[0] - gyro_error(v, b - eps, wz)[0])[:, None] / (2 * eps)
    np.testing.assert_allclose(J_v, num_v, atol=1e-9)
    np.testing.assert_allclose(J_b, num_b, atol=1e-9)


def test_graph_bias_against_truth_and_below_its_filter():
    model = ProcessModel(PolyBody(), name="oracle")
    oracle = fit_process_noise(model, simulate_truths(model, 30.0, np.random.default_rng(100), n_runs=4))
    truth, gnss, t, u = _run(oracle, 21, np.array([[1030.0, 1060.0]]), duration_s=70.0)
    imu, sensors = _imu(truth, 21, bias_rad_s=0.02)
    ekf = run_ekf_motion(oracle, EkfRun("r", t, u, truth.x6[0], P0, gnss), sensors)
    g = smooth_batch_motion(oracle, t, u, truth.x6[0], P0, gnss, sensors, ekf.x, marginal_stride=None)
    assert g.iterations >= 1 and g.error_final < g.error_initial
    ref = truth_on(truth, t)

    def rms(x):
        return float(np.sqrt(np.mean(np.sum((x[:, :2] - ref[:, :2]) ** 2, axis=1))))

    assert rms(g.x) < 0.5 * rms(ekf.x)  # the smoother sees both ends of the outage
    assert np.isfinite(g.P[-1]).all() and np.all(np.linalg.eigvalsh(g.P[-1]) > 0)
    t_bias = t[0] + np.arange(g.gyro_bias.size) * BIAS_SEGMENT_S
    err = g.gyro_bias - np.interp(t_bias, imu.t_ns * 1e-9, imu.bias)
    assert np.sqrt(np.mean(err ** 2)) < 0.15 * 0.02  # the true bias: 0.02 rad/s plus its walk
