"""What the seven-state EKF and the batch graph assume of the gyro and the wheel odometry
(``GyroNoise``, ``OdometryNoise``; the ``imu`` and ``odometry`` settings of ``filters.yaml``):
each value against a hand computation (one update at the first step, the bias variance growing by
``q^2 dt`` without measurements, the graph's factor sigmas), a much larger assumed noise bringing the
filter to the GNSS-only one, and a sample's stated std winning over the assumed one."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from simulation.motion_sensors import OdometrySpec, record_odometry
from sindy_ekf.estimation.ekf import EkfRun
from sindy_ekf.estimation.ekf_motion import (
    BIAS_STD_RAD_S,
    BIAS_WALK_RAD_S_SQRT_S,
    GYRO_STD_RAD_S,
    ODOMETRY_SCALE_STD,
    ODOMETRY_STD,
    GyroNoise,
    MotionSensors,
    OdometryNoise,
    run_ekf_motion,
)
from sindy_ekf.estimation.graph import FREE_SIGMA
from sindy_ekf.estimation.graph_motion import BIAS_SEGMENT_S, add_motion_factors
from tests.sindy_ekf.estimation.test_ekf_motion import P0, _imu, _run, oracle  # noqa: F401 (a fixture)

GYRO = GyroNoise(rate_std_rad_s=0.03, bias_std_rad_s=0.007, bias_walk_rad_s_sqrt_s=0.002)
ODOMETRY = OdometryNoise(v_std_m_s=0.07, omega_std_rad_s=0.11, scale_std=0.2)


def test_the_defaults_are_the_former_constants():
    assert GyroNoise() == GyroNoise(GYRO_STD_RAD_S, BIAS_STD_RAD_S, BIAS_WALK_RAD_S_SQRT_S)
    assert OdometryNoise() == OdometryNoise(*ODOMETRY_STD, ODOMETRY_SCALE_STD)
    assert (GYRO_STD_RAD_S, BIAS_STD_RAD_S, BIAS_WALK_RAD_S_SQRT_S) == (0.01, 0.02, 4e-4)
    assert (ODOMETRY_STD, ODOMETRY_SCALE_STD) == ((0.05, 0.05), 0.05)


def test_gyro_noise_by_hand_one_update_then_the_bias_walk(oracle):
    """One gyro sample at the first step (no stated std) and nothing after it, no GNSS: the first
    update weighs the sample with ``rate_std^2`` against ``var(omega) + bias_std^2``; afterwards the
    bias variance grows by exactly ``q^2 dt`` per step (nothing else enters its row)."""
    truth, _, t, u = _run(oracle, 41, np.empty((0, 2)), duration_s=4.0)
    wz = 0.3
    sensors = MotionSensors(t_gyro=t[:1], wz=np.array([wz]))
    x0 = truth.x6[0]
    res = run_ekf_motion(oracle, EkfRun("r", t, u, x0, P0, None), sensors, gyro_noise=GYRO)
    p_w, p_b, r = P0[5, 5], GYRO.bias_std_rad_s ** 2, GYRO.rate_std_rad_s ** 2
    s = p_w + p_b + r
    assert res.n_gyro == 1
    assert res.P[0, 5, 5] == pytest.approx(p_w - p_w ** 2 / s, rel=1e-12)
    assert res.gyro_bias_std[0] ** 2 == pytest.approx(p_b - p_b ** 2 / s, rel=1e-12)
    assert res.gyro_bias[0] == pytest.approx(p_b / s * (wz - x0[5]), rel=1e-12)
    grown = res.gyro_bias_std ** 2 - res.gyro_bias_std[0] ** 2
    np.testing.assert_allclose(grown, GYRO.bias_walk_rad_s_sqrt_s ** 2 * (t - t[0]), rtol=1e-9, atol=1e-18)


def test_odometry_noise_by_hand_one_update(oracle):
    """One odometry sample at the first step (no stated std): ``v`` and ``omega`` weighed with the
    assumed std plus the relative scale std of the measured value (``P0`` is diagonal: two scalar updates)."""
    truth, _, t, u = _run(oracle, 42, np.empty((0, 2)), duration_s=4.0)
    v, omega = 0.8, 0.3
    sensors = MotionSensors(t_odometry=t[:1], v_omega=np.array([[v, omega]]))
    x0 = truth.x6[0]
    res = run_ekf_motion(oracle, EkfRun("r", t, u, x0, P0, None), sensors, odometry_noise=ODOMETRY)
    r_v = ODOMETRY.v_std_m_s ** 2 + (ODOMETRY.scale_std * v) ** 2
    r_w = ODOMETRY.omega_std_rad_s ** 2 + (ODOMETRY.scale_std * omega) ** 2
    for i, r, z in ((3, r_v, v), (5, r_w, omega)):
        p = P0[i, i]
        assert res.P[0, i, i] == pytest.approx(p - p ** 2 / (p + r), rel=1e-12)
        assert res.x[0, i] == pytest.approx(x0[i] + p / (p + r) * (z - x0[i]), rel=1e-12)


def _sensors(truth, seed: int, kind: str, stated: bool) -> MotionSensors:
    """Return the simulator's gyro or (slip-free) odometry of ``truth``, with or without the stated std."""
    if kind == "imu":
        _, s = _imu(truth, seed)
        return s if stated else MotionSensors(t_gyro=s.t_gyro, wz=s.wz)
    od = record_odometry(np.round(truth.t * 1e9).astype(np.int64), truth.x6[:, 3], truth.x6[:, 5],
                         OdometrySpec(slip_const=0.0, slip_per_rad_s=0.0, width_error=0.0), np.random.default_rng(seed))
    std = np.tile(od.std, (od.v.size, 1)) if stated else None
    return MotionSensors(t_odometry=od.t_ns * 1e-9, v_omega=np.column_stack([od.v, od.omega]), v_omega_std=std)


LOUD = {"imu": {"gyro_noise": GyroNoise(rate_std_rad_s=100.0)},
        "odometry": {"odometry_noise": OdometryNoise(v_std_m_s=100.0, omega_std_rad_s=100.0, scale_std=0.0)}}
# only what stands in for a missing stated std changed (the odometry's relative scale std adds to either)
FALLBACK = {"imu": LOUD["imu"], "odometry": {"odometry_noise": OdometryNoise(v_std_m_s=100.0, omega_std_rad_s=100.0)}}


@pytest.mark.parametrize("kind", ["imu", "odometry"])
def test_a_much_larger_assumed_noise_brings_the_filter_to_the_gnss_only_one(oracle, kind):
    """A 20 s outage: with the default noise the sensor moves the estimate by decimetres; assumed
    10^4 times noisier it moves it by less than 1 % of that (the seven-state filter without motion
    sensors is the six-state EKF, test_ekf_motion). Where the samples state their std, the assumed
    noise does not enter."""
    truth, gnss, t, u = _run(oracle, 43, np.array([[1025.0, 1045.0]]), duration_s=50.0)
    run = EkfRun("r", t, u, truth.x6[0], P0, gnss)
    sensors = _sensors(truth, 43, kind, stated=False)
    gnss_only = run_ekf_motion(oracle, run, MotionSensors()).x

    def moved(**noise) -> float:
        return float(np.max(np.hypot(*(run_ekf_motion(oracle, run, sensors, **noise).x - gnss_only)[:, :2].T)))

    by_default, loud = moved(), moved(**LOUD[kind])
    assert by_default > 0.05, by_default  # the sensor matters here
    assert loud < 0.01 * by_default, (loud, by_default)
    stated = _sensors(truth, 43, kind, stated=True)
    np.testing.assert_array_equal(run_ekf_motion(oracle, run, stated, **FALLBACK[kind]).x,
                                  run_ekf_motion(oracle, run, stated).x)


def test_the_graph_factors_carry_the_assumed_noise():
    """Bias prior, random walk over one segment, gyro factor and odometry prior: their sigmas by hand
    (one sample per grid step, no stated std)."""
    t = 1000.0 + np.arange(0.0, 2.5, 0.02)
    v, omega = 0.6, -0.4
    sensors = MotionSensors(t_gyro=t[:1], wz=np.array([0.1]), t_odometry=t[1:2], v_omega=np.array([[v, omega]]))
    graph = gtsam.NonlinearFactorGraph()
    n_bias = add_motion_factors(graph, t, sensors, GYRO, ODOMETRY)
    assert n_bias == 3
    sigmas = {(type(f).__name__, tuple(gtsam.DefaultKeyFormatter(k) for k in f.keys())): f.noiseModel().sigmas()
              for f in (graph.at(i) for i in range(graph.size()))}
    np.testing.assert_allclose(sigmas["PriorFactorVector", ("b0",)], [GYRO.bias_std_rad_s], rtol=1e-12)
    walk = GYRO.bias_walk_rad_s_sqrt_s * np.sqrt(BIAS_SEGMENT_S)
    np.testing.assert_allclose(sigmas["BetweenFactorVector", ("b0", "b1")], [walk], rtol=1e-12)
    np.testing.assert_allclose(sigmas["CustomFactor", ("v0", "b0")], [GYRO.rate_std_rad_s], rtol=1e-12)
    np.testing.assert_allclose(sigmas["PriorFactorVector", ("v1",)],
                               [np.hypot(ODOMETRY.v_std_m_s, ODOMETRY.scale_std * v), FREE_SIGMA,
                                np.hypot(ODOMETRY.omega_std_rad_s, ODOMETRY.scale_std * omega)], rtol=1e-12)
