"""The chain on the real Warthog campaigns of ../shared/data (issue 6).

Independent references: the baselines measured in ../shared/data/README.md (reproduced here with
velocities from plain centred differences, not the package's splines), the envelope recomputed
from the data, and the times of a hole cut into a real run.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from identification.preprocessing.trajectory import (
    read_trajectory_campaign,
    write_trajectory_campaign,
)
from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel
from identification.sindy.data import states_of_runs
from identification.sindy.evaluate import evaluate_model, make_windows

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "real_warthog.py"


def _example():
    spec = importlib.util.spec_from_file_location("real_warthog", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("real_warthog", module)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def ex():
    return _example()


@pytest.fixture(scope="module")
def data(shared_dir) -> Path:
    return shared_dir / "data"


@pytest.fixture(scope="module")
def identified(ex, data):
    """Models identified on the train runs of both campaigns with the small fixed grid."""
    return {name: ex.run_campaign(data / name, ex.QUICK_REAL_GRID) for name in ex.CAMPAIGNS}


@pytest.mark.parametrize("name, pos_m, yaw_deg, cv_m", [
    ("warthog-drive-cmd", 0.51, 30.7, 1.40),
    ("warthog-drive-wheels", 0.13, 2.7, 1.34),
])
def test_evaluation_reproduces_the_readme_baselines(ex, data, name, pos_m, yaw_deg, cv_m):
    camp = read_trajectory_campaign(data / name)
    train = [ex.states_by_differences(r) for r in camp.split("train")]
    test = [ex.states_by_differences(r) for r in camp.split("test")]
    uni = evaluate_model(UnicycleModel().fit(train), test)
    # README: unicycle 0.51 m / 30.7 deg and 0.13 m / 2.7 deg (5 s windows, 50 % overlap)
    assert uni.pos_err_5s_m == pytest.approx(pos_m, abs=0.015)
    assert uni.yaw_err_5s_deg == pytest.approx(yaw_deg, abs=1.0)
    # constant velocity keeps the initial velocity, so it depends on how that velocity is
    # estimated from 10 Hz poses with 50 ms stamp jitter: 1.1 to 1.8 m for the usual estimators
    cv = evaluate_model(ConstantVelocityModel(), test)
    assert cv.pos_err_5s_m == pytest.approx(cv_m, rel=0.2)
    assert cv.n_windows == uni.n_windows == {"warthog-drive-cmd": 47, "warthog-drive-wheels": 76}[name]


@pytest.mark.parametrize("name, max_ratio", [("warthog-drive-cmd", 0.6), ("warthog-drive-wheels", 0.8)])
def test_identified_model_beats_the_unicycle_on_the_test_runs(ex, identified, data, name, max_ratio):
    sc = identified[name]
    sindy, uni = sc.results["sindy"], sc.results["unicycle"]
    readme_uni = ex.README_BASELINES[name]["unicycle"][0]
    assert sindy.n_windows == uni.n_windows > 40
    assert sindy.pos_err_5s_m < uni.pos_err_5s_m  # same states, same windows
    assert sindy.pos_err_5s_m < max_ratio * readme_uni  # issue 6 targets: 0.6 x 0.51 m, 0.8 x 0.13 m
    assert sindy.yaw_err_5s_deg < uni.yaw_err_5s_deg
    # kept model not unstable at rest: eigenvalues of a central-difference Jacobian of f at x = u = 0
    h = 1e-6
    J = np.column_stack([(sc.model.f(h * e, np.zeros(2)) - sc.model.f(-h * e, np.zeros(2))) / (2 * h)
                         for e in np.eye(3)])
    assert np.max(np.linalg.eigvals(J).real) < 1e-6
    train_names = {r.name for r in read_trajectory_campaign(data / name).split("train")}
    assert {r for fold in sc.search.folds for r in fold} == train_names  # identified on train runs only


def test_model_trained_on_one_campaign_scored_on_the_other(ex, identified, data):
    camps = {n: read_trajectory_campaign(data / n) for n in ex.CAMPAIGNS}
    for a, b in (ex.CAMPAIGNS, ex.CAMPAIGNS[::-1]):
        sc = ex.score(identified[a].model, camps[a], camps[b])
        assert np.isfinite(sc.results["sindy"].pos_err_5s_m)
        # sensible: better than keeping the initial velocity, within a metre after 5 s
        assert sc.results["sindy"].pos_err_5s_m < sc.results["constant_velocity"].pos_err_5s_m < 1.5
        # envelope warning iff a test sample leaves the training range (+-10 % of its width)
        segs, _, _ = states_of_runs(camps[b].split("test"), identified[a].model.hyperparameters["s"])
        z = np.vstack([np.column_stack([s.state, s.inputs]) for s in segs])
        env = identified[a].model.envelope
        lo, hi = (np.array([env[v][k] for v in ("vx", "vy", "omega", "u1", "u2")]) for k in (0, 1))
        outside = ((z < lo - 0.1 * (hi - lo)) | (z > hi + 0.1 * (hi - lo))).any()
        assert bool(sc.envelope_warnings) == bool(outside)


def test_inputs_beyond_the_training_range_warn_and_still_predict(ex, identified, data, tmp_path):
    camp = read_trajectory_campaign(data / "warthog-drive-wheels")
    run = camp.split("test")[0]
    fast = replace(run, inputs=replace(run.inputs, u1=1.6 * run.inputs.u1))  # faster than ever driven
    out = write_trajectory_campaign(tmp_path / "fast", "fast", [(r, None) for r in camp.split("train")] + [(fast, None)])
    sc = ex.score(identified["warthog-drive-wheels"].model, camp, read_trajectory_campaign(out))
    assert len(sc.envelope_warnings) == 1 and "u1" in sc.envelope_warnings[0]
    assert np.isfinite(sc.results["sindy"].pos_err_5s_m)


def test_hole_nan_rows_and_duplicates_in_a_real_run_are_counted_and_not_bridged(data, tmp_path):
    camp = read_trajectory_campaign(data / "warthog-drive-wheels")
    run = camp.split("test")[0]
    p = run.poses
    t_rel = p.t - p.t[0]
    hole = (t_rel > 60.0) & (t_rel < 70.0)
    cols = {c: getattr(p, c)[~hole] for c in ("t", "x", "y", "z", "pitch", "yaw", "x_std", "y_std", "z_std",
                                              "pitch_std", "yaw_std")}
    cols["yaw"] = np.angle(np.exp(1j * cols["yaw"]))  # and wrapped, as many tools write it
    damaged = replace(run, poses=replace(p, **cols))
    out = write_trajectory_campaign(tmp_path / "c", "damaged", [(damaged, None)])
    csv = out / "runs" / run.name / "poses.csv"
    lines = csv.read_text().splitlines()
    lines[10] = lines[10].replace(lines[10].split(",")[5], "nan")  # x is column 1, yaw column 5
    lines.insert(20, lines[20])  # a duplicated row
    csv.write_text("\n".join(lines) + "\n")
    back = read_trajectory_campaign(out).runs[0]
    assert back.repairs == {"nan_pose_rows": 1, "duplicate_pose_stamps": 1, "gaps": 1}
    kept = np.delete(np.flatnonzero(~hole), 9)  # file line 11 is pose row 9
    np.testing.assert_allclose(back.poses.t, p.t[kept], rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.poses.yaw, p.yaw[kept], rtol=0, atol=1e-9)  # unwrapped again
    segs, names, _ = states_of_runs([back], 10.0)
    assert len(segs) == 2 and segs[0].t[-1] < p.t[0] + 60.0 < 70.0 + p.t[0] < segs[1].t[0]
    w = make_windows(segs, names=names)
    t_hole = p.t[0] + np.array([60.0, 70.0])
    assert not np.any((w.t0 < t_hole[1]) & (w.t0 + 5.0 > t_hole[0]))  # no window spans the hole


def test_example_main_prints_the_comparison_and_scores_an_unseen_recording(ex, data, capsys, tmp_path):
    # an "other day": one real run cut to its second half, no train/test split marked test
    run = read_trajectory_campaign(data / "warthog-drive-wheels").split("train")[0]
    keep = run.poses.t > run.poses.t[0] + 0.5 * (run.poses.t[-1] - run.poses.t[0])
    half = replace(run, name="later", poses=replace(run.poses, **{c: getattr(run.poses, c)[keep] for c in (
        "t", "x", "y", "z", "pitch", "yaw", "x_std", "y_std", "z_std", "pitch_std", "yaw_std")}))
    other = write_trajectory_campaign(tmp_path / "other", "other-day", [(half, None)])
    assert ex.main(["--quick", "--score-on", str(other), "--models-out", str(tmp_path / "models")]) == 0
    text = capsys.readouterr().out
    for needle in ("warthog-drive-cmd: 5 s position error", "warthog-drive-wheels: 5 s position error",
                   "warthog-drive-cmd -> warthog-drive-wheels", "README unicycle"):
        assert needle in text
    assert re.search(r"warthog-drive-wheels\s+other-day\s+sindy\s+\d+\.\d+", text)
    from identification.sindy.model import SindyModel

    model = SindyModel.load(tmp_path / "models" / "warthog-drive-wheels.json")
    assert model.hyperparameters["s"] == ex.QUICK_REAL_GRID.s[0]


def test_identify_picks_the_low_rate_grid_for_lidar_poses(data, small_trajectory):
    from identification.sindy.search import DEFAULT_GRID, LOW_RATE_GRID, grid_for_runs

    grid, why = grid_for_runs(read_trajectory_campaign(data / "warthog-drive-wheels").split("train"))
    assert grid == LOW_RATE_GRID and "100 ms" in why  # ICP at about 10 Hz
    grid, why = grid_for_runs(read_trajectory_campaign(small_trajectory).split("train"))
    assert grid == DEFAULT_GRID and "20 ms" in why  # the simulated trackers at 50 Hz
    with pytest.raises(Exception, match="--grid"):
        grid_for_runs([], kind="lidar")


def test_the_report_chain_picks_the_grid_identify_picks(data, small_trajectory):
    # the chain behind `sindy-ekf report` and the demo once searched the tracker grid on any poses:
    # on the 10 Hz lidar poses of the shared campaigns no grid point gave a finite error and the
    # report had no model, where `sindy-ekf identify` worked
    from identification.sindy.search import (DEFAULT_GRID, LOW_RATE_GRID, QUICK_GRID, QUICK_LOW_RATE_GRID)
    from sindy_ekf.stages.chain import QUICK, identification_plan, open_chain

    real, sim = open_chain(data / "warthog-drive-wheels"), open_chain(small_trajectory)
    assert identification_plan(real, None).grid == LOW_RATE_GRID
    assert identification_plan(real, QUICK).grid == QUICK_LOW_RATE_GRID
    assert "100 ms" in identification_plan(real, None).why
    assert identification_plan(sim, None).grid == DEFAULT_GRID
    assert identification_plan(sim, QUICK).grid == QUICK_GRID
    assert identification_plan(real, DEFAULT_GRID).grid == DEFAULT_GRID  # a grid given is kept


def test_diagnosis_on_real_data_names_only_what_5s_prediction_confirms(identified, data):
    """On these runs the window residuals favour mechanisms (a 0.56 s delay on wheels) whose
    re-identified models run away at rest or predict 5 s worse; such a cause must not be named."""
    from identification.sindy.checks import stable_at_rest
    from sindy_ekf.diagnose import diagnose_states

    camp = read_trajectory_campaign(data / "warthog-drive-wheels")
    model = identified["warthog-drive-wheels"].model
    s = float(model.hyperparameters["s"])
    train, a, _ = states_of_runs(camp.split("train"), s)
    test, b, _ = states_of_runs(camp.split("test"), s)
    d = diagnose_states(model, train, test, a, b, ekf=False, uncertainty=False)
    if d.verdict != "none":
        assert d.after.pos_err_5s_m < d.before.pos_err_5s_m
        assert stable_at_rest(d.extended.base)
    for c in d.ranked:
        if "not confirmed" in c.note:
            assert not c.significant
