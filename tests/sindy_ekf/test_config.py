"""The filter settings file (issue 16 item 3): the shipped defaults hold exactly the code's
constants, a user file changes only what it gives and round-trips through the JSON record, and
every kind of bad file is a one-line InputError naming the file and the dotted key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from simulation.gnss import OUTAGE_DURATIONS_S, GnssProfile
from sindy_ekf.benchmark.run import ESTIMATORS, LATERAL_EVERY, OPTIONAL_ESTIMATORS, P0_STD
from sindy_ekf.config import config_from_dict, defaults_text, load_config
from sindy_ekf.estimation.ekf import GATE_PROB
from sindy_ekf.estimation.ekf_motion import GyroNoise, OdometryNoise

SHIPPED = Path(__file__).resolve().parents[2] / "sindy_ekf" / "data" / "filters.yaml"


def _write(tmp_path, text: str, name: str = "filters.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_shipped_defaults_are_the_code_constants():
    c = load_config()
    assert defaults_text() == SHIPPED.read_text()
    assert c.gnss.profile == "dgnss" and c.gnss.seed == 0
    assert c.gnss.outages.durations_s == OUTAGE_DURATIONS_S
    assert (c.gnss.outages.warmup_s, c.gnss.outages.recovery_s) == (30.0, 30.0)
    assert set(c.names()) == set(ESTIMATORS + OPTIONAL_ESTIMATORS)
    assert set(c.enabled()) == set(ESTIMATORS)
    for e in c.estimators:
        assert np.array_equal(e.P0, np.diag(P0_STD ** 2)), e.name  # bitwise: same floats
        assert e.process_noise == "fit" and e.Q_rate is None
        assert e.gate_prob in (None, GATE_PROB)
        assert e.lateral is None or (e.lateral.every == LATERAL_EVERY and e.lateral.vy_std_m_s is None
                                     and e.lateral.enabled == e.name.endswith("_lateral"))
        assert e.sensors in (None, ("gnss",))
        # the gyro / odometry noise of every estimator that can fuse them: the former constants
        assert e.imu in (None, GyroNoise()) and e.odometry in (None, OdometryNoise()), e.name
        assert (e.imu is None) == (e.odometry is None) == (e.sensors is None), e.name
    # a factor graph has no gate, dead reckoning no sensor and no constraint
    assert c.estimator("sindy_graph").gate_prob is None and c.estimator("sindy_isam2").lateral is None
    assert c.estimator("dead_reckoning").sensors is None and not c.estimator("dead_reckoning").fuses_gnss


def test_a_file_changes_only_what_it_gives(tmp_path):
    path = _write(tmp_path, "estimators:\n  sindy_ekf:\n    gate_prob: 0.9\n    lateral: {every: 4}\n"
                            "gnss:\n  outages: {warmup_s: 12}\n")
    c, d = load_config(path), load_config()
    e = c.estimator("sindy_ekf")
    assert e.gate_prob == 0.9 and e.lateral.every == 4
    assert e.lateral.enabled is False and e.lateral.vy_std_m_s is None  # the rest of the mapping kept
    assert c.gnss.outages == dataclasses.replace(d.gnss.outages, warmup_s=12.0)
    assert [x for x in c.estimators if x.name != "sindy_ekf"] == [x for x in d.estimators if x.name != "sindy_ekf"]
    assert c.source == str(path)
    assert load_config(_write(tmp_path, "", "empty.yaml")).estimators == d.estimators  # empty: nothing changed


def test_sensor_noise_changes_only_the_values_given():
    c = config_from_dict({"estimators": {"sindy_ekf": {"imu": {"rate_std_rad_s": 0.5}},
                                         "sindy_graph": {"odometry": {"scale_std": 0, "v_std_m_s": 2}}}}, "f")
    assert c.estimator("sindy_ekf").imu == GyroNoise(rate_std_rad_s=0.5)
    assert c.estimator("sindy_ekf").odometry == OdometryNoise()
    assert c.estimator("sindy_graph").odometry == OdometryNoise(v_std_m_s=2.0, scale_std=0.0)
    assert c.estimator("sindy_ekf_lateral").imu == GyroNoise()  # per estimator
    isam2 = config_from_dict({"estimators": {"sindy_isam2": {"sensors": ["gnss", "imu", "odometry"],
                                                             "imu": {"bias_std_rad_s": 0.1}}}}, "f")
    assert isam2.estimator("sindy_isam2").motion_sensors == ("imu", "odometry")
    assert isam2.estimator("sindy_isam2").imu == GyroNoise(bias_std_rad_s=0.1)


def test_process_noise_forms_give_the_density_matrix():
    std = [0.01, 0.02, 0.003, 0.4, 0.5, 0.06]
    q = np.diag(np.square(std)) + 1e-5 * (np.ones((6, 6)) - np.eye(6))
    vec = config_from_dict({"estimators": {"cv_ekf": {"process_noise": std}}}, "f").estimator("cv_ekf")
    mat = config_from_dict({"estimators": {"cv_ekf": {"process_noise": q.tolist()}}}, "f").estimator("cv_ekf")
    assert np.array_equal(vec.Q_rate, np.diag(np.square(std)))
    assert np.array_equal(mat.Q_rate, q)


def test_the_recorded_settings_load_back_equal():
    custom = {"name": "mybox", "rate_hz": 2, "std_m": 0.4, "std_up_m": 0.8, "latency_s": 0.3,
              "latency_jitter_s": 0.0, "outlier_m": [1, 2]}
    data = {"gnss": {"profile": custom, "seed": 4, "outages": {"durations_s": []}},
            "estimators": {"sindy_ekf": {"process_noise": np.eye(6).tolist(), "sensors": [],
                                         "imu": {"bias_walk_rad_s_sqrt_s": 1e-3}, "odometry": {"scale_std": 0}},
                           "cv_ekf": {"process_noise": [1, 2, 3, 4, 5, 6]},
                           "sindy_graph": {"lateral": {"enabled": True, "vy_std_m_s": 0.07}}}}
    c = config_from_dict(data, "a.yaml")
    assert c.gnss.profile == GnssProfile("mybox", 2.0, 0.4, 0.8, 0.3, 0.0, outlier_m=(1.0, 2.0))
    back = config_from_dict(yaml.safe_load(yaml.safe_dump(c.to_dict())), "b.yaml")
    assert dataclasses.replace(back, source="a.yaml") == c


def test_command_line_overrides_win_and_are_recorded():
    c = config_from_dict({"estimators": {"cv_ekf": {"enabled": False}}}, "f")
    o = c.with_overrides(profile="rtk", seed=7, estimators=("cv_ekf", "sindy_ekf"))
    assert o.enabled() == ("cv_ekf", "sindy_ekf")
    assert o.to_dict()["gnss"]["profile"] == "rtk" and o.to_dict()["gnss"]["seed"] == 7
    assert o.estimator("cv_ekf").gate_prob == GATE_PROB


# --- bad files: one line naming the file and the key -------------------------------------------

BAD = [  # (file text, the dotted key the message must name, a fragment of the cause)
    ("estimators:\n  sindy_ekf:\n    gate_prob: high\n", "estimators.sindy_ekf.gate_prob", "(0, 1]"),
    ("estimators:\n  sindy_ekf:\n    gate_prob: 0\n", "estimators.sindy_ekf.gate_prob", "(0, 1]"),
    ("estimators:\n  sindy_ekf:\n    gate_prob: 1.5\n", "estimators.sindy_ekf.gate_prob", "got 1.5"),
    ("estimators:\n  sindy_ekf:\n    gate_prob: true\n", "estimators.sindy_ekf.gate_prob", "got True"),
    ("estimators:\n  sindy_ekf:\n    gate: 0.9\n", "estimators.sindy_ekf.gate", "unknown key"),
    ("estimators:\n  sindy_graph:\n    gate_prob: 0.9\n", "estimators.sindy_graph.gate_prob", "unknown key"),
    ("estimators:\n  dead_reckoning:\n    sensors: [gnss]\n", "estimators.dead_reckoning.sensors", "unknown key"),
    ("estimators:\n  kalman:\n    enabled: true\n", "estimators.kalman", "unknown estimator"),
    ("estimators:\n  sindy_ekf:\n    enabled: yes please\n", "estimators.sindy_ekf.enabled", "true or false"),
    ("estimators:\n  sindy_ekf:\n    initial_std: [1, 2, 3]\n", "estimators.sindy_ekf.initial_std", "6 numbers"),
    ("estimators:\n  sindy_ekf:\n    initial_std: [1, 1, 1, 1, 1, 0]\n", "estimators.sindy_ekf.initial_std", "> 0"),
    ("estimators:\n  sindy_ekf:\n    initial_std: [1, 1, 1, 1, 1, .nan]\n", "estimators.sindy_ekf.initial_std", "nan"),
    ("estimators:\n  sindy_ekf:\n    process_noise: fitted\n", "estimators.sindy_ekf.process_noise", "fit,"),
    ("estimators:\n  sindy_ekf:\n    process_noise: [[1, 0], [0, 1]]\n", "estimators.sindy_ekf.process_noise",
     "got [[1, 0], [0, 1]]"),
    ("estimators:\n  sindy_ekf:\n    process_noise: " + str((-np.eye(6)).tolist()) + "\n",
     "estimators.sindy_ekf.process_noise", "positive definite"),
    ("estimators:\n  sindy_ekf:\n    process_noise: " + str((np.eye(6) + np.eye(6, k=1)).tolist()) + "\n",
     "estimators.sindy_ekf.process_noise", "symmetric"),
    ("estimators:\n  sindy_ekf:\n    lateral: true\n", "estimators.sindy_ekf.lateral", "a mapping"),
    ("estimators:\n  sindy_ekf:\n    lateral: {every: 0}\n", "estimators.sindy_ekf.lateral.every", "integer >= 1"),
    ("estimators:\n  sindy_ekf:\n    lateral: {every: 2.5}\n", "estimators.sindy_ekf.lateral.every", "got 2.5"),
    ("estimators:\n  sindy_ekf:\n    lateral: {vy_std_m_s: -1}\n", "estimators.sindy_ekf.lateral.vy_std_m_s", "> 0"),
    ("estimators:\n  sindy_ekf:\n    lateral: {on: true}\n", "estimators.sindy_ekf.lateral", "key True is not a name"),
    ("estimators:\n  sindy_ekf:\n    sensors: [lidar]\n", "estimators.sindy_ekf.sensors", "unknown sensor 'lidar'"),
    ("estimators:\n  sindy_ekf:\n    sensors: gnss\n", "estimators.sindy_ekf.sensors", "a list"),
    ("estimators:\n  sindy_ekf:\n    sensors: [gnss, gnss]\n", "estimators.sindy_ekf.sensors", "twice"),
    ("estimators:\n  sindy_ekf:\n    imu: {rate_std_rad_s: 0}\n", "estimators.sindy_ekf.imu.rate_std_rad_s",
     "a number > 0, got 0"),
    ("estimators:\n  sindy_ekf:\n    imu: {bias_std_rad_s: -0.01}\n", "estimators.sindy_ekf.imu.bias_std_rad_s",
     "a number > 0"),
    ("estimators:\n  sindy_graph:\n    imu: {bias_walk_rad_s_sqrt_s: slow}\n",
     "estimators.sindy_graph.imu.bias_walk_rad_s_sqrt_s", "got 'slow'"),
    ("estimators:\n  sindy_ekf:\n    imu: {bias_walk_rad_s_sqrt_s: .inf}\n",
     "estimators.sindy_ekf.imu.bias_walk_rad_s_sqrt_s", "got inf"),
    ("estimators:\n  sindy_ekf:\n    imu: {accel_std: 0.1}\n", "estimators.sindy_ekf.imu.accel_std",
     "unknown key (imu takes rate_std_rad_s, bias_std_rad_s, bias_walk_rad_s_sqrt_s)"),
    ("estimators:\n  sindy_ekf:\n    imu: 0.01\n", "estimators.sindy_ekf.imu", "a mapping"),
    ("estimators:\n  cv_ekf:\n    odometry: {v_std_m_s: 0.0}\n", "estimators.cv_ekf.odometry.v_std_m_s", "> 0"),
    ("estimators:\n  sindy_ekf:\n    odometry: {omega_std_rad_s: [0.1]}\n",
     "estimators.sindy_ekf.odometry.omega_std_rad_s", "a number > 0"),
    ("estimators:\n  sindy_ekf:\n    odometry: {scale_std: -0.05}\n", "estimators.sindy_ekf.odometry.scale_std",
     "a number >= 0"),
    ("estimators:\n  sindy_ekf:\n    odometry: {scale_std: true}\n", "estimators.sindy_ekf.odometry.scale_std",
     "got True"),
    ("estimators:\n  sindy_ekf:\n    odometry: {track_width: 0.5}\n", "estimators.sindy_ekf.odometry.track_width",
     "unknown key (odometry takes v_std_m_s, omega_std_rad_s, scale_std)"),
    ("estimators:\n  dead_reckoning:\n    imu: {rate_std_rad_s: 0.1}\n", "estimators.dead_reckoning.imu",
     "unknown key"),
    ("gnss:\n  profile: galileo\n", "gnss.profile", "unknown GNSS profile 'galileo'"),
    ("gnss:\n  profile: [dgnss]\n", "gnss.profile", "a profile name"),
    ("gnss:\n  profile: {rate_hz: 2, std_m: 0.3}\n", "gnss.profile.std_up_m", "missing"),
    ("gnss:\n  profile: {rate_hz: 0, std_m: 1, std_up_m: 1, latency_s: 0, latency_jitter_s: 0}\n",
     "gnss.profile.rate_hz", "> 0"),
    ("gnss:\n  profile: {rate_hz: 1, std_m: 1, std_up_m: 1, latency_s: 0, latency_jitter_s: 0, colour: red}\n",
     "gnss.profile.colour", "unknown key"),
    ("gnss:\n  profile: {rate_hz: 1, std_m: 1, std_up_m: 1, latency_s: 0, latency_jitter_s: 0, outlier_m: [3, 1]}\n",
     "gnss.profile.outlier_m", "low <= high"),
    ("gnss:\n  seed: -1\n", "gnss.seed", "integer >= 0"),
    ("gnss:\n  outages: {durations_s: [5, -1]}\n", "gnss.outages.durations_s", "> 0"),
    ("gnss:\n  outages: {warmup_s: soon}\n", "gnss.outages.warmup_s", "'soon'"),
    ("gnss:\n  outage: {warmup_s: 3}\n", "gnss.outage", "unknown key"),
    ("filters:\n  sindy_ekf: {}\n", "filters", "unknown key"),
    ("- gnss\n", "top level", "a mapping"),
    ("estimators:\n  sindy_ekf: 3\n", "estimators.sindy_ekf", "a mapping"),
]


def _one_line(exc: pytest.ExceptionInfo, *parts: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg, msg
    for part in parts:
        assert part in msg, (part, msg)
    return msg


@pytest.mark.parametrize("text, key, cause", BAD, ids=[b[1] + ":" + b[2] for b in BAD])
def test_a_bad_value_is_one_line_naming_file_and_key(tmp_path, text, key, cause):
    path = _write(tmp_path, text, "my_filters.yaml")
    with pytest.raises(InputError) as exc:
        load_config(path)
    msg = _one_line(exc, cause)
    assert msg.startswith(f"{path}: {key}: "), msg


def test_malformed_yaml_names_the_file_and_line(tmp_path):
    path = _write(tmp_path, "gnss:\n  profile: dgnss\n estimators: [\n")
    with pytest.raises(InputError) as exc:
        load_config(path)
    _one_line(exc, str(path), "not valid YAML", "line 3")


def test_a_key_given_twice_is_an_error(tmp_path):
    path = _write(tmp_path, "estimators:\n  sindy_ekf:\n    gate_prob: 0.9\n    gate_prob: 0.5\n")
    with pytest.raises(InputError) as exc:
        load_config(path)
    _one_line(exc, str(path), "'gate_prob' given twice", "line 4")


def test_a_missing_file_or_a_folder_is_an_error(tmp_path):
    with pytest.raises(InputError) as exc:
        load_config(tmp_path / "nope.yaml")
    _one_line(exc, "nope.yaml", "not found")
    with pytest.raises(InputError) as exc:
        load_config(tmp_path)
    _one_line(exc, str(tmp_path), "a folder")
