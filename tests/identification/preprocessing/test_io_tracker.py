"""Reading tracker campaigns: round trips through ROS1 and ROS2 bags, and every bad input."""

from __future__ import annotations

import logging
import re
import shutil
from dataclasses import replace

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import PointSeries
from identification.preprocessing.io_tracker import (
    read_tracker_campaign,
    read_tracker_run,
)
from tests.support import REPO
from tests.support.tracker_synth import synth_run, write_campaign, write_run_bags

CALIBRATION = REPO / "simulation" / "data" / "calibration.yaml"


@pytest.fixture(scope="module")
def raw():
    return synth_run(seed=21, minutes=0.25)[0]


def _assert_same(a, b):
    np.testing.assert_allclose(a.t_trigger_utc, b.t_trigger_utc, rtol=0, atol=5e-7)  # float64 UTC
    for tr in ("at960", "ltd800"):
        np.testing.assert_allclose(getattr(a, tr).t_tracker, getattr(b, tr).t_tracker, rtol=0, atol=2e-9)
        np.testing.assert_array_equal(getattr(a, tr).xyz, getattr(b, tr).xyz)
    np.testing.assert_allclose(a.u_joy, b.u_joy, atol=1e-7)  # Joy axes are float32
    np.testing.assert_array_equal(a.hub_azimuth, b.hub_azimuth)


@pytest.mark.parametrize("ros2", [False, True], ids=["ros1-two-bags", "ros2-folder"])
def test_round_trip_through_bags(tmp_path, raw, ros2):
    write_run_bags(tmp_path / "run_01", raw, ros2=ros2)
    back = read_tracker_run(tmp_path / "run_01", "run_01", "test")
    _assert_same(raw, back)
    assert back.split == "test"
    np.testing.assert_allclose(back.t_receive_utc["at960"], raw.t_receive_utc["at960"], atol=5e-7)


def test_topics_are_found_across_ros1_and_ros2_bags_of_one_run(tmp_path, raw):
    write_run_bags(tmp_path / "a", raw, drop_topics=("/at960/measurement",))
    write_run_bags(tmp_path / "b", raw, ros2=True, drop_topics=("/rpi/trigger", "/joy_teleop/joy",
                                                                  "/turning_hub/azimuth", "/ltd800/measurement"))
    run = tmp_path / "run_01"
    run.mkdir()
    for f in (tmp_path / "a").iterdir():
        shutil.move(f, run / f.name)
    shutil.move(tmp_path / "b" / "bag_ros2", run / "bag_ros2")
    _assert_same(raw, read_tracker_run(run))


def test_a_run_folder_that_is_itself_a_ros2_bag_is_read(tmp_path, raw):
    # `ros2 bag record -o runs/run_01` makes the run folder the bag folder
    write_run_bags(tmp_path / "w", raw, ros2=True)
    run = tmp_path / "run_01"
    shutil.move(tmp_path / "w" / "bag_ros2", run)
    assert (run / "metadata.yaml").is_file()
    _assert_same(raw, read_tracker_run(run))


def test_missing_topic_names_run_and_topic(tmp_path, raw):
    write_run_bags(tmp_path / "run_01", raw, drop_topics=("/ltd800/measurement",))
    with pytest.raises(InputError, match=r"^run run_01: topic /ltd800/measurement missing or empty$"):
        read_tracker_run(tmp_path / "run_01")


def test_a_required_topic_under_another_name_is_pointed_to(tmp_path, raw):
    # the joystick recorded on /joy (a common driver default) instead of the contract's /joy_teleop/joy
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    write_run_bags(tmp_path / "src", raw)
    (tmp_path / "run_01").mkdir()
    shutil.copy(tmp_path / "src" / "trackers.bag", tmp_path / "run_01" / "trackers.bag")
    store = get_typestore(Stores.ROS1_NOETIC)
    with Reader(tmp_path / "src" / "robot.bag") as r, Writer(tmp_path / "run_01" / "robot.bag") as w:
        conns = {c.id: w.add_connection("/joy" if c.topic == "/joy_teleop/joy" else c.topic, c.msgtype, typestore=store)
                 for c in r.connections}
        for c, t, data in r.messages():
            w.write(conns[c.id], t, data)
    with pytest.raises(InputError, match=r"^run run_01: topic /joy_teleop/joy missing or empty; sensor_msgs/msg/Joy is "
                                         r"recorded on /joy instead: the data contract names that topic /joy_teleop/joy$"):
        read_tracker_run(tmp_path / "run_01")


def test_missing_hub_topic_only_warns(tmp_path, raw, caplog):
    write_run_bags(tmp_path / "run_01", raw, drop_topics=("/turning_hub/azimuth",))
    with caplog.at_level(logging.WARNING):
        back = read_tracker_run(tmp_path / "run_01")
    assert back.t_hub_utc.size == 0 and "/turning_hub/azimuth" in caplog.text


def test_a_backward_jump_of_a_period_is_a_clock_reset_and_a_short_part_is_dropped_with_a_warning(
        tmp_path, raw, caplog):
    # two messages a whole trigger period apart stored swapped: longer than half a period, so by
    # the data contract a clock reset, not a reordering; the 1 s before it is too short to keep
    t = raw.at960.t_tracker.copy()
    t[50], t[51] = t[51], t[50]
    write_run_bags(tmp_path / "run_01", replace(raw, at960=PointSeries(t, raw.at960.xyz)))
    with caplog.at_level(logging.WARNING):
        back = read_tracker_run(tmp_path / "run_01")
    jump = f"{t[50] - t[51]:.6f}"
    assert re.search(rf"run run_01: topic /at960/measurement: clock jumps back {jump} s at message 51 .*"
                     r"the 1\.0 s of trigger stamps before it .* dropped", caplog.text)
    assert back.name == "run_01" and back.t_trigger_utc[0] > raw.t_trigger_utc[0] + 0.9
    assert back.facts.parts_dropped and "message 51" in back.facts.parts_dropped[0]
    assert np.all(np.diff(back.at960.t_tracker) > 0)
    # the next stamp passes the jump's start again: the warning says it may be a late message
    assert "a message received more than half a trigger period late rather than a restarted clock?" in caplog.text


def test_messages_a_period_late_throughout_are_named_as_such_when_no_part_is_left(tmp_path, raw, caplog):
    # a recorder whose latencies spread beyond half a trigger period: every 25th AT960 message
    # stored after its successor. Each swap is a clock reset by the data contract, no part between
    # them lasts 12 s, and the error says that the stamps come back: late messages, not clocks
    t = raw.at960.t_tracker.copy()
    swapped = np.arange(20, t.size - 1, 25)
    t[swapped], t[swapped + 1] = t[swapped + 1], t[swapped].copy()
    write_run_bags(tmp_path / "run_01", replace(raw, at960=PointSeries(t, raw.at960.xyz)))
    n = swapped.size
    with pytest.raises(InputError, match=rf"^run run_01: no part between its clock resets lasts 12 s \(first: "
                                         rf"topic /at960/measurement: clock jumps back .* at message 21 .*\); "
                                         rf"{n} of its {n} clock resets are passed again by the stamps within 1 s: "
                                         "messages received more than half a trigger period late"):
        read_tracker_run(tmp_path / "run_01")


def test_a_restarted_clock_is_not_called_a_late_message(tmp_path, raw, caplog):
    t = raw.ltd800.t_tracker.copy()
    t[t.size // 2:] -= 3600.0  # the LTD800 controller rebooted: its clock stays an hour back
    write_run_bags(tmp_path / "run_01", replace(raw, ltd800=PointSeries(t, raw.ltd800.xyz)))
    with caplog.at_level(logging.WARNING), pytest.raises(InputError, match=r"no part .*lasts 12 s") as err:
        read_tracker_run(tmp_path / "run_01")  # 7.5 s either side of the reset: both parts too short
    assert "clock jumps back 3599.97" in caplog.text and "late" not in caplog.text
    assert "passed again" not in str(err.value)


def test_a_repeated_stamp_is_dropped_and_said(tmp_path, raw, caplog):
    t, xyz = raw.at960.t_tracker, raw.at960.xyz
    # a spurious measurement on the very clock tick of a real one (seen in simulated campaigns)
    t2, xyz2 = np.insert(t, 51, t[50]), np.insert(xyz, 51, xyz[50] + 1e-3, axis=0)
    receive = dict(raw.t_receive_utc)
    if "at960" in receive:
        receive["at960"] = np.insert(receive["at960"], 51, receive["at960"][50])
    write_run_bags(tmp_path / "run_01", replace(raw, at960=PointSeries(t2, xyz2), t_receive_utc=receive))
    with caplog.at_level(logging.WARNING):
        back = read_tracker_run(tmp_path / "run_01")
    np.testing.assert_allclose(back.at960.t_tracker, t, rtol=0, atol=2e-9)
    np.testing.assert_array_equal(back.at960.xyz, xyz)
    assert "run run_01: topic /at960/measurement: 1 message(s) repeat the previous stamp" in caplog.text


def test_nan_coordinates_are_kept_for_the_clock(tmp_path, raw):
    xyz = raw.at960.xyz.copy()
    xyz[10] = np.nan
    write_run_bags(tmp_path / "run_01", replace(raw, at960=PointSeries(raw.at960.t_tracker, xyz)))
    back = read_tracker_run(tmp_path / "run_01")
    assert np.isnan(back.at960.xyz[10]).all() and back.at960.t_tracker.size == raw.at960.t_tracker.size


def test_campaign_skips_bad_runs_and_lists_them(tmp_path, raw, caplog):
    root = write_campaign(tmp_path / "c", [raw, replace(raw, name="run_02")], CALIBRATION.read_text())
    empty = root / "runs" / "run_03"
    empty.mkdir()
    text = (root / "campaign.yaml").read_text() + "- {name: run_03, split: test}\n"
    (root / "campaign.yaml").write_text(text)
    for f in (root / "runs" / "run_02").glob("trackers.bag"):
        f.unlink()  # run_02 keeps only the robot's bag: no tracker topics
    with caplog.at_level(logging.WARNING):
        c = read_tracker_campaign(root)
    assert [r.name for r in c.runs] == ["run_01"]
    assert c.skipped["run_02"] == "run run_02: topic /at960/measurement missing or empty"
    assert c.skipped["run_03"].startswith("run run_03: no bags")
    assert "run_02" in caplog.text


def test_run_folders_not_listed_are_named_and_not_read(tmp_path, raw, caplog):
    root = write_campaign(tmp_path / "c", [raw], CALIBRATION.read_text())
    shutil.copytree(root / "runs" / "run_01", root / "runs" / "run_02")
    shutil.copytree(root / "runs" / "run_01", root / "runs" / "run_03")
    with caplog.at_level(logging.WARNING):
        c = read_tracker_campaign(root)
    assert [r.name for r in c.runs] == ["run_01"] and c.skipped == {}
    assert f"{root / 'runs'}: run folders run_02, run_03 are not listed in campaign.yaml; not read" in caplog.text


def test_tracker_points_in_millimetres_are_named_before_synchronisation(tmp_path, raw, capsys):
    # laser-tracker software exports millimetres; the survey in calibration.yaml is in metres
    from sindy_ekf.cli import main

    mm = replace(raw, name="run_02", ltd800=PointSeries(raw.ltd800.t_tracker, raw.ltd800.xyz * 1000.0))
    root = write_campaign(tmp_path / "c", [raw, mm], CALIBRATION.read_text())
    c = read_tracker_campaign(root)
    assert [r.name for r in c.runs] == ["run_01"]
    assert re.fullmatch(r"run run_02: topic /ltd800/measurement: points a median [\d.]+ from the tracker, its network "
                        r"points in calibration.yaml [\d.]+: one of them is not in metres \(millimetres\?\)",
                        c.skipped["run_02"])
    root2 = write_campaign(tmp_path / "d", [replace(mm, name="run_01")], CALIBRATION.read_text())
    assert main(["preprocess", str(root2), "--out", str(tmp_path / "out"), "--jobs", "1", "--quiet"]) == 2
    assert "run run_01: topic /ltd800/measurement: points a median" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_campaign_with_no_usable_run_is_an_error(tmp_path, raw):
    root = write_campaign(tmp_path / "c", [raw], CALIBRATION.read_text())
    shutil.rmtree(root / "runs" / "run_01")
    with pytest.raises(InputError, match=r"no usable run.*run run_01: folder .* missing"):
        read_tracker_campaign(root)


def test_not_a_campaign(tmp_path):
    with pytest.raises(InputError, match=r"not a campaign \(no campaign.yaml\)"):
        read_tracker_campaign(tmp_path)


def test_bad_split_names_the_key(tmp_path, raw):
    root = write_campaign(tmp_path / "c", [replace(raw, split="validation")], CALIBRATION.read_text())
    with pytest.raises(InputError, match=r"campaign.yaml: runs\[0\] \(run_01\): key 'split'"):
        read_tracker_campaign(root)


@pytest.mark.parametrize("edit, key", [
    (lambda t: t.replace('\n    "31":', '\n    "99":', 1), "31|99"),  # a point id only one tracker has
    (lambda t: t.replace("prisms:", "prisms_x:", 1), "prisms"),
])
def test_calibration_with_missing_or_extra_point_names_the_key(tmp_path, raw, edit, key):
    text = CALIBRATION.read_text()
    assert edit(text) != text
    root = write_campaign(tmp_path / "c", [raw], edit(text))
    with pytest.raises(InputError, match=rf"calibration.yaml.*({key})"):
        read_tracker_campaign(root)


def test_fast_ros1_parser_agrees_with_rosbags_and_refuses_non_uniform_messages():
    from rosbags.typesys import Stores, get_typestore

    from identification.preprocessing.io_bags import _ros1_columns

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    msgs = [T["geometry_msgs/msg/PointStamped"](
        header=T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=100 + i, nanosec=7 * i),
                                        frame_id=frame),
        point=T["geometry_msgs/msg/Point"](x=0.1 * i, y=-2.0, z=np.pi))
        for i, frame in enumerate(["at960", "at960", "at960"])]
    raw = [bytes(store.serialize_ros1(m, "geometry_msgs/msg/PointStamped")) for m in msgs]
    cols = _ros1_columns(raw, "geometry_msgs/msg/PointStamped")
    ref = [(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.point.x, m.point.y, m.point.z) for m in msgs]
    np.testing.assert_array_equal(cols, np.array(ref))
    odd = raw[:2] + [bytes(store.serialize_ros1(replace(msgs[2], header=replace(msgs[2].header, frame_id="x")),
                                                "geometry_msgs/msg/PointStamped"))]
    assert _ros1_columns(odd, "geometry_msgs/msg/PointStamped") is None


def test_a_short_run_without_clock_resets_is_read_whole(tmp_path):
    short = synth_run(seed=3, minutes=0.1)[0]  # 6 s: shorter than a part cut at a reset may be
    write_run_bags(tmp_path / "run_01", short)
    back = read_tracker_run(tmp_path / "run_01")
    _assert_same(short, back)
    assert back.facts.parts_dropped == () and back.facts.clock_resets == ()
