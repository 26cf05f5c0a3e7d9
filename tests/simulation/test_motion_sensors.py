"""Recorded IMU and wheel odometry of the simulator against their own definitions: the gyro is the
true yaw rate plus the recorded true bias plus white noise of the stated std, the bias a constant
plus a random walk of the stated density; the odometry is the track speeds with slip, not the body
velocity; the tracker bags keep their bytes when the sensors are asked for; truth/ holds the bias."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import yaml

from simulation.campaign import simulate_campaign
from simulation.motion_sensors import ImuSpec, OdometrySpec, record_imu, record_odometry, true_bias


def _truth_track(n=60_001, dt=0.002):
    t = np.arange(n) * dt
    vx = 0.6 + 0.3 * np.sin(0.3 * t)
    vy = 0.01 * np.cos(t)
    omega = 0.5 * np.sin(0.2 * t) + 0.1 * np.cos(1.3 * t)
    t_ns = 1_671_615_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    return t, t_ns, vx, vy, omega


def test_gyro_is_yaw_rate_plus_bias_plus_white_noise_of_the_stated_std():
    t, t_ns, vx, vy, omega = _truth_track()
    spec = ImuSpec()
    s = record_imu(t_ns, vx, vy, omega, spec, np.random.default_rng(3))
    assert np.all(np.diff(s.t_ns) == 10_000_000)  # 100 Hz
    om = np.interp((s.t_ns - t_ns[0]) * 1e-9, t, omega)
    noise = s.wz - om - s.bias
    assert abs(noise.std() / spec.noise_std_rad_s - 1) < 0.03 and abs(noise.mean()) < 3 * spec.noise_std_rad_s / 60
    # bias: increments of the random walk with density q per sqrt(s), on a constant drawn per run
    inc = np.diff(s.bias)
    assert abs(inc.std() / (spec.bias_walk_rad_s_sqrt_s * np.sqrt(0.01)) - 1) < 0.03
    assert s.bias[0] != 0 and abs(s.bias[0]) < 5 * spec.bias_std_rad_s
    other = record_imu(t_ns, vx, vy, omega, spec, np.random.default_rng(4))
    assert abs(other.bias[0] - s.bias[0]) > 1e-4  # drawn per run


def test_odometry_is_the_track_speeds_with_slip_not_the_body_velocity():
    t, t_ns, vx, vy, omega = _truth_track()
    spec = OdometrySpec()
    s = record_odometry(t_ns, vx, omega, spec, np.random.default_rng(5))
    tt = (s.t_ns - t_ns[0]) * 1e-9
    v_true, om_true = np.interp(tt, t, vx), np.interp(tt, t, omega)
    slip = spec.slip_const + spec.slip_per_rad_s * np.abs(om_true)
    np.testing.assert_allclose(s.slip, slip)
    # hand computation: v = vx (1 + s), omega = omega (1 + s) (1 + width_error), plus noise
    np.testing.assert_allclose(s.v, v_true * (1 + slip), atol=5 * spec.stated_std[0])
    np.testing.assert_allclose(s.omega, om_true * (1 + slip) * (1 + spec.width_error), atol=5 * spec.stated_std[1])
    assert np.mean(s.v - v_true) > 0.01  # not the body velocity: slip makes it read fast
    res = s.v - v_true * (1 + slip)
    assert abs(res.std() / spec.stated_std[0] - 1) < 0.05


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    root = tmp_path_factory.mktemp("motion")
    simulate_campaign(root / "plain", seed=2, minutes=2.25)
    simulate_campaign(root / "with", seed=2, minutes=2.25, imu=True, odometry=OdometrySpec())
    return root / "plain", root / "with"


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_tracker_bags_keep_their_bytes_and_truth_holds_the_bias(twins):
    plain, withs = twins
    for bag in plain.glob("runs/*/*.bag"):
        assert _digest(bag) == _digest(withs / bag.relative_to(plain))
    assert sorted(p.name.split("_")[0] for p in (withs / "runs" / "run_01").iterdir()) == [
        "husky", "motion", "server"]
    meta = yaml.safe_load((withs / "campaign.yaml").read_text())
    assert [(s["name"], s["type"]) for s in meta["sensors"]] == [("imu", "sensor_msgs/Imu"),
                                                                  ("odometry", "nav_msgs/Odometry")]
    truth = yaml.safe_load((withs / "truth" / "motion_sensors.yaml").read_text())
    assert truth["imu"]["bias_std_rad_s"] == ImuSpec().bias_std_rad_s
    r = truth["runs"]["run_01"]["imu"]
    b = true_bias(truth, "run_01", r["t0_utc_ns"] * 1e-9 + np.array([0.0, 1.0, 1.5]))
    assert b[0] == r["bias_rad_s"][0] and b[2] == pytest.approx(0.5 * (r["bias_rad_s"][1] + r["bias_rad_s"][2]))
