"""Every bad input answered before the work starts (issue 14, item 4), one case per test, each
built by code: output paths that cannot be written, inputs beyond the contract's range, poses that
never move, test runs too short to benchmark. Each ends in a one-line error naming the culprit and
exit 2 with no output written, or is a fault handled and counted."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf.cli import main
from tests.support.trajectory_synth import MINI_RUNS, write_mini_campaign

SHORT_RUNS = (("run_a", 20.0, "train"), ("run_b", 20.0, "train"), ("run_c", 25.0, "test"))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A short trajectory campaign of the simulator and the true model's file."""
    tmp = tmp_path_factory.mktemp("bad_input")
    root = write_mini_campaign(tmp / "mini", runs=SHORT_RUNS)
    return root, model_from_terms(RobotParams().terms()).to_json(tmp / "model.json")


def _one_line_error(capsys, code, *names):
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "error:" in err and "Traceback" not in err, err
    for name in names:
        assert name in err, (name, err)
    return err


def _copy(root, tmp_path):
    import shutil

    return shutil.copytree(root, tmp_path / root.name)


def _rewrite_column(path, column, fn):
    """Rewrite one column of a CSV file with ``fn(values)``."""
    head, *rows = path.read_text().splitlines()
    names = head.split(",")
    data = np.array([[float(v) for v in r.split(",")] for r in rows])
    j = names.index(column)
    data[:, j] = fn(data[:, j])
    path.write_text("\n".join([head] + [",".join(repr(float(v)) for v in r) for r in data]) + "\n")


# --- output paths, checked before the work ----------------------------------------------------

@pytest.mark.parametrize("command", ["evaluate", "diagnose", "benchmark"])
def test_json_under_a_file_is_an_error_before_the_work(small, tmp_path, capsys, command):
    root, model = small
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = tmp_path / "out"
    extra = ["--out", str(out)] if command == "benchmark" else []
    code = main([command, str(root), "--model", str(model), "--json", str(blocker / "r.json"), *extra, "--quiet"])
    _one_line_error(capsys, code, "--json", "a_file")
    assert not out.exists()


@pytest.mark.parametrize("command", ["evaluate", "diagnose"])
def test_plots_naming_an_existing_file_is_an_error_before_the_work(small, tmp_path, capsys, command):
    root, model = small
    plots = tmp_path / "plots.png"
    plots.write_text("x")
    code = main([command, str(root), "--model", str(model), "--plots", str(plots),
                 "--json", str(tmp_path / "r.json"), "--quiet"])
    _one_line_error(capsys, code, "--plots", "plots.png")
    assert not (tmp_path / "r.json").exists() and plots.read_text() == "x"


def test_benchmark_out_naming_a_file_is_an_error_before_the_work(small, tmp_path, capsys):
    root, model = small
    target = tmp_path / "results.txt"
    target.write_text("x")
    code = main(["benchmark", str(root), "--model", str(model), "--out", str(target),
                 "--json", str(tmp_path / "b.json"), "--quiet"])
    _one_line_error(capsys, code, "--out", "results.txt")
    assert not (tmp_path / "b.json").exists()


def test_simulate_json_under_a_file_leaves_no_campaign(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    code = main(["simulate", str(tmp_path / "camp"), "--minutes", "0.5",
                 "--json", str(blocker / "s.json"), "--quiet"])
    _one_line_error(capsys, code, "--json", "a_file")
    assert not (tmp_path / "camp").exists()


@pytest.mark.parametrize("option", ["--json", "--plots"])
def test_preprocess_outputs_are_checked_before_reading_a_bag(small, tmp_path, capsys, option):
    root, _ = small
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    bad = str(blocker / "x.json") if option == "--json" else str(blocker)
    code = main(["preprocess", str(root), "--out", str(tmp_path / "traj"), option, bad, "--quiet"])
    _one_line_error(capsys, code, option, "a_file")
    assert not (tmp_path / "traj").exists()


def test_preprocess_of_a_trajectory_campaign_says_it_is_preprocessed_already(small, tmp_path, capsys):
    root, _ = small  # poses and inputs per run, no bags, no calibration.yaml
    code = main(["preprocess", str(root), "--out", str(tmp_path / "traj"), "--quiet"])
    _one_line_error(capsys, code, str(root), "a trajectory campaign", "preprocessed already")
    assert not (tmp_path / "traj").exists()


def test_identify_plots_naming_a_file_is_an_error_before_the_search(small, tmp_path, capsys):
    root, _ = small
    plots = tmp_path / "plots"
    plots.write_text("x")
    code = main(["identify", str(root), "--out", str(tmp_path / "m.json"), "--plots", str(plots), "--quiet"])
    _one_line_error(capsys, code, "--plots")
    assert not (tmp_path / "m.json").exists()


# --- inputs outside the contract, poses that never move ---------------------------------------

@pytest.mark.parametrize("column", ["u1", "u2"])
def test_inputs_a_hundred_times_too_large_are_an_error_naming_file_and_column(small, tmp_path, capsys, column):
    root, model = small
    camp = _copy(root, tmp_path)
    _rewrite_column(camp / "runs" / "run_b" / "inputs.csv", column, lambda u: 100.0 * u)
    code = main(["evaluate", str(camp), "--model", str(model), "--json", str(tmp_path / "e.json"), "--quiet"])
    _one_line_error(capsys, code, "run_b", "inputs.csv", f"column {column}")
    assert not (tmp_path / "e.json").exists()


def test_inputs_at_the_edge_of_the_range_are_accepted():
    from groundfloor.types import INPUT_ABS_MAX, check_input_range

    check_input_range(np.array([-1.0, 1.0, INPUT_ABS_MAX, -INPUT_ABS_MAX, np.nan]), "f", "u1")
    with pytest.raises(Exception, match=r"f: column u1: 1 value\(s\).*first -1.51 at row 2"):
        check_input_range(np.array([0.0, 1.0, -1.51]), "f", "u1")


def test_poses_that_never_move_are_an_error_naming_the_run(small, tmp_path, capsys):
    root, model = small
    camp = _copy(root, tmp_path)
    poses = camp / "runs" / "run_a" / "poses.csv"
    for column in ("x", "y", "yaw"):
        _rewrite_column(poses, column, lambda v: np.full_like(v, v[0]) + 1e-5 * np.sin(np.arange(v.size)))
    code = main(["benchmark", str(camp), "--model", str(model), "--estimators", "cv_ekf", "--quiet"])
    _one_line_error(capsys, code, "run run_a", "never move")


def test_a_robot_that_turns_on_the_spot_moves():
    from groundfloor.types import check_poses_move

    n = 100
    check_poses_move(np.zeros(n), np.zeros(n), np.linspace(0.0, 0.5, n), "turning")
    check_poses_move(np.linspace(0.0, 0.05, n), np.zeros(n), np.zeros(n), "driving")
    with pytest.raises(Exception, match="standing: poses never move"):
        check_poses_move(np.full(n, 2.0), np.zeros(n), np.full(n, 0.3), "standing")


# --- test runs too short to benchmark --------------------------------------------------------

@pytest.fixture(scope="module")
def with_short_run(tmp_path_factory):
    """The mini campaign, and the same with a 3 s test run after it (the other runs unchanged)."""
    tmp = tmp_path_factory.mktemp("short_run")
    plain = write_mini_campaign(tmp / "plain")
    short = write_mini_campaign(tmp / "short", runs=MINI_RUNS + (("run_d", 3.0, "test"),))
    return plain, short, model_from_terms(RobotParams().terms()).to_json(tmp / "model.json")


def test_a_test_run_too_short_is_named_and_skipped_not_scored(with_short_run, tmp_path, capsys):
    plain, short, model = with_short_run
    args = ["--model", str(model), "--estimators", "cv_ekf,sindy_ekf", "--quiet"]
    assert main(["benchmark", str(short), *args, "--json", str(tmp_path / "short.json")]) == 0
    err = capsys.readouterr().err
    assert "warning: run run_d: 3.0 s" in err and "shorter than" in err
    assert main(["benchmark", str(plain), *args, "--json", str(tmp_path / "plain.json")]) == 0
    doc = json.loads((tmp_path / "short.json").read_text())
    ref = json.loads((tmp_path / "plain.json").read_text())
    assert list(doc["skipped_runs"]) == ["run_d"] and "3.0 s" in doc["skipped_runs"]["run_d"]
    assert ref["skipped_runs"] == {}
    # the scores are those of the campaign without the short run: it weighs nothing
    for name in ("cv_ekf", "sindy_ekf"):
        assert doc["estimators"][name]["ate_pos_m"] == ref["estimators"][name]["ate_pos_m"]


def test_a_campaign_whose_test_runs_are_all_too_short_is_an_error(tmp_path, capsys):
    root = write_mini_campaign(tmp_path / "tiny", runs=(("run_a", 20.0, "train"), ("run_t", 4.0, "test")))
    model = model_from_terms(RobotParams().terms()).to_json(tmp_path / "model.json")
    code = main(["benchmark", str(root), "--model", str(model), "--estimators", "cv_ekf", "--quiet"])
    _one_line_error(capsys, code, "run_t", "too short")
