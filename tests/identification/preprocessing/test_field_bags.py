"""Bags as they come from the field (issue 14, item 1): messages stored out of stamp order, clock
resets, a known topic of another type, truncated bags, NaN points.

The receive-jitter campaign is the shared ``field_campaign`` (tests/conftest.py), preprocessed
through the cache every later command uses; the reorderings are counted independently from the
bags with rosbags' own reader (tests/support/bag_order.py) and compared with what the simulator
injected (truth/) and what preprocessing reports.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from groundfloor.types import PointSeries
from identification.preprocessing.io_tracker import read_tracker_parts, read_tracker_run
from simulation.truth import read_truth
from tests.conftest import FIELD_RESETS
from tests.support import REPO
from tests.support.bag_order import backward_steps, stored_stamps
from tests.support.tracker_synth import synth_run, write_campaign, write_run_bags

CALIBRATION = REPO / "simulation" / "data" / "calibration.yaml"


@pytest.fixture(scope="module")
def field(field_campaign):
    """``field_campaign`` preprocessed into its cache (as identify/evaluate find it): JSON, truth."""
    from identification.preprocessing.campaigns import preprocessed_dir

    out = preprocessed_dir(field_campaign)
    return json.loads((out / "preprocess.json").read_text()), read_truth(field_campaign), out


@pytest.fixture(scope="module")
def twin(field_twin, tmp_path_factory):
    from identification.preprocessing.preprocess import preprocess_campaign

    out = tmp_path_factory.mktemp("twin") / "out"
    preprocess_campaign(field_twin, out)
    return json.loads((out / "preprocess.json").read_text()), out


def _source(name: str) -> str:
    return name.rsplit(".", 1)[0] if re.fullmatch(r".+\.\d+", name) else name


def test_every_run_kept_and_the_reorderings_counted(field, field_campaign):
    report, truth, _ = field
    assert report["skipped_runs"] == {}
    assert sorted({_source(n) for n in report["runs"]}) == [r.name for r in truth.runs]
    assert [n for n in report["runs"] if n.startswith("run_06")] == ["run_06.1", "run_06.2"]
    total = 0
    for name, r in report["runs"].items():
        injected = truth.run(_source(name)).bags["reordered"]
        if name in FIELD_RESETS or _source(name) in FIELD_RESETS:
            # a part dropped at a reset takes its reorderings with it
            assert sum(r["reordered"].values()) <= sum(injected.values())
            continue
        in_bag = {t: backward_steps(s)[0] for t, (s, _) in stored_stamps(field_campaign / "runs" / name).items()}
        assert r["reordered"] == injected == in_bag, name
        total += sum(in_bag.values())
    assert total >= 3


def _pose_rms_m(out: Path, truth) -> dict[str, float]:
    from identification.preprocessing.trajectory import read_trajectory_campaign

    rms = {}
    for run in read_trajectory_campaign(out).runs:
        st = truth.run(_source(run.name)).states
        i = np.clip(np.searchsorted(st.t_utc, run.poses.t), 1, st.t_utc.size - 1)
        i -= np.abs(st.t_utc[i - 1] - run.poses.t) < np.abs(st.t_utc[i] - run.poses.t)
        assert np.abs(st.t_utc[i] - run.poses.t).max() < 1e-6
        err = np.column_stack([run.poses.x - st.x[i], run.poses.y - st.y[i], run.poses.z - st.z[i]])
        rms[run.name] = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    return rms


def test_poses_drifts_and_offsets_as_accurate_as_without_jitter(field, twin):
    report, truth, out = field
    rms, rms_twin = _pose_rms_m(out, truth), _pose_rms_m(twin[1], truth)
    assert rms.keys() == rms_twin.keys()
    for name, r in report["runs"].items():
        t = truth.run(_source(name))
        assert rms[name] <= 1.05 * rms_twin[name] + 1e-6 and rms[name] < 0.5e-3, (name, rms[name])
        at, ltd = r["clock"]["at960"], r["clock"]["ltd800"]
        assert abs(ltd["drift_ppm"] - t.clocks["ltd800"]["drift_ppm"]) < 0.05, name
        assert abs(at["drift_ppm"] - t.clocks["at960"]["drift_ppm"]) < 3 * at["drift_std_ppm"], name
        assert abs(r["at960_extra_offset_s"] - t.at960["offset_s"]) < 20e-6, name
        if _source(name) in FIELD_RESETS:
            continue  # cut at a bag time: a message at the cut may fall on the other side
        other = twin[0]["runs"][name]  # the same messages, sorted: the same synchronisation
        for tracker in ("at960", "ltd800"):
            assert r["clock"][tracker]["drift_ppm"] == pytest.approx(other["clock"][tracker]["drift_ppm"], abs=1e-9)
        assert r["at960_extra_offset_s"] == pytest.approx(other["at960_extra_offset_s"], abs=1e-12)


def test_a_clock_reset_splits_the_run_into_two_parts(field):
    report, truth, out = field
    reset = truth.run("run_06").clock_reset
    t_reset = reset["t_utc_ns"] * 1e-9
    for k, name in enumerate(("run_06.1", "run_06.2")):
        r = report["runs"][name]
        assert r["part_of"] == "run_06" and r["parts_dropped"] == []
        (c,) = r["clock_resets"]
        assert c["topic"] == "/at960/measurement" and c["message"] == reset["message"]
        assert c["jump_s"] == pytest.approx(reset["jump_s"], abs=1e-6)
        t = np.loadtxt(out / "runs" / name / "poses.csv", delimiter=",", skiprows=1, usecols=0)
        assert (t[-1] < t_reset) if k == 0 else (t[0] > t_reset)
        assert t[-1] - t[0] > 15.0
    assert "run_06" not in report["runs"]


def test_the_parts_of_a_run_are_one_cross_validation_group(field):
    # leave-one-group-out must not train on one part of a run and score the other
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from identification.sindy.reference import run_group

    report, _, out = field
    groups = {r.name: run_group(r) for r in read_trajectory_campaign(out).runs}
    assert groups["run_06.1"] == groups["run_06.2"] == "run_06"
    whole = [n for n in report["runs"] if not report["runs"][n]["part_of"]]
    assert whole and all(groups[n] == n for n in whole)
    assert len(set(groups.values())) == len(whole) + 1


def test_a_group_given_in_a_raw_campaign_is_kept_by_preprocessing(tmp_path):
    from identification.preprocessing.preprocess import preprocess_campaign
    from identification.preprocessing.trajectory import read_trajectory_campaign

    from simulation.campaign import simulate_campaign

    root = tmp_path / "c"
    simulate_campaign(root, seed=3, minutes=2.25)
    meta = yaml.safe_load((root / "campaign.yaml").read_text())
    meta["runs"][0]["group"], meta["runs"][1]["group"] = "day-1", "day-2"
    (root / "campaign.yaml").write_text(yaml.safe_dump(meta))
    preprocess_campaign(root, tmp_path / "out", jobs=1)
    back = {r.name: r.group for r in read_trajectory_campaign(tmp_path / "out").runs}
    first, second, *rest = (r["name"] for r in meta["runs"])
    assert back == {first: "day-1", second: "day-2", **{n: "" for n in rest}}


def test_a_part_is_read_by_its_name_and_the_whole_run_names_its_parts(field_campaign):
    part = read_tracker_run(field_campaign / "runs" / "run_06.2", "run_06.2", "train")
    assert part.name == "run_06.2" and part.facts.part_of == "run_06"
    assert part.at960.t_tracker[0] < 10.0  # the restarted clock
    with pytest.raises(InputError, match=r"^run run_06: clock resets cut it into run_06.1, run_06.2; read one"):
        read_tracker_run(field_campaign / "runs" / "run_06")


def test_a_part_too_short_is_dropped_with_a_warning_naming_topic_message_and_jump(field, field_campaign, caplog):
    report, truth, _ = field
    reset = truth.run("run_09").clock_reset
    with caplog.at_level(logging.WARNING):
        (part,) = read_tracker_parts(field_campaign / "runs" / "run_09", "run_09", "test")
    warning = (rf"run run_09: topic /ltd800/measurement: clock jumps back {-reset['jump_s']:.6f} s at message "
               rf"{reset['message']} \(.*\); the [\d.]+ s of trigger stamps before it are fewer than the 12 s "
               "a run needs and are dropped")
    assert re.search(warning, caplog.text)
    assert part.name == "run_09" and part.t_trigger_utc[0] > reset["t_utc_ns"] * 1e-9
    r = report["runs"]["run_09"]
    assert r["part_of"] is None and re.fullmatch(warning, r["parts_dropped"][0])


def test_identify_and_evaluate_through_the_cache(field, field_campaign, tmp_path):
    from sindy_ekf.cli import main

    cached = field[2] / "preprocess.json"
    stamp = cached.stat().st_mtime_ns
    model, js = tmp_path / "model.json", tmp_path / "eval.json"
    assert main(["identify", str(field_campaign), "--out", str(model), "--quick", "--quiet"]) == 0
    assert main(["evaluate", str(field_campaign), "--model", str(model), "--json", str(js), "--quiet"]) == 0
    assert cached.stat().st_mtime_ns == stamp  # both read the cached preprocessing
    scores = json.loads(js.read_text())
    assert scores["n_windows"] > 0 and 0 < scores["pos_err_5s_m"] < 1.0


# --- synthetic bags: one per kind of damage ----------------------------------------------------


@pytest.fixture(scope="module")
def synth():
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey

    tf = calibrate(read_survey(CALIBRATION)).transform
    return synth_run(seed=61, minutes=0.6, R_at960_ltd800=tf.R_at960_ltd800, t_at960_ltd800=tf.t_at960_ltd800)[0]


def test_a_known_topic_of_another_type_is_one_line_naming_both_types(tmp_path, synth, capsys):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from sindy_ekf.cli import main

    camp = write_campaign(tmp_path / "c", [synth], CALIBRATION.read_text())
    (camp / "runs" / "run_01" / "trackers.bag").unlink()
    write_run_bags(tmp_path / "tmp", synth, drop_topics=("/at960/measurement",))
    shutil.move(tmp_path / "tmp" / "trackers.bag", camp / "runs" / "run_01" / "trackers.bag")
    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    V = T["geometry_msgs/msg/Vector3Stamped"]
    with Writer(camp / "runs" / "run_01" / "at960.bag") as w:
        conn = w.add_connection("/at960/measurement", V.__msgtype__, typestore=store)
        for i in range(3):
            msg = V(header=T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=100 + i, nanosec=0),
                                                  frame_id="at960"),
                    vector=T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0))
            w.write(conn, int((synth.t_trigger_utc[0] + i) * 1e9), store.serialize_ros1(msg, V.__msgtype__))
    expected = ("run run_01: topic /at960/measurement: type geometry_msgs/msg/Vector3Stamped, "
                "expected geometry_msgs/msg/PointStamped")
    with pytest.raises(InputError) as err:
        read_tracker_run(camp / "runs" / "run_01")
    assert str(err.value) == expected
    out = tmp_path / "out"
    assert main(["preprocess", str(camp), "--out", str(out), "--jobs", "1", "--quiet"]) == 2
    stderr = capsys.readouterr().err
    assert expected in stderr and len(stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_a_truncated_bag_is_read_up_to_the_damage_and_reported(tmp_path, synth, capsys):
    from sindy_ekf.cli import main

    camp = write_campaign(tmp_path / "c", [synth], CALIBRATION.read_text())
    bag = camp / "runs" / "run_01" / "trackers.bag"
    whole = read_tracker_run(camp / "runs" / "run_01")
    with open(bag, "r+b") as fh:  # the recording stopped at 70 %: no index, the last chunk cut
        fh.truncate(int(bag.stat().st_size * 0.7))
    back = read_tracker_run(camp / "runs" / "run_01")
    (cut,) = back.facts.truncated
    assert cut.bag == "trackers.bag" and "cut" in cut.reason
    n_at, n_ltd = back.at960.t_tracker.size, back.ltd800.t_tracker.size
    assert cut.messages == n_at + n_ltd
    assert 0.5 * whole.at960.t_tracker.size < n_at < whole.at960.t_tracker.size
    np.testing.assert_array_equal(back.at960.t_tracker, whole.at960.t_tracker[:n_at])  # the readable part
    np.testing.assert_array_equal(back.ltd800.xyz, whole.ltd800.xyz[:n_ltd])
    np.testing.assert_array_equal(back.t_trigger_utc, whole.t_trigger_utc)  # the other bag is whole

    out, js = tmp_path / "out", tmp_path / "pre.json"
    assert main(["preprocess", str(camp), "--out", str(out), "--json", str(js), "--jobs", "1"]) == 0
    assert "run_01: bag trackers.bag truncated (" in capsys.readouterr().out
    run = json.loads(js.read_text())["runs"]["run_01"]
    assert run["truncated"] == [cut.to_dict()]
    from sindy_ekf.report.bag_facts import bag_notes, bag_words

    assert bag_words(run) == "truncated" and "truncated" in bag_notes({"run_01": run})[0]


def test_nan_points_are_dropped_and_counted(tmp_path, synth, capsys):
    from sindy_ekf.cli import main

    at, ltd = synth.at960.xyz.copy(), synth.ltd800.xyz.copy()
    at[[40, 41, 300, 301, 302, 900, 1200]] = np.nan
    ltd[[10, 500, 1400]] = np.nan
    raw = replace(synth, at960=PointSeries(synth.at960.t_tracker, at), ltd800=PointSeries(synth.ltd800.t_tracker, ltd))
    camp = write_campaign(tmp_path / "c", [raw], CALIBRATION.read_text())
    js = tmp_path / "pre.json"
    assert main(["preprocess", str(camp), "--out", str(tmp_path / "out"), "--json", str(js), "--jobs", "1"]) == 0
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("run_01"))
    assert row.split()[-1] == "10"  # the summary's nan column
    run = json.loads(js.read_text())["runs"]["run_01"]
    assert run["nan_points_dropped"] == {"/at960/measurement": 7, "/ltd800/measurement": 3}
    assert run["counts"]["at960"]["samples"] == raw.at960.t_tracker.size  # stamps kept for the clock
    poses = np.loadtxt(tmp_path / "out" / "runs" / "run_01" / "poses.csv", delimiter=",", skiprows=1)
    assert np.isfinite(poses[:, :6]).all()


def test_a_trigger_clock_reset_cuts_every_topic_at_its_bag_time(tmp_path, synth):
    k = synth.t_trigger_utc.size // 2
    t = synth.t_trigger_utc.copy()
    t[k:] -= 3600.0  # the trigger computer's clock stepped back an hour; bag times did not
    raw = replace(synth, t_trigger_utc=t, t_receive_utc={**synth.t_receive_utc, "trigger": synth.t_trigger_utc + 3e-4})
    write_run_bags(tmp_path / "run_01", raw)
    one, two = read_tracker_parts(tmp_path / "run_01")
    assert (one.name, two.name) == ("run_01.1", "run_01.2")
    (reset,) = one.facts.clock_resets
    assert reset.topic == "/rpi/trigger" and reset.message == k
    assert reset.jump_s == pytest.approx(-3600.0 + np.diff(synth.t_trigger_utc)[k - 1], abs=1e-5)
    np.testing.assert_allclose(one.t_trigger_utc, t[:k], rtol=0, atol=5e-7)  # float64 UTC
    np.testing.assert_allclose(two.t_trigger_utc, t[k:], rtol=0, atol=5e-7)
    t_cut = reset.t_receive_utc
    assert t_cut == pytest.approx(synth.t_trigger_utc[k] + 3e-4, abs=1e-6)
    for tracker in ("at960", "ltd800"):  # the trackers' own clocks are cut at the same bag time
        assert one.t_receive_utc[tracker].max() < t_cut <= two.t_receive_utc[tracker].min()
        n = one.t_receive_utc[tracker].size + two.t_receive_utc[tracker].size
        assert n == getattr(synth, tracker).t_tracker.size
    assert one.t_joy_utc.max() < t_cut <= two.t_joy_utc.min()


def test_an_unreadable_extra_bag_is_left_out_and_the_run_read_from_its_other_bags(tmp_path, synth, capsys):
    # a recorder killed at its start leaves an empty file, another a file with its header cut:
    # the run's good bags hold every topic, so the run is read as without them, and both are named
    from sindy_ekf.cli import main

    camp = write_campaign(tmp_path / "c", [synth], CALIBRATION.read_text())
    run_dir = camp / "runs" / "run_01"
    whole = read_tracker_run(run_dir)
    (run_dir / "empty.bag").write_bytes(b"")
    (run_dir / "cut.bag").write_bytes((run_dir / "trackers.bag").read_bytes()[:3000])
    (run_dir / "ros2").mkdir()  # a ROS2 recording whose metadata lists no file
    (run_dir / "ros2" / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n")
    back = read_tracker_run(run_dir)
    assert sorted((c.bag, c.messages) for c in back.facts.truncated) == [("cut.bag", 0), ("empty.bag", 0), ("ros2", 0)]
    np.testing.assert_array_equal(back.at960.t_tracker, whole.at960.t_tracker)
    np.testing.assert_array_equal(back.ltd800.xyz, whole.ltd800.xyz)
    np.testing.assert_array_equal(back.t_trigger_utc, whole.t_trigger_utc)
    js = tmp_path / "pre.json"
    assert main(["preprocess", str(camp), "--out", str(tmp_path / "out"), "--json", str(js), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "run_01: bag empty.bag unreadable (not a ROS1 bag" in out and "left out, the run read from its other bags" in out
    assert "run_01" in json.loads(js.read_text())["runs"]


JOY, HUB = "/joy_teleop/joy", "/turning_hub/azimuth"


@pytest.mark.parametrize("every", [1, 2])
def test_header_stamps_never_set_take_the_bag_time_and_are_counted(tmp_path, synth, every):
    # a joystick or hub node that never fills header.stamp (ROS leaves it at zero): all of its
    # messages, or every other one. The synthetic bags receive each at its true UTC stamp, so the
    # times read must be those, with no clock reset at each unset stamp (every == 2) and no run in 1970.
    unset = {JOY: lambda i, t: 0.0 if i % every == 0 else t, HUB: lambda i, t: 0.0 if i % every == 0 else t}
    write_run_bags(tmp_path / "run_01", synth, header_stamps=unset)
    (run,) = read_tracker_parts(tmp_path / "run_01")
    np.testing.assert_allclose(run.t_joy_utc, synth.t_joy_utc, rtol=0, atol=1e-6)
    np.testing.assert_allclose(run.u_joy, synth.u_joy, rtol=0, atol=1e-6)  # float32 axes
    np.testing.assert_allclose(run.t_hub_utc, synth.t_hub_utc, rtol=0, atol=1e-6)
    assert run.facts.clock_resets == ()
    assert run.facts.unstamped == {JOY: len(range(0, synth.t_joy_utc.size, every)),
                                   HUB: len(range(0, synth.t_hub_utc.size, every))}


def test_an_unstamped_joystick_preprocesses_as_a_stamped_one_and_the_json_counts_it(tmp_path, synth, caplog, capsys):
    from sindy_ekf.cli import main

    stamped = write_campaign(tmp_path / "a", [synth], CALIBRATION.read_text())
    unstamped = write_campaign(tmp_path / "b", [synth], CALIBRATION.read_text())
    for bag in (unstamped / "runs" / "run_01").glob("*.bag"):
        bag.unlink()
    write_run_bags(unstamped / "runs" / "run_01", synth, header_stamps={JOY: lambda i, t: 0.0})
    for camp in (stamped, unstamped):
        assert main(["preprocess", str(camp), "--out", str(camp.parent / f"{camp.name}_out"),
                     "--json", str(camp.parent / f"{camp.name}.json"), "--jobs", "1"]) == 0
    assert ("run run_01: topic /joy_teleop/joy: 400 of 400 messages have no header stamp (zero); their bag times "
            "are taken") in caplog.text and synth.t_joy_utc.size == 400
    out = capsys.readouterr().out
    assert out.count("header stamps never set") == 1  # the summary's note, for the unstamped campaign alone
    assert "run_01: header stamps never set (zero), timed by their bag time: /joy_teleop/joy 400" in out
    run = json.loads((tmp_path / "b.json").read_text())["runs"]["run_01"]
    assert run["unstamped_receive_time"] == {JOY: synth.t_joy_utc.size}
    assert json.loads((tmp_path / "a.json").read_text())["runs"]["run_01"]["unstamped_receive_time"] == {}
    a, b = (np.loadtxt(tmp_path / f"{x}_out" / "runs" / "run_01" / "inputs.csv", delimiter=",", skiprows=1)
            for x in "ab")
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-6)
    assert a[0, 0] == pytest.approx(synth.t_joy_utc[0], abs=1e-6)


def test_joystick_stamps_on_another_clock_are_one_line_naming_run_and_topic(tmp_path, synth):
    # stamped with the seconds since the robot booted instead of UTC (received at UTC all the same)
    write_run_bags(tmp_path / "run_01", synth, header_stamps={JOY: lambda i, t: t - synth.t_joy_utc[0] + 12.5})
    with pytest.raises(InputError, match=r"^run run_01: topic /joy_teleop/joy: header stamps 12\.500 to .* s are not "
                                         r"on the trigger's UTC \(.*\); the data contract stamps the joystick"):
        read_tracker_parts(tmp_path / "run_01")
