"""The stages the commands and the report share: what they score, on which windows, with which oracle."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest

from groundfloor.errors import InputError
from identification.preprocessing.trajectory import read_trajectory_campaign
from identification.sindy.model import model_from_terms
from simulation.effects import Effect
from simulation.robot import RobotParams, TrueDynamics
from sindy_ekf.benchmark.run import ESTIMATORS
from sindy_ekf.stages.estimation import estimators_for
from sindy_ekf.stages.evaluation import evaluate_files, evaluation_stage
from tests.support.trajectory_synth import write_mini_campaign
from tests.support.truth_synth import write_bare_truth


def perfect_model():
    """The simulator's dynamics without effect, as an identified model would be at best."""
    return model_from_terms(RobotParams().terms(), hyperparameters={"s": 0.0005, "tau": 1.0})


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """A trajectory campaign of the simulator (no truth) and :func:`perfect_model` as a model file."""
    root = write_mini_campaign(tmp_path_factory.mktemp("stages") / "mini")
    return root, perfect_model().to_json(root.parent / "model.json")


def test_evaluation_scores_every_model_on_the_same_windows(mini):
    root, path = mini
    out = evaluate_files(root, path, methods=("rk4", "euler2")).to_json()
    assert set(out) == {"pos_err_5s_m", "yaw_err_5s_deg", "n_windows", "euler2", "baselines",  # no truth: no oracle
                        "reference_smoothing", "start_state_sensitivity", "beats_lag"}  # no CV in a hand-made file
    assert set(out["baselines"]) == {"constant_velocity", "unicycle", "lag"}
    assert out["n_windows"] > 0
    assert all(b["n_windows"] == out["n_windows"] for b in [out["euler2"], *out["baselines"].values()])
    # the simulator's own dynamics predict better than a model that ignores the inputs
    assert out["pos_err_5s_m"] < out["baselines"]["constant_velocity"]["pos_err_5s_m"]


def test_scoring_does_not_depend_on_the_models_smoothing(mini):
    root, _ = mini
    campaign = read_trajectory_campaign(root)
    a = evaluation_stage(campaign, perfect_model()).to_json()
    b = evaluation_stage(campaign, replace(perfect_model(), hyperparameters={"s": 50.0, "tau": 1.0})).to_json()
    assert a["pos_err_5s_m"] == b["pos_err_5s_m"] and a["baselines"]["lag"] == b["baselines"]["lag"]
    sens = a["start_state_sensitivity"]
    assert sens["smoothing"] == [0.1, 1.0, 10.0]
    assert sens["pos_err_5s_m"]["sindy"][1] == a["pos_err_5s_m"]
    assert len(sens["pos_err_5s_m"]["lag"]) == 3


def test_the_cv_estimate_beside_the_test_score_and_a_warning_when_they_disagree(mini, caplog):
    root, _ = mini
    campaign = read_trajectory_campaign(root)
    near = {"cv": {"pos_err_5s_m": 0.05, "fold_pos_err_5s_m": [0.04, 0.06], "kind": "leave-one-run-out"}}
    far = {"cv": {"pos_err_5s_m": 5.0, "fold_pos_err_5s_m": [4.9, 5.1], "kind": "leave-one-run-out"}}
    test_err = evaluation_stage(campaign, perfect_model()).model.pos_err_5s_m
    near["cv"]["pos_err_5s_m"] = test_err
    ev = evaluation_stage(campaign, replace(perfect_model(), training=near))
    # two folds 0.04, 0.06: s = 0.01414, t(0.975, 1) = 12.706, sqrt(1 + 1/2): +- 0.2201 by hand
    assert ev.to_json()["cv"] == {"pos_err_5s_m": test_err, "spread_m": pytest.approx(0.01414, rel=1e-3),
                                  "n_folds": 2, "interval_m": pytest.approx(12.706 * 0.014142 * 1.2247, rel=1e-3),
                                  "level": 0.95, "kind": "leave-one-run-out", "disagrees": False}
    caplog.clear()
    ev = evaluation_stage(campaign, replace(perfect_model(), training=far))
    assert ev.to_json()["cv"]["disagrees"] is True
    assert "outside the 95 % prediction interval" in caplog.text


def test_a_model_file_failing_its_checks_is_refused(mini, tmp_path):
    root, _ = mini
    bad = replace(perfect_model(), checks={"dissipative": {"passed": False}, "passed": False}).to_json(
        tmp_path / "bad.json")
    with pytest.raises(InputError, match=r"bad.json: the model fails its well-posedness checks \(dissipative\)"):
        evaluate_files(root, bad)
    from sindy_ekf.stages.estimation import benchmark_files
    with pytest.raises(InputError, match=r"fails its well-posedness checks"):
        benchmark_files(root, bad)


def test_the_oracle_of_a_simulated_campaign_is_its_truths_dynamics(mini, tmp_path):
    root, path = mini
    sim = shutil.copytree(root, tmp_path / "sim")
    effect = Effect("heading_dependence", 1.5)
    write_bare_truth(sim, effects=((effect.name, effect.value),))
    ev = evaluate_files(sim, path, methods=("rk4",))
    campaign = read_trajectory_campaign(sim)
    given = evaluation_stage(campaign, perfect_model(), TrueDynamics(effect=effect))
    assert ev.to_json()["oracle"] == given.to_json()["oracle"]
    without = evaluation_stage(campaign, perfect_model(), TrueDynamics())
    assert ev.to_json()["oracle"]["pos_err_5s_m"] != pytest.approx(without.to_json()["oracle"]["pos_err_5s_m"])


def test_estimators_by_default_and_the_oracle_only_where_a_truth_is():
    oracle = TrueDynamics()
    assert estimators_for(None, oracle, "c") == ESTIMATORS
    assert estimators_for(None, None, "c") == tuple(n for n in ESTIMATORS if n != "oracle_ekf")
    assert estimators_for(["sindy_ekf", "oracle_ekf"], oracle, "c") == ("sindy_ekf", "oracle_ekf")
    with pytest.raises(InputError, match=r"measured_campaign: oracle_ekf needs a simulated campaign"):
        estimators_for(["sindy_ekf", "oracle_ekf"], None, "measured_campaign")


def test_prediction_errors_are_one_value_type(mini):
    from groundfloor.results import PredictionError
    from sindy_ekf.stages.evaluation import prediction_error

    root, path = mini
    ev = evaluate_files(root, path, methods=("rk4",))
    errors = ev.errors()
    assert all(isinstance(e, PredictionError) for e in errors.values())
    r = ev.results["sindy"]["rk4"]
    # the triple at 5 s is the last sample of the RMS curves (eqs. 5.77, 5.78)
    assert prediction_error(r) == PredictionError(float(r.s_p[-1]), float(np.degrees(r.s_h[-1])), r.eps_p.shape[0])


def test_the_chain_benchmarks_with_the_settings_given(mini):
    """``report --config``: the chain's estimation stage runs what the settings enable (of the
    quick estimators, with the quick grid), with their GNSS profile and outages."""
    from sindy_ekf.config import config_from_dict
    from sindy_ekf.stages.chain import QUICK, run_chain

    root, path = mini
    config = config_from_dict({"gnss": {"profile": "standalone",
                                        "outages": {"warmup_s": 10, "recovery_s": 12, "durations_s": [4]}},
                               "estimators": {n: {"enabled": n in ("sindy_ekf", "sindy_ekf_lateral")}
                                              for n in ESTIMATORS}}, "f.yaml")
    stages = ("identification", "estimation")
    quick = run_chain(root, model=path, grid=QUICK, stages=stages, config=config).benchmark
    assert set(quick.scores) == {"sindy_ekf"}  # sindy_ekf_lateral is not a quick estimator
    assert quick.profile == "standalone"
    t0 = quick.truth["run_c"][0, 0]
    np.testing.assert_allclose(quick.outages["run_c"] - t0, [[10, 14], [26, 30]], atol=1e-6)  # 45 s run
    full = run_chain(root, model=path, grid=None, stages=stages, config=config).benchmark
    assert set(full.scores) == {"sindy_ekf", "sindy_ekf_lateral"}


def test_unicycle_means_the_kinematic_unicycle_and_lag_ekf_runs_the_lag(mini):
    from identification.sindy.baselines import LagModel, UnicycleModel
    from sindy_ekf.benchmark.run import fit_models

    root, _ = mini
    models = fit_models(read_trajectory_campaign(root).split("train"), perfect_model())
    assert type(models["unicycle_ekf"].dynamics) is UnicycleModel
    assert type(models["lag_ekf"].dynamics) is LagModel
    assert "lag_ekf" in ESTIMATORS
