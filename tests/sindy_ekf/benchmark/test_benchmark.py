"""Benchmark on a small simulated trajectory campaign: our ATE equals evo's on the same TUM files,
scores ordered as the estimators' information implies, the command's JSON and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sindy_ekf.benchmark.figures import write_benchmark_figures
from sindy_ekf.benchmark.files import read_tum, write_benchmark
from sindy_ekf.benchmark.run import benchmark_campaign
from sindy_ekf.benchmark.scoring import ate


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """Two train runs and one test run of the simulator, written as a trajectory campaign."""
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from identification.sindy.model import model_from_terms
    from simulation.robot import RobotParams, TrueDynamics
    from tests.support.trajectory_synth import write_mini_campaign

    root = write_mini_campaign(tmp_path_factory.mktemp("bench") / "mini")
    model = model_from_terms(RobotParams().terms())  # a perfectly identified model
    campaign = read_trajectory_campaign(root)
    result = benchmark_campaign(campaign, model, "dgnss", seed=3, oracle_dynamics=TrueDynamics(),
                                estimators=("dead_reckoning", "cv_ekf", "unicycle_ekf", "sindy_ekf",
                                            "oracle_ekf", "sindy_graph", "sindy_ekf_lateral",
                                            "sindy_graph_lateral"),
                                outage_warmup_s=10.0, outage_recovery_s=12.0)
    out = write_benchmark(result, root.parent / "out")
    write_benchmark_figures(result, out)
    return root, model, result, out


def test_our_ate_equals_evo_on_the_same_tum_files(mini):
    # evo is GPL: a test-only dependency, imported here and never by the package
    from evo.core import metrics, sync
    from evo.tools import file_interface as evo_file

    _, _, result, out = mini
    ref_path = out / "tum" / "truth" / "run_c.tum"
    for name in ("sindy_ekf", "cv_ekf", "dead_reckoning"):
        est_path = out / "tum" / name / "run_c.tum"
        ours_pos, ours_yaw = ate(read_tum(ref_path), read_tum(est_path))
        ref, est = sync.associate_trajectories(evo_file.read_tum_trajectory_file(ref_path),
                                               evo_file.read_tum_trajectory_file(est_path), max_diff=0.01)
        values = {}
        for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
            ape = metrics.APE(rel)
            ape.process_data((ref, est))
            values[rel] = ape.get_statistic(metrics.StatisticsType.rmse)
        assert ours_pos == pytest.approx(values[metrics.PoseRelation.translation_part], rel=1e-9)
        assert ours_yaw == pytest.approx(values[metrics.PoseRelation.rotation_angle_deg], rel=1e-6)
        # and the benchmark's own score (one test run) is the same number
        assert result.scores[name].ate_pos_m == pytest.approx(ours_pos, rel=1e-6)


def test_scores_follow_the_information_each_estimator_has(mini):
    _, _, result, _ = mini
    s = result.scores
    assert result.alignment == "none"
    assert set(s["sindy_ekf"].outage_pos_err_m) == {"5", "10"}  # 45 s: warm-up 10, 5, 12, 10
    assert s["sindy_ekf"].ate_pos_m < 0.3  # dgnss: 0.3 m per axis
    # the true terms as "identified" model: as good as the oracle, better than the baselines
    assert s["sindy_ekf"].ate_pos_m < 1.3 * s["oracle_ekf"].ate_pos_m
    for base in ("cv_ekf", "unicycle_ekf"):
        assert s["sindy_ekf"].outage_pos_err_m["10"] < s[base].outage_pos_err_m["10"]
    assert s["sindy_graph"].ate_pos_m <= s["sindy_ekf"].ate_pos_m
    assert 0.5 < s["sindy_ekf"].nis_mean < 4.0  # 2 dof
    assert np.isnan(s["dead_reckoning"].nis_mean)


def test_lateral_pseudo_measurements_run_by_default_and_keep_the_true_model_accurate(mini):
    from sindy_ekf.benchmark.run import ESTIMATORS

    _, _, result, _ = mini
    s = result.scores
    assert "sindy_ekf_lateral" in ESTIMATORS
    # the simulator's vy is small but not zero: the fitted constraint must not spoil the true model
    assert s["sindy_ekf_lateral"].ate_pos_m < 1.3 * s["sindy_ekf"].ate_pos_m
    assert s["sindy_ekf_lateral"].outage_pos_err_m["10"] < s["unicycle_ekf"].outage_pos_err_m["10"]
    assert 0.5 < s["sindy_ekf_lateral"].nis_mean < 4.0
    # the graph with the same v_y = 0 factors: no worse than the graph without on the true model
    assert "sindy_graph_lateral" in ESTIMATORS
    assert s["sindy_graph_lateral"].ate_pos_m < 1.3 * s["sindy_graph"].ate_pos_m
    assert s["sindy_graph_lateral"].outage_pos_err_m["10"] < s["unicycle_ekf"].outage_pos_err_m["10"]


def test_outputs_hold_tum_files_json_and_plots(mini):
    _, _, result, out = mini
    for name in result.estimates:
        assert (out / "tum" / name / "run_c.tum").is_file()
    doc = json.loads((out / "benchmark.json").read_text())
    for name in ("dead_reckoning", "cv_ekf", "unicycle_ekf", "sindy_ekf", "sindy_graph"):
        entry = doc["estimators"][name]
        assert {"ate_pos_m", "ate_yaw_deg", "outage_pos_err_m", "runtime_s"} <= set(entry)
    assert (out / "trajectories.png").stat().st_size > 1000
    assert (out / "outage_errors.png").stat().st_size > 1000
    assert (out / "nees.png").stat().st_size > 1000
    assert (out / "error_bands.png").stat().st_size > 1000


def test_command_rejects_a_model_whose_features_do_not_match(mini, tmp_path, capsys):
    from sindy_ekf.cli import main

    root, model, _, _ = mini
    doc = model.to_dict()
    doc["feature_names"] = doc["feature_names"][:-1] + ["u2^7"]
    bad = tmp_path / "bad_model.json"
    bad.write_text(json.dumps(doc))
    code = main(["benchmark", str(root), "--model", str(bad), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert "bad_model.json" in err and "feature_names" in err and len(err.strip().splitlines()) == 1


def test_command_rejects_an_unknown_estimator(mini, tmp_path, capsys):
    from sindy_ekf.cli import main

    root, model, _, _ = mini
    path = model.to_json(tmp_path / "model.json")
    code = main(["benchmark", str(root), "--model", str(path), "--estimators", "sindy_ekf,kalman9", "--quiet"])
    assert code == 2 and "kalman9" in capsys.readouterr().err


def test_nees_curve_of_the_figure_matches_the_score(mini):
    """The NEES drawn in nees.png is the one scored: its mean over the one test run is nees_mean."""
    from sindy_ekf.benchmark.scoring import pose_nees

    _, _, result, _ = mini
    curves = pose_nees(result, "run_c")
    assert {"cv_ekf", "sindy_ekf", "sindy_graph"} <= set(curves)
    for name, (t, nees) in curves.items():
        assert t.shape == nees.shape and t[0] >= 0.0
        assert np.mean(nees) == pytest.approx(result.scores[name].nees_mean, rel=1e-12)
