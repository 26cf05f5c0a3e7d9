"""Trajectory campaigns (data contract part 2): round trip, the real Warthog data, bad input."""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor import repairs
from groundfloor.errors import InputError
from groundfloor.types import BodyStates, InputSeries, PoseTrack, TrajectoryRun
from identification.preprocessing.trajectory import (
    GAPS_NOTE,
    gap_segments,
    quaternion_from_yaw_pitch,
    read_trajectory_campaign,
    write_trajectory_campaign,
)

T0_UTC = 1722278818.878209352


def _make_run(rng, name="r1", split="train", n=200, rate_hz=10.0, full=True) -> TrajectoryRun:
    """Return a run on UTC stamps with irregular pose and input timing."""
    t = T0_UTC + np.cumsum(rng.uniform(0.5, 1.5, n)) / rate_hz
    yaw = np.cumsum(rng.normal(0.0, 0.2, n))  # unwrapped, leaves [-pi, pi]
    nan = np.full(n, np.nan)
    cols = dict(t=t, x=rng.normal(size=n), y=rng.normal(size=n), yaw=yaw,
                z=rng.normal(size=n) if full else nan, pitch=rng.normal(0, 0.05, n) if full else nan,
                x_std=rng.uniform(1e-5, 1e-4, n) if full else nan, y_std=nan, z_std=nan,
                pitch_std=nan, yaw_std=rng.uniform(1e-4, 1e-3, n) if full else nan)
    m = 3 * n
    t_u = np.sort(rng.uniform(t[0] - 0.5, t[-1] + 0.5, m))
    return TrajectoryRun(name=name, split=split, poses=PoseTrack(**cols),
                         inputs=InputSeries(t=t_u, u1=rng.uniform(-1, 1, m), u2=rng.uniform(-1, 1, m)))


def _write_csv(path: Path, header: list[str], rows) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def _campaign(root: Path, t_pose, yaw=None, t_input=None, meta=None, pose_header=None, extra=None) -> Path:
    """Write a one-run campaign by hand (independent of the writer under test); return root."""
    t_pose = np.asarray(t_pose, dtype=float)
    yaw = np.zeros_like(t_pose) if yaw is None else yaw
    t_input = t_pose if t_input is None else np.asarray(t_input, dtype=float)
    meta = meta or {"name": "hand", "kind": "trajectory", "runs": [{"name": "a", "split": "test"}]}
    (root).mkdir(parents=True, exist_ok=True)
    (root / "campaign.yaml").write_text(yaml.safe_dump(meta) if isinstance(meta, dict) else meta)
    header = pose_header or ["t", "x", "y", "yaw"]
    rows = np.column_stack([t_pose, 0.1 * np.arange(t_pose.size), np.zeros_like(t_pose), yaw])
    if extra is not None:
        rows = np.column_stack([rows, extra])
    _write_csv(root / "runs" / "a" / "poses.csv", header, [[repr(float(v)) for v in r] for r in rows])
    _write_csv(root / "runs" / "a" / "inputs.csv", ["t", "u1", "u2"],
               [[repr(float(v)), "0.5", "0.1"] for v in t_input])
    return root


# --------------------------------------------------------------------------------------------


def test_round_trip_keeps_every_column_and_writes_tum_for_evo(tmp_path):
    rng = np.random.default_rng(0)
    runs = [_make_run(rng, "r1", "train"), _make_run(rng, "r2", "test", full=False)]
    n = runs[0].poses.t.size
    states = BodyStates(t=runs[0].poses.t, vx=rng.normal(size=n), vy=rng.normal(size=n),
                        omega=rng.normal(size=n), u1=rng.normal(size=n), u2=rng.normal(size=n),
                        x=runs[0].poses.x, y=runs[0].poses.y, yaw=runs[0].poses.yaw)
    out = write_trajectory_campaign(tmp_path / "c", "round", [(runs[0], states), (runs[1], None)],
                                    source="unit test")
    camp = read_trajectory_campaign(out)
    assert camp.name == "round" and [r.name for r in camp.runs] == ["r1", "r2"]
    assert [r.split for r in camp.runs] == ["train", "test"]
    for a, b in zip(runs, camp.runs):
        assert b.repairs == {}
        np.testing.assert_allclose(b.poses.t, a.poses.t, rtol=0, atol=1e-9)  # ns on UTC seconds
        for c in ("x", "y", "z", "pitch", "yaw", "x_std", "y_std", "z_std", "pitch_std", "yaw_std"):
            np.testing.assert_array_equal(getattr(b.poses, c), getattr(a.poses, c), err_msg=c)
        np.testing.assert_array_equal(b.inputs.u1, a.inputs.u1)
        np.testing.assert_allclose(b.inputs.t, a.inputs.t, rtol=0, atol=1e-9)
    back = np.genfromtxt(out / "runs" / "r1" / "states.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(back["omega"], states.omega)
    assert not (out / "runs" / "r2" / "states.csv").exists()
    assert yaml.safe_load((out / "campaign.yaml").read_text())["source"] == "unit test"

    # TUM: evo reads it, and the quaternion is Rz(yaw) Ry(pitch) (checked against scipy)
    from evo.tools import file_interface
    from scipy.spatial.transform import Rotation

    traj = file_interface.read_tum_trajectory_file(str(out / "runs" / "r1" / "poses.tum"))
    np.testing.assert_allclose(traj.positions_xyz[:, 2], runs[0].poses.z, atol=1e-12)
    q_wxyz = traj.orientations_quat_wxyz
    R_ref = Rotation.from_euler("ZY", np.column_stack([runs[0].poses.yaw, runs[0].poses.pitch]))
    R_got = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]])
    assert np.max((R_ref.inv() * R_got).magnitude()) < 1e-9
    q = quaternion_from_yaw_pitch(np.array([0.3]), np.array([0.0]))
    np.testing.assert_allclose(q, [[0, 0, np.sin(0.15), np.cos(0.15)]])
    # unknown z and pitch are written as 0 so evo can read them
    traj2 = file_interface.read_tum_trajectory_file(str(out / "runs" / "r2" / "poses.tum"))
    assert np.all(traj2.positions_xyz[:, 2] == 0.0)


def test_writer_refuses_non_empty_folder_and_leaves_it_intact(tmp_path):
    rng = np.random.default_rng(1)
    out = write_trajectory_campaign(tmp_path / "c", "x", [(_make_run(rng), None)])
    before = (out / "runs" / "r1" / "poses.csv").read_text()
    with pytest.raises(InputError, match="not empty"):
        write_trajectory_campaign(out, "y", [(_make_run(rng), None)])
    assert (out / "runs" / "r1" / "poses.csv").read_text() == before
    write_trajectory_campaign(out, "y", [(_make_run(rng, "r9"), None)], force=True)
    assert [r.name for r in read_trajectory_campaign(out).runs] == ["r9"]


@pytest.mark.parametrize("campaign, n_train, test_run", [
    ("warthog-drive-cmd", 7, "grass_2024_7_29_14h46s15_seg0"),
    ("warthog-drive-wheels", 4, "grass_2024_7_29_14h46s15"),
])
def test_real_warthog_campaigns_read_as_the_files_say(shared_dir, campaign, n_train, test_run):
    root = shared_dir / "data" / campaign
    camp = read_trajectory_campaign(root)
    assert camp.name == campaign
    assert len(camp.split("train")) == n_train and [r.name for r in camp.split("test")] == [test_run]
    for run in camp.runs:
        # second, independent parse with the csv module
        with open(root / "runs" / run.name / "poses.csv") as fh:
            rows = list(csv.DictReader(fh))
        assert run.poses.t.size == len(rows) and run.repairs == {}
        np.testing.assert_array_equal(run.poses.x, [float(r["x"]) for r in rows])
        np.testing.assert_array_equal(run.poses.pitch, [float(r["pitch"]) for r in rows])
        assert np.all(np.isnan(run.poses.yaw_std))  # optional column absent
        assert np.all(np.diff(run.poses.t) > 0) and np.all(np.diff(run.inputs.t) > 0)
        assert np.max(np.abs(np.diff(run.poses.yaw))) < 1.0  # unwrapped
        assert 0.09 < np.median(np.diff(run.poses.t)) < 0.16  # ICP at about 10 Hz, not 50 Hz
        assert 0.049 < np.median(np.diff(run.inputs.t)) < 0.051
        assert np.abs(run.inputs.u1).max() <= 1.1 and np.abs(run.inputs.u2).max() <= 1.1  # "about [-1, 1]"


def test_wrapped_yaw_is_unwrapped_and_extra_columns_ignored(tmp_path):
    t = np.arange(100) * 0.1
    yaw_true = 1.5 * t  # 15 rad: more than two turns
    wrapped = np.angle(np.exp(1j * yaw_true))
    root = _campaign(tmp_path / "c", t, yaw=wrapped, pose_header=["t", "x", "y", "yaw", "speed"],
                     extra=np.ones_like(t))
    run = read_trajectory_campaign(root / "campaign.yaml").runs[0]
    np.testing.assert_allclose(run.poses.yaw, yaw_true, atol=1e-12)
    assert np.all(np.isnan(run.poses.z))


# --------------------------------------------------------------------------------------------
# bad input: one test per kind, each asserting the message or count names the culprit


def test_poses_and_inputs_without_overlap_name_the_run(tmp_path):
    t = np.arange(50) * 0.1
    root = _campaign(tmp_path / "c", t, t_input=t + 100.0)
    with pytest.raises(InputError, match=r"run a: poses .* do not overlap in time; they last about as long "
                                         r"\(4.9 s and 4.9 s\): one file counted from the run's start"):
        read_trajectory_campaign(root)
    # inputs of another recording altogether (a quarter as long): no such guess
    root = _campaign(tmp_path / "d", t, t_input=t[:12] + 100.0)
    with pytest.raises(InputError, match=r"run a: poses \(0.000 to 4.900 s\) and inputs \(100.000 to 101.100 s\) "
                                         r"do not overlap in time$"):
        read_trajectory_campaign(root)


def test_poses_beyond_the_inputs_span_are_left_out_and_counted(tmp_path, caplog):
    # a logger that started 3 s late and stopped 12 s early: 20 Hz inputs from 3.0 to 7.95 s
    # under 10 Hz poses from 0 to 19.9 s. The inputs' ends hold for the gap threshold of their
    # stamps, max(0.5 s, 10 x 0.05 s) = 0.5 s, so by hand the poses 2.5 s to 8.4 s remain.
    t = np.arange(200) * 0.1
    t_in = 3.0 + np.arange(100) * 0.05
    root = _campaign(tmp_path / "c", t, t_input=t_in)
    with caplog.at_level(logging.WARNING):
        run = read_trajectory_campaign(root).runs[0]
    np.testing.assert_allclose(run.poses.t, np.arange(25, 85) * 0.1, atol=1e-12)
    assert run.repairs == {"poses_outside_inputs": 140}
    assert "run a: 140 poses (2.5 s before the first input, 11.5 s after the last) left out" in caplog.text
    # inputs that end with the poses, within the hold, leave every pose
    root = _campaign(tmp_path / "d", t, t_input=np.arange(0.4, 19.5, 0.05))
    assert read_trajectory_campaign(root).runs[0].poses.t.size == 200


def test_ten_second_hole_is_counted_and_splits_segments(tmp_path, caplog):
    t = np.concatenate([np.arange(100) * 0.1, 19.9 + np.arange(100) * 0.1])  # 10 s hole
    root = _campaign(tmp_path / "c", t)
    repairs.clear()
    with caplog.at_level(logging.INFO):
        run = read_trajectory_campaign(root).runs[0]
    assert run.repairs == {"gaps": 1}
    # an expected repair: logged at INFO and noted for the command's one-line summary, no warning
    assert "run a: 1 pose gaps" in caplog.text
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert repairs.summary() == [f"{GAPS_NOTE}: 1 in 1 runs (a 1)"]
    repairs.clear()
    np.testing.assert_array_equal(gap_segments(run.poses.t), [[0, 100], [100, 200]])
    # the trigger's skipped pulse (2 intervals at 50 Hz) is no gap
    t50 = np.delete(np.arange(500) * 0.02, [150, 300])
    assert gap_segments(t50).shape == (1, 2)


def test_nan_rows_are_dropped_and_counted(tmp_path):
    t = np.arange(60) * 0.1
    yaw = np.zeros_like(t)
    yaw[[5, 17, 40]] = np.nan
    root = _campaign(tmp_path / "c", t, yaw=yaw)
    run = read_trajectory_campaign(root).runs[0]
    assert run.repairs == {"nan_pose_rows": 3}
    assert run.poses.t.size == 57 and not np.any(np.isin(run.poses.t, t[[5, 17, 40]]))


def test_duplicate_stamps_are_merged_and_counted(tmp_path):
    t = np.arange(60) * 0.1
    t_dup = np.insert(t, [10, 30], t[[10, 30]])
    root = _campaign(tmp_path / "c", t_dup, t_input=np.insert(t, 7, t[7]))
    run = read_trajectory_campaign(root).runs[0]
    assert run.repairs == {"duplicate_pose_stamps": 2, "duplicate_input_stamps": 1}
    np.testing.assert_array_equal(run.poses.t, t)
    # x was 0.1 * row index: rows 10, 11 (same stamp) average to 1.05
    assert run.poses.x[10] == pytest.approx(1.05)


def test_stamps_going_backwards_name_file_and_row(tmp_path):
    t = np.arange(60) * 0.1
    t[20] = 1.0
    root = _campaign(tmp_path / "c", t)
    with pytest.raises(InputError, match=r"poses\.csv: stamps not in time order at row 22"):
        read_trajectory_campaign(root)


def test_missing_required_column_names_file_and_column(tmp_path):
    root = _campaign(tmp_path / "c", np.arange(20) * 0.1, pose_header=["t", "x", "y", "heading"])
    with pytest.raises(InputError, match=r"runs/a/poses\.csv: required column 'yaw' missing"):
        read_trajectory_campaign(root)


@pytest.mark.parametrize("text, match", [
    ("runs: [unclosed", r"campaign\.yaml: not valid YAML"),
    ("- just\n- a list\n", r"campaign\.yaml: expected a mapping"),
    ("kind: tracker\nruns: [{name: a, split: test}]\n", r"key 'kind' is 'tracker'"),
    ("kind: trajectory\n", r"key 'runs' missing"),
    ("kind: trajectory\nruns: [{name: a, split: validation}]\n", r"run a: key 'split' is 'validation'"),
    ("kind: trajectory\nruns: [{name: a, split: test}, {name: b, split: train}]\n", r"run b: folder .* missing"),
])
def test_wrong_campaign_yaml_names_the_key(tmp_path, text, match):
    root = _campaign(tmp_path / "c", np.arange(20) * 0.1, meta=text)
    with pytest.raises(InputError, match=match):
        read_trajectory_campaign(root)


def test_missing_campaign_folder_or_inputs_file(tmp_path):
    with pytest.raises(InputError, match="campaign folder missing"):
        read_trajectory_campaign(tmp_path / "nope")
    root = _campaign(tmp_path / "c", np.arange(20) * 0.1)
    (root / "runs" / "a" / "inputs.csv").unlink()
    with pytest.raises(InputError, match=r"runs/a/inputs\.csv: file missing"):
        read_trajectory_campaign(root)


def test_writer_refuses_runs_with_arrays_of_different_lengths(tmp_path):
    from dataclasses import replace

    run = _make_run(np.random.default_rng(2))
    bad = replace(run, inputs=replace(run.inputs, u1=run.inputs.u1[:-1]))
    with pytest.raises(InputError, match="run r1: input arrays differ in length"):
        write_trajectory_campaign(tmp_path / "c", "x", [(bad, None)])
    assert not (tmp_path / "c").exists()


def test_a_spreadsheet_export_with_a_byte_order_mark_reads_and_semicolons_are_named(tmp_path):
    # Excel's "CSV UTF-8" starts the file with a byte-order mark; a European export separates by ';'
    t = np.arange(50) * 0.1
    root = _campaign(tmp_path / "c", t)
    plain = read_trajectory_campaign(root).runs[0]
    for name in ("poses.csv", "inputs.csv"):
        p = root / "runs" / "a" / name
        p.write_text("\ufeff" + p.read_text())
    bom = read_trajectory_campaign(root).runs[0]
    np.testing.assert_array_equal(bom.poses.t, plain.poses.t)
    np.testing.assert_array_equal(bom.inputs.u1, plain.inputs.u1)
    for name in ("poses.csv", "inputs.csv"):  # R's write.csv quotes every column name
        p = root / "runs" / "a" / name
        head, body = p.read_text().lstrip("\ufeff").split("\n", 1)
        p.write_text(",".join(f'"{h}"' for h in head.split(",")) + "\n" + body)
    quoted = read_trajectory_campaign(root).runs[0]
    np.testing.assert_array_equal(quoted.poses.yaw, plain.poses.yaw)
    np.testing.assert_array_equal(quoted.inputs.u2, plain.inputs.u2)
    p = root / "runs" / "a" / "poses.csv"
    p.write_text(p.read_text().replace('"', "").replace(",", ";"))
    with pytest.raises(InputError, match=r"poses.csv: required column 't' missing \(header: t;x;y;yaw\); columns "
                                         r"separated by ';', the data contract's CSV files use commas"):
        read_trajectory_campaign(root)


def test_stamps_in_milliseconds_are_named_not_read_as_seconds(tmp_path):
    # 10 Hz poses stamped in ms are 100 "s" apart: read as seconds, every later figure would be
    # nonsense (5 s windows of 5 ms); 0.5 Hz is the slowest ground truth taken as seconds
    t = 1722278818.878 + np.arange(300) * 0.1
    with pytest.raises(InputError, match=r"poses.csv: the poses are 100 s apart \(median\) over 8.31 h: t must be in "
                                         r"seconds \(milliseconds or nanoseconds\?\)"):
        read_trajectory_campaign(_campaign(tmp_path / "ms", t * 1000.0))
    assert read_trajectory_campaign(_campaign(tmp_path / "slow", np.arange(300) * 2.0)).runs[0].poses.t.size == 300


def test_yaw_in_degrees_is_named_not_read_as_radians(tmp_path):
    # a robot turning at 0.5 rad/s for 30 s, its yaw written in degrees (wrapping at +-180): read as
    # radians it would turn at 28.6 rad/s; in radians, with 2 mrad noise at 200 Hz, it reads
    rng = np.random.default_rng(4)
    t = np.arange(6000) * 0.005
    yaw = 0.5 * t + rng.normal(0.0, 0.002, t.size)
    deg = (np.degrees(0.5 * t) + 180.0) % 360.0 - 180.0  # by hand: 0.5 rad/s is 28.65 deg/s
    with pytest.raises(InputError, match=r"poses.csv: column yaw turns at 28.6 rad/s \(95th percentile\), faster "
                                         r"than a ground robot turns: yaw must be in radians \(degrees\?\)"):
        read_trajectory_campaign(_campaign(tmp_path / "deg", t, yaw=deg))
    run = read_trajectory_campaign(_campaign(tmp_path / "rad", t, yaw=np.angle(np.exp(1j * yaw)))).runs[0]
    np.testing.assert_allclose(run.poses.yaw, yaw, atol=1e-9)


def test_a_hole_in_the_inputs_while_the_poses_go_on_is_named_and_held(tmp_path, caplog):
    # 10 Hz poses over 40 s; 20 Hz inputs silent from 10 s to 20 s (a recorder's pause, or a
    # stick held on a joystick that publishes on change): named, counted, the inputs kept as they are
    t = np.arange(400) * 0.1
    t_in = np.concatenate([np.arange(0.0, 10.0 + 1e-9, 0.05), np.arange(20.0, 39.95, 0.05)])
    with caplog.at_level(logging.WARNING):
        run = read_trajectory_campaign(_campaign(tmp_path / "c", t, t_input=t_in)).runs[0]
    assert run.repairs == {"input_holes": 1} and run.poses.t.size == 400 and run.inputs.t.size == t_in.size
    assert "inputs.csv holds its inputs through 1 holes longer than 2 s while the poses go on, the longest " \
           "10.0 s from t = 10.000 s" in caplog.text
    # the same hole in the poses too (the whole recording paused) is a pose gap, not an input hole
    t_gap = t[(t < 10.0) | (t > 20.0)]
    run = read_trajectory_campaign(_campaign(tmp_path / "d", t_gap, t_input=t_in)).runs[0]
    assert run.repairs == {"gaps": 1}


def test_run_folders_not_listed_in_campaign_yaml_are_named_not_read(tmp_path, caplog):
    # a run copied into runs/ without its entry in campaign.yaml: left out, but said so
    import shutil

    t = np.arange(100) * 0.1
    root = _campaign(tmp_path / "c", t)
    with caplog.at_level(logging.WARNING):
        read_trajectory_campaign(root)
    assert "not listed" not in caplog.text
    shutil.copytree(root / "runs" / "a", root / "runs" / "b_copied")
    (root / "runs" / ".hidden").mkdir()
    (root / "runs" / "notes.txt").write_text("x")
    with caplog.at_level(logging.WARNING):
        camp = read_trajectory_campaign(root)
    assert [r.name for r in camp.runs] == ["a"]
    assert f"{root / 'runs'}: run folder b_copied is not listed in campaign.yaml; not read" in caplog.text


def _unicycle_campaign(root: Path, mirror=False, flip_u1=False, yaw_offset=0.0) -> Path:
    """Write a one-run campaign of a unicycle driven by its inputs (v = u1 m/s, omega = u2 rad/s,
    integrated by hand at 100 Hz, poses at 10 Hz), its frame or an input's sign changed as asked."""
    dt = 0.01
    t = np.arange(0.0, 60.0, dt)
    u1, u2 = 0.5 + 0.3 * np.sin(0.3 * t), np.sin(0.5 * t)
    yaw = np.concatenate([[0.0], np.cumsum(u2[:-1] * dt)])
    x = np.concatenate([[0.0], np.cumsum(u1[:-1] * np.cos(yaw[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(u1[:-1] * np.sin(yaw[:-1]) * dt)])
    if mirror:  # a left-handed frame: y and the yaw's sense negated
        y, yaw = -y, -yaw
    k = slice(None, None, 10)
    meta = {"name": "hand", "kind": "trajectory", "runs": [{"name": "a", "split": "train"}]}
    root.mkdir(parents=True)
    (root / "campaign.yaml").write_text(yaml.safe_dump(meta))
    _write_csv(root / "runs" / "a" / "poses.csv", ["t", "x", "y", "yaw"],
               [[repr(float(v)) for v in r] for r in np.column_stack([t[k], x[k], y[k], yaw[k] + yaw_offset])])
    _write_csv(root / "runs" / "a" / "inputs.csv", ["t", "u1", "u2"],
               [[repr(float(v)) for v in r] for r in np.column_stack([t, -u1 if flip_u1 else u1, u2])])
    return root


@pytest.mark.parametrize("change, named", [({}, ()), ({"mirror": True}, ("u2",)), ({"flip_u1": True}, ("u1",)),
                                           ({"yaw_offset": np.pi}, ("u1",))])
def test_an_input_against_the_contracts_sign_is_named(tmp_path, caplog, change, named):
    # u1 forward and u2 left (counter-clockwise) positive: a left-handed (NED-like) frame turns u2
    # against the yaw rate, an inverted throttle or a yaw 180 degrees off turns u1 against the speed
    root = _unicycle_campaign(tmp_path / "c", **change)
    with caplog.at_level(logging.WARNING):
        read_trajectory_campaign(root)
    for u in ("u1", "u2"):
        said = f"{u} and the " in caplog.text and "are anti-correlated" in caplog.text
        assert said == (u in named), (u, caplog.text)


def test_a_column_of_text_is_named_not_read_as_nan_rows(tmp_path):
    # a logger's ISO date-times in t, or units beside every number: each row used to be dropped as a
    # NaN row, and the file called "fewer than 2 valid pose rows"
    t = np.arange(50) * 0.1
    root = _campaign(tmp_path / "c", t)
    poses = root / "runs" / "a" / "poses.csv"
    rows = list(csv.reader(open(poses)))
    iso = [rows[0]] + [[f"2024-07-29T18:45:{float(r[0]):09.6f}Z"] + r[1:] for r in rows[1:]]
    _write_csv(poses, iso[0], iso[1:])
    with pytest.raises(InputError, match=r"poses.csv: column t holds no numbers \(first value '2024-07-29T18:45:00.000000Z'\); "
                                         r"a date and time\? the data contract's t is in seconds"):
        read_trajectory_campaign(root)
    _write_csv(poses, rows[0], [[r[0], r[1] + " m"] + r[2:] for r in rows[1:]])
    with pytest.raises(InputError, match=r"poses.csv: column x holds no numbers \(first value '0.0 m'\)$"):
        read_trajectory_campaign(root)
    rows[5][1] = "n/a"  # one row of text stays a NaN row, dropped and counted
    _write_csv(poses, rows[0], rows[1:])
    assert read_trajectory_campaign(root).runs[0].repairs["nan_pose_rows"] == 1


def test_a_run_with_a_tum_trajectory_instead_of_poses_csv_is_read(tmp_path):
    # evo's and the SLAM benchmarks' format: t x y z qx qy qz qw; quaternions from scipy's Rotation
    # (not the project's writer), with a roll the reader must not mistake for yaw or pitch
    from scipy.spatial.transform import Rotation

    t = np.arange(100) * 0.1
    yaw = 1.2 * t - 3.0  # 12 rad: wraps several times
    pitch, roll = 0.05 * np.sin(t), 0.04 * np.cos(t)
    q = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_quat()  # x, y, z, w
    root = _campaign(tmp_path / "c", t, meta={"name": "tum", "runs": [{"name": "a", "split": "test"}]})
    (root / "runs" / "a" / "poses.csv").unlink()
    xyz = np.column_stack([0.1 * t, -0.2 * t, np.full_like(t, 0.3)])
    lines = ["# t x y z qx qy qz qw"] + [" ".join(repr(float(v)) for v in row) for row in np.column_stack([t, xyz, q])]
    (root / "runs" / "a" / "poses.tum").write_text("\n".join(lines) + "\n")
    from identification.preprocessing.campaigns import campaign_kind

    assert campaign_kind(root) == "trajectory"  # no 'kind' key: found by its files
    run = read_trajectory_campaign(root).runs[0]
    np.testing.assert_allclose(run.poses.yaw - run.poses.yaw[0] + yaw[0], yaw, atol=1e-9)
    assert abs(run.poses.yaw[0] - yaw[0]) < 1e-9 or abs(abs(run.poses.yaw[0] - yaw[0]) - 2 * np.pi) < 1e-9
    np.testing.assert_allclose(run.poses.pitch, pitch, atol=1e-9)
    np.testing.assert_allclose(np.column_stack([run.poses.x, run.poses.y, run.poses.z]), xyz, atol=1e-12)
    (root / "runs" / "a" / "poses.tum").write_text("\n".join(line.rsplit(" ", 1)[0] for line in lines) + "\n")
    with pytest.raises(InputError, match=r"poses.tum: a TUM trajectory has 8 columns \(t x y z qx qy qz qw\), this one 7"):
        read_trajectory_campaign(root)
