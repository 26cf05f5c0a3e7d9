"""The ``imu`` and ``odometry`` settings of an estimator reach its seven-state EKF, its batch graph
and iSAM2 (issue 16): a benchmark run with them changed gives what the estimator's API called
directly with that noise gives, and that differs from the default noise (the setting matters on
this campaign, whose imu.csv / odometry.csv state no std, so the assumed one applies)."""

from __future__ import annotations

import numpy as np
import pytest

from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
from sindy_ekf.benchmark.motion_source import motion_sensors_of
from sindy_ekf.benchmark.run import _prepare_run, fit_models, train_series
from sindy_ekf.estimation.ekf import EkfRun
from sindy_ekf.estimation.ekf_motion import GyroNoise, OdometryNoise, run_ekf_motion
from sindy_ekf.estimation.graph_motion import smooth_batch_motion, smooth_isam2_motion
from tests.sindy_ekf.benchmark.test_benchmark_config import P0, RECOVERY_S, SEED, WARMUP_S, _bench

GYRO = {"rate_std_rad_s": 0.2, "bias_std_rad_s": 0.05, "bias_walk_rad_s_sqrt_s": 0.003}
ODOMETRY = {"v_std_m_s": 0.4, "omega_std_rad_s": 0.3, "scale_std": 0.0}


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """The mini campaign of test_benchmark_config with the simulator's gyro and odometry on every run."""
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from identification.sindy.model import model_from_terms
    from simulation.robot import RobotParams
    from tests.support.trajectory_synth import write_mini_campaign

    root = write_mini_campaign(tmp_path_factory.mktemp("bench_motion") / "mini", motion_sensors=True)
    return read_trajectory_campaign(root), model_from_terms(RobotParams().terms())


def _direct(mini, kinds: tuple[str, ...]):
    """Return the test run prepared as the benchmark does, the fitted SINDy process model and its sensors."""
    campaign, model = mini
    train = campaign.split("train")
    pm = fit_models(train, model, series=train_series(train))["sindy_ekf"]
    r = _prepare_run(campaign.split("test")[0], "dgnss", SEED, None, DEFAULT_SMOOTHING, WARMUP_S, RECOVERY_S)
    return r, pm, motion_sensors_of(campaign, r.name, r.t_pose, kinds)


def _ekf(r, pm, sensors, **noise):
    return run_ekf_motion(pm, EkfRun("direct", r.grid, r.u, r.x0, P0, r.gnss), sensors, **noise)


@pytest.mark.parametrize("kind, setting, noise", [
    ("imu", GYRO, {"gyro_noise": GyroNoise(**GYRO)}),
    ("odometry", ODOMETRY, {"odometry_noise": OdometryNoise(**ODOMETRY)}),
])
def test_the_sensor_noise_reaches_the_seven_state_ekf(mini, kind, setting, noise):
    result = _bench(mini, {"estimators": {"sindy_ekf": {"sensors": ["gnss", kind], kind: setting}}})
    r, pm, sensors = _direct(mini, (kind,))
    res, default = _ekf(r, pm, sensors, **noise), _ekf(r, pm, sensors)
    assert np.max(np.abs(res.x[:, :2] - default.x[:, :2])) > 0.01  # the setting matters here
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, res.x[r.at_pose])
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].P, res.P[r.at_pose])


def test_the_sensor_noise_reaches_the_batch_graph_and_its_starting_ekf(mini):
    result = _bench(mini, {"estimators": {"sindy_graph": {"sensors": ["gnss", "imu", "odometry"],
                                                          "imu": GYRO, "odometry": ODOMETRY}}}, run=("sindy_graph",))
    r, pm, sensors = _direct(mini, ("imu", "odometry"))
    noise = {"gyro_noise": GyroNoise(**GYRO), "odometry_noise": OdometryNoise(**ODOMETRY)}
    g = smooth_batch_motion(pm, r.grid, r.u, r.x0, P0, r.gnss, sensors, _ekf(r, pm, sensors, **noise).x,
                            marginal_stride=10, **noise)
    default = smooth_batch_motion(pm, r.grid, r.u, r.x0, P0, r.gnss, sensors, _ekf(r, pm, sensors).x,
                                  marginal_stride=10)
    assert np.max(np.abs(g.x[:, :2] - default.x[:, :2])) > 0.01  # the setting matters here
    assert np.array_equal(result.estimates["sindy_graph"]["run_c"].x, g.x[r.at_pose])


def test_the_sensors_and_their_noise_reach_isam2(mini):
    result = _bench(mini, {"estimators": {"sindy_isam2": {"enabled": True, "sensors": ["gnss", "imu", "odometry"],
                                                          "imu": GYRO, "odometry": ODOMETRY}}}, run=("sindy_isam2",))
    r, pm, sensors = _direct(mini, ("imu", "odometry"))
    noise = {"gyro_noise": GyroNoise(**GYRO), "odometry_noise": OdometryNoise(**ODOMETRY)}
    isam = smooth_isam2_motion(pm, r.grid, r.u, r.x0, P0, r.gnss, sensors, **noise)
    default = smooth_isam2_motion(pm, r.grid, r.u, r.x0, P0, r.gnss, sensors)
    assert np.max(np.abs(isam.x[:, :2] - default.x[:, :2])) > 0.01  # the setting matters here
    assert np.array_equal(result.estimates["sindy_isam2"]["run_c"].x, isam.x[r.at_pose])
