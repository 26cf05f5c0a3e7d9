"""The seven-state EKF with gyro and wheel odometry: measurement Jacobians against central
differences at several headings, one gyro update against a hand computation, the six-state EKF
reproduced without gyro and odometry, the gyro bias estimated against the simulator's true bias,
and the gyro shrinking the position error at the end of a 30 s GNSS outage."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simulation.gnss import PROFILES, simulate_gnss
from simulation.motion_sensors import ImuSpec, OdometrySpec, record_imu, record_odometry
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf
from sindy_ekf.estimation.ekf_motion import (
    I_BIAS,
    N_Z,
    MotionSensors,
    OdometryNoise,
    _joseph,
    h_gnss7,
    h_gyro,
    h_odometry,
    run_ekf_motion,
)
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, inputs_at, simulate_truth, simulate_truths, truth_on

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2
HEADINGS = (-3.0, -1.2, 0.0, 0.7, 2.4)


def _central(h, z, eps=1e-6):
    J = np.zeros((len(h(z)[0]), z.size))
    for i in range(z.size):
        d = np.zeros(z.size)
        d[i] = eps
        J[:, i] = (h(z + d)[0] - h(z - d)[0]) / (2 * eps)
    return J


@pytest.mark.parametrize("psi", HEADINGS)
def test_measurement_jacobians_match_central_differences(psi):
    rng = np.random.default_rng(int(10 * psi) + 50)
    z = np.array([3.0, -2.0, psi, 0.8, 0.05, 0.4, 0.012]) + 0.1 * rng.standard_normal(N_Z)
    z[2] = psi
    lever = np.array([-0.2, 0.1])
    for h in (h_gyro, h_odometry, lambda q: h_gnss7(q, lever)):
        _, J = h(z)
        np.testing.assert_allclose(J, _central(h, z), atol=1e-8)
    assert h_gyro(z)[0][0] == pytest.approx(z[5] + z[I_BIAS])  # omega plus bias
    np.testing.assert_allclose(h_odometry(z)[0], [z[3], z[5]])


def test_one_gyro_update_against_a_hand_computation():
    z = np.array([0, 0, 0, 0.5, 0, 0.2, 0.01])
    P = np.diag([1.0, 1.0, 0.1, 0.04, 0.01, 0.04, 0.0004])
    wz, r = 0.25, 1e-4
    h, H = h_gyro(z)
    z1, P1, _ = _joseph(z, P, np.array([wz]) - h, H, np.array([[r]]))
    s = 0.04 + 0.0004 + r  # omega and bias uncorrelated: var(omega + b) + R
    y = wz - 0.21
    assert z1[5] == pytest.approx(0.2 + 0.04 / s * y)
    assert z1[I_BIAS] == pytest.approx(0.01 + 0.0004 / s * y)
    assert P1[5, I_BIAS] == pytest.approx(-0.04 * 0.0004 / s)
    assert P1[I_BIAS, I_BIAS] == pytest.approx(0.0004 - 0.0004 ** 2 / s)
    np.testing.assert_array_equal(z1[:5], z[:5])


@pytest.fixture(scope="module")
def oracle():
    model = ProcessModel(PolyBody(), name="oracle")
    return fit_process_noise(model, simulate_truths(model, 30.0, np.random.default_rng(100), n_runs=4))


def _run(oracle, seed, outages, duration_s=90.0):
    truth = simulate_truth(oracle, duration_s, np.random.default_rng(seed))
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2],
                         replace(PROFILES["dgnss"], outlier_prob=0.0), seed=seed, outages=outages)
    t = estimation_grid(truth.t, gnss.t_valid)
    return truth, gnss, t, inputs_at(truth, t)


def _imu(truth, seed, **kw):
    t_ns = np.round(truth.t * 1e9).astype(np.int64)
    spec = ImuSpec(**kw)
    s = record_imu(t_ns, truth.x6[:, 3], truth.x6[:, 4], truth.x6[:, 5], spec, np.random.default_rng(seed))
    return s, MotionSensors(t_gyro=s.t_ns * 1e-9, wz=s.wz, wz_std=np.full(s.wz.size, spec.noise_std_rad_s))


def test_without_gyro_and_odometry_it_is_the_six_state_ekf(oracle):
    truth, gnss, t, u = _run(oracle, 7, np.array([[1030.0, 1040.0]]), duration_s=50.0)
    six = run_ekf(oracle, t, u, truth.x6[0], P0, gnss)
    seven = run_ekf_motion(oracle, EkfRun("r", t, u, truth.x6[0], P0, gnss), MotionSensors())
    np.testing.assert_allclose(seven.x, six.x, atol=1e-8)
    np.testing.assert_allclose(seven.P, six.P, atol=1e-10)
    np.testing.assert_array_equal(seven.accepted, six.accepted)
    # the innovations the NIS monitor's step test reads, as the six-state EKF records them
    np.testing.assert_allclose(seven.innovation, six.innovation, atol=1e-8)
    np.testing.assert_allclose(seven.innovation_cov, six.innovation_cov, atol=1e-10)
    assert len(seven.innovation) == len(seven.nis) > 100


@pytest.mark.parametrize("seed", [11, 12])
def test_gyro_bias_estimated_against_the_true_bias(oracle, seed):
    truth, gnss, t, u = _run(oracle, seed, np.empty((0, 2)))
    imu, sensors = _imu(truth, seed, bias_rad_s=0.02 * (-1) ** seed)
    res = run_ekf_motion(oracle, EkfRun("r", t, u, truth.x6[0], P0, gnss), sensors)
    assert res.n_gyro > 0.9 * len(t)
    t_imu = imu.t_ns * 1e-9
    late = t > t[0] + 30.0  # after the bias has been learnt
    b_true = np.interp(t[late], t_imu, imu.bias)
    err = res.gyro_bias[late] - b_true
    assert np.sqrt(np.mean(err ** 2)) < 0.15 * 0.02
    assert np.mean(np.abs(err) < 3 * res.gyro_bias_std[late]) > 0.95
    assert res.gyro_bias_std[-1] < 0.25 * 0.02  # from the 0.02 rad/s prior (the assumed walk keeps it open)


def test_gyro_shrinks_the_error_at_the_end_of_a_30_s_outage(oracle):
    """RMS over four seeds (one outage each, after 70 s of GNSS to learn the bias) of the position error
    at the outage's end: the gyro's less than 0.6 of the GNSS-only filter's (0.34 when written)."""
    ends = []
    for seed in (21, 22, 23, 24):
        truth, gnss, t, u = _run(oracle, seed, np.array([[1070.0, 1100.0]]), duration_s=101.0)
        _, sensors = _imu(truth, seed)
        run = EkfRun("r", t, u, truth.x6[0], P0, gnss)
        k = np.searchsorted(t, 1100.0 - 1e-9) - 1  # last step of the outage
        ref = truth_on(truth, t[k:k + 1])[0]
        ends.append([float(np.hypot(*(res.x[k, :2] - ref[:2])))
                     for res in (run_ekf_motion(oracle, run, MotionSensors()), run_ekf_motion(oracle, run, sensors))])
    gnss_only, with_gyro = np.sqrt(np.mean(np.square(ends), axis=0))
    assert with_gyro < 0.6 * gnss_only, ends


def test_odometry_is_fused_and_keeps_the_filter_near_truth(oracle):
    truth, gnss, t, u = _run(oracle, 31, np.array([[1040.0, 1070.0]]), duration_s=75.0)
    spec = OdometrySpec(slip_const=0.0, slip_per_rad_s=0.0, width_error=0.0)
    od = record_odometry(np.round(truth.t * 1e9).astype(np.int64), truth.x6[:, 3], truth.x6[:, 5], spec,
                         np.random.default_rng(3))
    sensors = MotionSensors(t_odometry=od.t_ns * 1e-9, v_omega=np.column_stack([od.v, od.omega]),
                            v_omega_std=np.tile(od.std, (od.v.size, 1)))
    run = EkfRun("r", t, u, truth.x6[0], P0, gnss)
    res = run_ekf_motion(oracle, run, sensors, odometry_noise=OdometryNoise(scale_std=0.0))
    plain = run_ekf_motion(oracle, run, MotionSensors())
    ref = truth_on(truth, t)
    v_err = np.sqrt(np.mean((res.x[:, 3] - ref[:, 3]) ** 2))
    assert res.n_odometry > 0.9 * len(t)
    assert v_err < 0.5 * np.sqrt(np.mean((plain.x[:, 3] - ref[:, 3]) ** 2))
