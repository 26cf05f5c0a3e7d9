"""Recorded IMU and wheel odometry in preprocessing: read by name and type from campaign.yaml (ROS2
bag folders here; ROS1 in the CLI test), written to imu.csv / odometry.csv that hold the true yaw
rate plus the true bias (truth/motion_sensors.yaml) within the stated noise; CSV rows with NaN
dropped and counted; no sample inside the poses an error naming the file; what the readers do not
know (JointState wheel speeds) ignored."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from identification.preprocessing.io_motion import (
    IMU,
    IMU_CSV,
    ODOMETRY,
    ODOMETRY_CSV,
    clean_samples,
    load_run_motion,
    read_motion_csv,
    write_run_motion,
)
from identification.preprocessing.io_sensors import read_sensors_config
from identification.preprocessing.preprocess import preprocess_campaign
from simulation.campaign import simulate_campaign
from simulation.motion_sensors import ImuSpec, OdometrySpec, true_bias
from simulation.truth import read_truth


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    root = tmp_path_factory.mktemp("motion_ros2")
    simulate_campaign(root / "c", seed=3, minutes=2.25, imu=ImuSpec(ros2=True), odometry=OdometrySpec(ros2=True))
    result = preprocess_campaign(root / "c", root / "t")
    return root / "c", root / "t", result


def test_imu_csv_is_true_yaw_rate_plus_true_bias_within_stated_noise(camp):
    tracker, traj, result = camp
    truth = yaml.safe_load((tracker / "truth" / "motion_sensors.yaml").read_text())
    counts = result.to_json_dict()["sensors"]
    for r in read_truth(tracker).runs:
        st = r.states
        imu = read_motion_csv(traj / "runs" / r.name / IMU_CSV, IMU)
        odo = read_motion_csv(traj / "runs" / r.name / ODOMETRY_CSV, ODOMETRY)
        assert counts[IMU][r.name]["written"] == imu.t.size and counts[ODOMETRY][r.name]["written"] == odo.t.size
        assert counts[IMU][r.name]["samples"] == truth["runs"][r.name]["imu"]["n_samples"]
        omega = np.interp(imu.t, st.t_utc_ns * 1e-9, st.omega)
        res = imu.columns["wz"] - omega - true_bias(truth, r.name, imu.t)
        assert abs(res.std() / ImuSpec().noise_std_rad_s - 1) < 0.2  # 1 Hz bias truth: its walk in between adds
        assert abs(res.mean()) < 4 * ImuSpec().noise_std_rad_s / np.sqrt(imu.t.size) + 2e-4
        np.testing.assert_allclose(imu.columns["wz_std"], ImuSpec().noise_std_rad_s)
        vx = np.interp(odo.t, st.t_utc_ns * 1e-9, st.vx)
        assert np.corrcoef(odo.columns["v"], vx)[0, 1] > 0.99
        np.testing.assert_allclose(odo.columns["v_std"], OdometrySpec().stated_std[0], rtol=1e-6)


def test_nan_rows_dropped_and_counted_and_no_overlap_names_the_file(camp, tmp_path):
    _, traj, _ = camp
    src = (traj / "runs" / "run_01" / IMU_CSV).read_text().splitlines()
    lines = src[:1] + [src[1].replace(src[1].split(",")[1], "nan", 1), "nan,0.1,0,0,0.005"] + src[2:]
    run = tmp_path / "run_01"
    run.mkdir()
    (run / IMU_CSV).write_text("\n".join(lines) + "\n")
    t_pose = np.loadtxt(traj / "runs" / "run_01" / "poses.csv", delimiter=",", skiprows=1, usecols=0)
    s, counts = load_run_motion(run, IMU, t_pose)
    assert counts["nan_dropped"] == 2 and counts["samples"] == len(src)  # header + one added row
    assert s.t.size == len(src) - 2 and np.all(np.isfinite(s.columns["wz"]))  # the written rows are all inside
    with pytest.raises(InputError, match=r"run_01/imu.csv: no imu sample inside the poses' time span"):
        load_run_motion(run, IMU, t_pose + 1e4)
    (run / ODOMETRY_CSV).write_text("t,v\n1,2\n")
    with pytest.raises(InputError, match=r"odometry.csv: required column 'omega' missing"):
        load_run_motion(run, ODOMETRY, t_pose)


def test_clean_samples_sorts_and_drops_duplicates():
    from identification.preprocessing.io_motion import MotionSamples
    s = MotionSamples(IMU, np.array([2.0, 1.0, 1.0, np.nan]), {"wz": np.array([0.2, 0.1, 0.1, 0.3])})
    kept, counts = clean_samples(s, "x")
    assert kept.t.tolist() == [1.0, 2.0] and counts == {"samples": 4, "nan_dropped": 1, "duplicates_dropped": 1,
                                                   "unstamped_receive_time": 0}


def test_unknown_readers_ignored_and_a_wrong_message_type_named(camp, tmp_path):
    tracker, _, _ = camp
    out = tmp_path / "out"
    (out / "runs" / "run_01").mkdir(parents=True)
    doc = yaml.safe_load((tracker / "campaign.yaml").read_text())
    t_pose = np.array([0.0, 2e9])
    # the wheels declared are not read; the IMU the bags hold under its default name /imu/data is,
    # the odometry under /wheel_odom (not the contract's /odometry) is not
    cases = (([{"name": "wheels", "topic": "/joint_states", "type": "sensor_msgs/JointState"}], {"imu"}),
             ([{"name": "imu", "topic": "/wheel_odom", "type": "sensor_msgs/Imu"}], None))
    for i, (sensors, expect) in enumerate(cases):
        root = tmp_path / f"c{i}"
        root.mkdir()
        (root / "runs").symlink_to(tracker / "runs")
        (root / "campaign.yaml").write_text(yaml.safe_dump({**doc, "sensors": sensors}))
        if expect is None:
            with pytest.raises(InputError, match="/wheel_odom is nav_msgs/msg/Odometry, expected sensor_msgs/msg/Imu"):
                write_run_motion(root, out, {"run_01": t_pose})
        else:
            assert set(write_run_motion(root, out, {"run_01": t_pose})) == expect


def test_wheel_speeds_in_odometry_csv_become_v_and_omega_by_hand(tmp_path):
    # data contract part 2: odometry.csv may give t,w_left,w_right with wheel_radius_m and track_m
    # in campaign.yaml. By hand, r = 0.3 m, b = 1.2 m: both sides at 2 rad/s -> 0.6 m/s straight;
    # left -1, right +1 rad/s -> turning left in place at 0.3 * 2 / 1.2 = 0.5 rad/s.
    root = tmp_path / "c"
    run = root / "runs" / "a"
    run.mkdir(parents=True)
    (root / "campaign.yaml").write_text("kind: trajectory\nwheel_radius_m: 0.3\ntrack_m: 1.2\n"
                                        "runs: [{name: a, split: test}]\n")
    (run / ODOMETRY_CSV).write_text("t,w_left,w_right\n0.0,2.0,2.0\n1.0,-1.0,1.0\n2.0,1.0,3.0\n")
    s, _ = load_run_motion(run, ODOMETRY, np.array([0.0, 2.0]))
    np.testing.assert_allclose(s.columns["v"], [0.6, 0.0, 0.6], atol=1e-12)
    np.testing.assert_allclose(s.columns["omega"], [0.0, 0.5, 0.5], atol=1e-12)
    (root / "campaign.yaml").write_text("kind: trajectory\nwheel_radius_m: 0.3\nruns: [{name: a, split: test}]\n")
    with pytest.raises(InputError, match=r"campaign.yaml: key 'track_m' missing; .*odometry.csv gives wheel speeds"):
        load_run_motion(run, ODOMETRY, np.array([0.0, 2.0]))
    (root / "campaign.yaml").write_text("kind: trajectory\nwheel_radius_m: -0.3\ntrack_m: 1.2\n"
                                        "runs: [{name: a, split: test}]\n")
    with pytest.raises(InputError, match=r"campaign.yaml: key 'wheel_radius_m' is -0.3, expected a positive"):
        load_run_motion(run, ODOMETRY, np.array([0.0, 2.0]))


def test_sensors_under_the_contracts_default_names_are_read_without_a_declaration(camp, tmp_path, caplog):
    # data contract part 1: a run may carry the optional topics under their default names and a
    # reader uses what is there; campaign.yaml names them only when the names differ. The same
    # bags without the sensors: key give the same imu.csv (/imu/data), and no odometry.csv: the
    # simulator records it on /wheel_odom, not the contract's /odometry.
    tracker, traj, _ = camp
    root = tmp_path / "c"
    root.mkdir()
    (root / "runs").symlink_to(tracker / "runs")
    doc = yaml.safe_load((tracker / "campaign.yaml").read_text())
    assert doc.pop("sensors")
    (root / "campaign.yaml").write_text(yaml.safe_dump(doc))
    t_pose = np.loadtxt(traj / "runs" / "run_01" / "poses.csv", delimiter=",", skiprows=1, usecols=0)
    out = tmp_path / "out"
    (out / "runs" / "run_01").mkdir(parents=True)
    with caplog.at_level("INFO"):
        counts = write_run_motion(root, out, {"run_01": t_pose})
    assert set(counts) == {IMU}
    assert (out / "runs" / "run_01" / IMU_CSV).read_text() == (traj / "runs" / "run_01" / IMU_CSV).read_text()
    assert not (out / "runs" / "run_01" / ODOMETRY_CSV).exists()
    assert "run run_01: /imu/data read under the data contract's default name" in caplog.text
    assert not [r for r in caplog.records if r.levelno >= 30]  # an undeclared topic absent is no warning


def test_an_undeclared_topic_of_another_type_is_skipped_with_a_warning(caplog):
    # probed under its default name, a topic of another message type is not the contract's sensor:
    # skipped and said; declared, the same fault stays an error
    from identification.preprocessing.io_sensors import undeclared_guard

    def wrong():
        raise InputError("run r: topic /imu/data is nav_msgs/msg/Odometry, expected sensor_msgs/msg/Imu")

    with caplog.at_level("WARNING"):
        assert undeclared_guard(wrong, False, "r", "/imu/data") is None
    assert "expected sensor_msgs/msg/Imu; not read (declare the sensor" in caplog.text
    with pytest.raises(InputError):
        undeclared_guard(wrong, True, "r", "/imu/data")


def _joint_state_bag(path, t_utc: np.ndarray, names: list[str], velocity: np.ndarray, topic="/wheels/joint_states",
                     stamp=lambda i, t: t):
    """Write a ROS1 bag of sensor_msgs/JointState wheel speeds with rosbags directly (not the simulator's
    writer), message ``i`` received at ``t_utc[i]`` and stamped ``stamp(i, t_utc[i])``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS1_NOETIC)
    JS, H, T = (ts.types[k] for k in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time"))
    with Writer(path) as w:
        c = w.add_connection(topic, JS.__msgtype__, typestore=ts)
        for i, t in enumerate(t_utc):
            ns, hs = int(round(t * 1e9)), int(round(stamp(i, t) * 1e9))
            msg = JS(header=H(seq=i, stamp=T(sec=hs // 10**9, nanosec=hs % 10**9), frame_id=""), name=list(names),
                     position=np.zeros(len(names)), velocity=np.asarray(velocity[i], float), effort=np.zeros(0))
            w.write(c, ns, ts.serialize_ros1(msg, JS.__msgtype__))


def test_joint_state_wheel_speeds_become_odometry_by_hand(camp, tmp_path):
    # data contract part 1: /wheels/joint_states (sensor_msgs/JointState, velocity in rad/s, the name
    # saying which wheel). By hand: left wheels at 2.1 and 1.9 rad/s (mean 2), right at 3 -> with
    # r = 0.3 m and B = 1.2 m, v = 0.3 (2 + 3) / 2 = 0.75 m/s and omega = 0.3 (3 - 2) / 1.2 = 0.25 rad/s
    tracker, traj, _ = camp
    t_pose = np.loadtxt(traj / "runs" / "run_01" / "poses.csv", delimiter=",", skiprows=1, usecols=0)
    root = tmp_path / "c"
    run = root / "runs" / "run_01"
    run.mkdir(parents=True)
    for bag in (tracker / "runs" / "run_01").iterdir():  # the tracker's topics, and its odometry on /wheel_odom
        (run / bag.name).symlink_to(bag)
    t = np.arange(t_pose[0], t_pose[-1], 0.02)
    names = ["front_left_wheel", "rear_left_wheel", "front_right_wheel", "rear_right_wheel"]
    _joint_state_bag(run / "wheels.bag", t, names, np.tile([2.1, 1.9, 3.0, 3.0], (t.size, 1)))
    doc = yaml.safe_load((tracker / "campaign.yaml").read_text())
    doc.pop("sensors")
    (root / "campaign.yaml").write_text(yaml.safe_dump({**doc, "wheel_radius_m": 0.3, "track_m": 1.2}))
    out = tmp_path / "out"
    (out / "runs" / "run_01").mkdir(parents=True)
    counts = write_run_motion(root, out, {"run_01": t_pose})
    assert counts["wheels"]["run_01"]["written"] == t.size and ODOMETRY not in counts
    (out / "campaign.yaml").write_text(yaml.safe_dump(read_sensors_config(root).to_yaml()))  # as preprocess writes it
    s, _ = load_run_motion(out / "runs" / "run_01", ODOMETRY, t_pose)
    np.testing.assert_allclose(s.t, t, atol=1e-6)
    np.testing.assert_allclose(s.columns["v"], 0.75, atol=1e-9)
    np.testing.assert_allclose(s.columns["omega"], 0.25, atol=1e-9)
    # joints that name no side: a one-line error when declared
    (run / "wheels.bag").unlink()
    _joint_state_bag(run / "wheels.bag", t, ["a", "b"], np.ones((t.size, 2)))
    (root / "campaign.yaml").write_text(yaml.safe_dump({**doc, "sensors": {"wheels": "/wheels/joint_states"}}))
    with pytest.raises(InputError, match=r"run run_01: topic /wheels/joint_states: no message with a velocity of a joint named left"):
        write_run_motion(root, out, {"run_01": t_pose})


def test_sensor_messages_whose_header_stamp_was_never_set_take_their_bag_time(tmp_path):
    # a wheel-speed node that stamps every third message and leaves the others at zero
    from identification.preprocessing.io_motion import WHEELS, read_motion_topic

    t = 1.7e9 + np.arange(300) * 0.02
    _joint_state_bag(tmp_path / "w.bag", t, ["left", "right"], np.tile([1.0, 2.0], (t.size, 1)),
                     stamp=lambda i, ti: ti if i % 3 == 0 else 0.0)
    s = read_motion_topic([tmp_path / "w.bag"], "/wheels/joint_states", WHEELS, "run_01")
    np.testing.assert_allclose(s.t, t, rtol=0, atol=1e-6)
    kept, counts = clean_samples(s, "run_01")
    assert counts["unstamped_receive_time"] == 200 and counts["duplicates_dropped"] == 0 and kept.t.size == 300


def _drive(t):
    """Return a drive that does not repeat itself: v and omega as sums of sines of incommensurate periods."""
    v = 0.5 + 0.2 * np.sin(0.31 * t) + 0.1 * np.sin(1.13 * t + 1.0)
    om = 0.6 * np.sin(0.47 * t) + 0.4 * np.sin(1.71 * t + 0.3) + 0.2 * np.sin(np.sqrt(5.0) * t)
    return v, om


def _unicycle_poses(rate_hz=20.0):
    """Return poses of a unicycle on :func:`_drive` (integrated by hand at 100 Hz), and that v and
    omega at 50 Hz sample times."""
    from groundfloor.types import PoseTrack

    dt = 0.01
    t = np.arange(0.0, 60.0, dt)
    v, om = _drive(t)
    yaw = np.concatenate([[0.0], np.cumsum(om[:-1] * dt)])
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(yaw[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(yaw[:-1]) * dt)])
    k = slice(None, None, int(round(1 / (rate_hz * dt))))
    nan = np.full(t[k].size, np.nan)
    poses = PoseTrack(t=t[k], x=x[k], y=y[k], yaw=yaw[k], z=nan, pitch=nan, x_std=nan, y_std=nan, z_std=nan,
                      pitch_std=nan, yaw_std=nan)
    ts = np.arange(0.5, 59.5, 0.02)
    return poses, ts, *_drive(ts)


@pytest.mark.parametrize("column, factor, said", [
    ("wz", 1.0, None), ("wz", -1.0, "column wz runs against the poses' yaw rate"),
    ("wz", np.degrees(1.0), "column wz is 57.[0-9] times the poses' yaw rate"),
    ("omega", 1.8, None),  # a skid-steered robot's odometry overstates its turns
    ("omega", -1.0, "column omega runs against the poses' yaw rate"),
    ("v", -1.0, "column v runs against the poses' forward speed"),
    ("v", 60 / (2 * np.pi), "column v is 9.5[0-9] times the poses' forward speed")])
def test_a_gyro_or_odometry_against_the_truth_in_sign_or_unit_is_named(column, factor, said):
    from identification.preprocessing.io_motion import MotionSamples, check_against_poses

    poses, ts, v, om = _unicycle_poses()
    rng = np.random.default_rng(0)
    if column == "wz":
        s = MotionSamples(IMU, ts, {"wz": factor * om + 0.01 + rng.normal(0, 0.01, ts.size)})  # a bias and noise
    else:
        s = MotionSamples(ODOMETRY, ts, {"v": (factor if column == "v" else 1.0) * v,
                                         "omega": (factor if column == "omega" else 1.0) * om})
    if said is None:
        check_against_poses([(s, poses)], "x/imu.csv")
    else:
        with pytest.raises(InputError, match="^x/imu.csv: " + said.replace("(", r"\(")):
            check_against_poses([(s, poses)], "x/imu.csv")


@pytest.mark.parametrize("late_s", [1.0, -2.0, 18.0])
def test_a_gyro_on_another_time_base_is_named_with_its_offset(late_s):
    # each sample stamped late_s after the instant it measured (GPS time: 18 s; a clock off by 2 s)
    from identification.preprocessing.io_motion import MotionSamples, check_against_poses

    poses, ts, _, om = _unicycle_poses()
    s = MotionSamples(IMU, ts + late_s, {"wz": om})
    with pytest.raises(InputError, match=r"^x/imu.csv: column wz follows the poses' yaw rate best at its stamps "
                                         + re.escape(f"{-late_s:+.2f} s (r = 1.00 there")):
        check_against_poses([(s, poses)], "x/imu.csv")
    check_against_poses([(MotionSamples(IMU, ts + 0.02, {"wz": om}), poses)], "x/imu.csv")  # 20 ms: a latency


def test_a_periodic_drive_is_not_mistaken_for_a_time_offset():
    # a slalom repeats itself every 12.6 s and is inverted half a period away: the gyro as stamped
    # passes, the gyro negated is a sign, not a clock 6.3 s off
    from groundfloor.types import PoseTrack
    from identification.preprocessing.io_motion import MotionSamples, check_against_poses

    dt = 0.01
    t = np.arange(0.0, 60.0, dt)
    om = np.sin(0.5 * t)
    yaw = np.concatenate([[0.0], np.cumsum(om[:-1] * dt)])
    x = np.concatenate([[0.0], np.cumsum(0.5 * np.cos(yaw[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(0.5 * np.sin(yaw[:-1]) * dt)])
    nan = np.full(t[::5].size, np.nan)
    poses = PoseTrack(t=t[::5], x=x[::5], y=y[::5], yaw=yaw[::5], z=nan, pitch=nan, x_std=nan, y_std=nan,
                      z_std=nan, pitch_std=nan, yaw_std=nan)
    ts = np.arange(0.5, 59.5, 0.02)
    check_against_poses([(MotionSamples(IMU, ts, {"wz": np.sin(0.5 * ts)}), poses)], "x/imu.csv")
    with pytest.raises(InputError, match=r"^x/imu.csv: column wz runs against the poses' yaw rate"):
        check_against_poses([(MotionSamples(IMU, ts, {"wz": -np.sin(0.5 * ts)}), poses)], "x/imu.csv")


def test_a_clock_off_is_found_in_the_evidence_of_all_runs_that_none_shows_alone():
    # four runs of 15 s, the gyro stamped 0.5 s late: no run alone shows it significantly, the four
    # pooled do (a sensor's clock is the campaign's, every run adds evidence)
    from groundfloor.types import PoseTrack
    from identification.preprocessing.io_motion import MotionSamples, check_against_poses

    poses, ts, _, om = _unicycle_poses()
    runs = []
    for k in range(4):
        cut = (poses.t >= 15 * k) & (poses.t < 15 * (k + 1))
        part = PoseTrack(**{f: getattr(poses, f)[cut] for f in ("t", "x", "y", "yaw", "z", "pitch", "x_std", "y_std",
                                                              "z_std", "pitch_std", "yaw_std")})
        keep = (ts >= 15 * k + 0.5) & (ts < 15 * (k + 1) - 0.5)
        runs.append((MotionSamples(IMU, ts[keep] + 0.5, {"wz": om[keep]}), part))
    for run in runs:
        check_against_poses([run], "x/*/imu.csv")
    with pytest.raises(InputError, match=r"^x/\*/imu.csv: column wz follows the poses' yaw rate best at its stamps -0\.5"):
        check_against_poses(runs, "x/*/imu.csv")
