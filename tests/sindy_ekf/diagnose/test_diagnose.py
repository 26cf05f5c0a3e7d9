"""Diagnosis tests: hidden effects in short simulated campaigns must be found, named and fixed.

Each test draws the magnitude of the hidden effect at random within [0.75, 1.25] times the
family's moderate value (simulation.effects), from a seed printed in every failure message, and
hands the diagnosis only the body states and the reference model (identified on an effect-free
campaign): nothing says which effect is in the data. Campaigns go from the simulator's true
trajectory to 25 Hz body states with measurement noise (no bags), 4 x 60 s train and 2 x 60 s
test runs, so that all eight campaigns fit the time budget.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from groundfloor.errors import InputError  # noqa: E402
from simulation.effects import EFFECTS, Effect  # noqa: E402
from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose import diagnose_states  # noqa: E402
from sindy_ekf.diagnose.fitting import normal_equations
from tests.support import REPO
from tests.support.diagnose_synth import fit_reference_with_lateral_law

# The magnitude and campaign seed of each hidden effect are drawn from this master seed; the code
# under test never sees them. CI uses a fixed master seed so that a green run is reproducible;
# SINDY_EKF_TEST_SEED=random (or any integer) draws other campaigns. Run on 2026-11-22 with master
# seeds 101 to 113: all hidden effects found, estimated and fixed; one effect-free campaign (109)
# raised a false alarm (heading_dependence, gain 0.072 over its threshold 0.060), as a 10 % false-
# alarm target allows. The randomised statistics over many campaigns are bench/'s job.
_SEED_ENV = os.environ.get("SINDY_EKF_TEST_SEED", "20221221")
MASTER_SEED = int(np.random.SeedSequence().entropy % 2**31 if _SEED_ENV == "random" else _SEED_ENV)
RUN_S, RATE_HZ = 60.0, 25.0

# the physical parameter of each family (simulation.effects) and how to read it from an estimate
TRUE_PARAMETER = {
    "input_delay": lambda v: ("delay_s", v),
    "heading_dependence": lambda v: ("tilt_deg", v),
    "position_dependence": lambda v: ("damping_fraction", v),
    "time_dependence": lambda v: ("decay_per_10min", v),
    "asymmetry": lambda v: ("imbalance", v),
    "deadband": lambda v: ("threshold", v),
    "lateral_slip": lambda v: ("slip_gain", v),
}


@pytest.fixture(scope="module")
def reference_model():
    """The lab's model: identified on an effect-free campaign (seed 12345), lateral law included."""
    return fit_reference_with_lateral_law(n_runs=4, run_s=RUN_S, rate_hz=RATE_HZ)


def draw(family: str, index: int) -> tuple[int, float]:
    """Return a campaign seed and a magnitude in [0.75, 1.25] x moderate (inside the valid range)."""
    rng = np.random.default_rng([MASTER_SEED, index])
    spec = EFFECTS[family]
    value = float(np.clip(spec.moderate * rng.uniform(0.75, 1.25), *spec.valid_range))
    return int(rng.integers(2**31)), value


@pytest.mark.parametrize("index, family", list(enumerate(EFFECTS)))
def test_hidden_effect_is_found_estimated_and_fixed(reference_model, index, family):
    seed, value = draw(family, index)
    why = f"(SINDY_EKF_TEST_SEED={MASTER_SEED}: campaign seed {seed}, {family}={value:.4g})"
    train, test, a, b = simulate_states_campaign(seed, Effect(family, value), run_s=RUN_S, rate_hz=RATE_HZ)
    d = diagnose_states(reference_model, train, test, a, b, ekf=(family == "input_delay"))
    ranking = [(c.name, round(c.gain, 4)) for c in d.ranked[:3]]
    assert d.verdict == family, f"named {d.verdict}, ranking {ranking} {why}"
    key, truth = TRUE_PARAMETER[family](value)
    est = d.ranked[0].score.estimate[key]
    assert abs(est - truth) <= 0.25 * abs(truth), f"{key} = {est:.4g}, truth {truth:.4g} {why}"
    assert d.after.pos_err_5s_m < d.before.pos_err_5s_m, f"5 s error {d.before} -> {d.after} {why}"
    if family == "lateral_slip":  # the forward and yaw equations keep the base's drift: heading not spoilt
        # (fed the larger drift, the base's vy terms of the yaw equation took it from 2.8 to 5.1 deg)
        assert d.after.yaw_err_5s_deg < 1.25 * d.before.yaw_err_5s_deg, f"{d.before} -> {d.after} {why}"
    if family == "heading_dependence":  # the residual structure shows it too: vx residual vs heading
        be = d.structure["vx"]["heading"]
        assert be.eta2 > 0.3 and be.p_value < 1e-3, f"vx residual vs heading eta2 {be.eta2:.2f} {why}"
        assert be.eta2 == max(x.eta2 for x in d.structure["vx"].values()), why
        psi_down = EFFECTS[family].fixed["psi_down_rad"]
        err = abs(np.angle(np.exp(1j * (d.ranked[0].score.estimate["psi_down_rad"] - psi_down))))
        assert err < 0.2, f"downhill azimuth off by {err:.3f} rad {why}"
    if family == "position_dependence":
        fx = EFFECTS[family].fixed
        e = d.ranked[0].score.estimate
        dist = math.dist(e["patch_center_local_m"], fx["patch_center_local_m"])
        assert dist < 0.3, f"patch centre {e['patch_center_local_m']} is {dist:.2f} m off {why}"
        assert abs(e["patch_radius_m"] - fx["patch_radius_m"]) < 0.25 * fx["patch_radius_m"], why
    if family == "input_delay":  # EKF through GNSS outages measured (its gain is judged in bench/, over
        # many outages: two 10 s outages per campaign are too few to decide here)
        assert d.outage["n"] >= 2 and np.isfinite([d.outage["before_m"], d.outage["after_m"]]).all(), why
        std = d.ranked[0].score.estimate_std["delay_s"]
        assert 0 < std < 0.05, f"jackknife std of the delay {std} {why}"
    # train and test runs of one robot: the extension helps the test runs and nothing is said against it
    assert d.extension_on_test["lowers"] and d.extension_warning() is None, why


def test_effect_free_campaign_says_none(reference_model):
    seed = int(np.random.default_rng([MASTER_SEED, 99]).integers(2**31))
    train, test, a, b = simulate_states_campaign(seed, None, run_s=RUN_S, rate_hz=RATE_HZ)
    d = diagnose_states(reference_model, train, test, a, b)
    ranking = [(c.name, round(c.gain, 4), round(c.threshold, 4)) for c in d.ranked[:3]]
    assert d.verdict == "none", f"false alarm {ranking} (SINDY_EKF_TEST_SEED={MASTER_SEED}, seed {seed})"
    out = d.to_json()
    assert out["causes"][0]["name"] == "none"
    assert out["causes"][0]["pos_err_5s_m"]["before"] == out["causes"][0]["pos_err_5s_m"]["after"]
    assert all({"name", "estimate", "pos_err_5s_m"} <= set(c) for c in out["causes"])  # INTERFACES.md keys
    assert [c["name"] for c in out["causes"][1:]] == [c.name for c in d.ranked]
    json.dumps(out)  # JSON-ready
    # without an effect no residual structure stands out strongly against heading or time
    assert max(d.structure["vx"]["heading"].eta2, d.structure["vx"]["t_run"].eta2) < 0.3


def test_families_scored_in_two_processes_rank_as_in_one(reference_model):
    """Scale-out (issue 16): one task per family, the ranking independent of where they ran."""
    seed = int(np.random.default_rng([MASTER_SEED, 7]).integers(2**31))
    train, test, a, b = simulate_states_campaign(seed, Effect("input_delay", 0.2), run_s=RUN_S, rate_hz=RATE_HZ)
    one, two = (diagnose_states(reference_model, train, test, a, b, uncertainty=False, workers=w) for w in (1, 2))
    assert one.verdict == two.verdict
    assert [(c.name, c.gain, c.score.estimate) for c in one.ranked] == \
        [(c.name, c.gain, c.score.estimate) for c in two.ranked]


def test_extended_model_jacobians_match_numerical_derivatives(reference_model, tmp_path):
    """The EKF linearises the extended model: analytic Jacobians (pose columns included) vs central
    differences, of the accelerations and of the six-state derivative with its kinematics."""
    from sindy_ekf.diagnose.extend import ExtendedModel

    rng = np.random.default_rng(3)
    x6 = np.column_stack([rng.uniform(2, 5, 20), rng.uniform(2, 4, 20), rng.uniform(-3, 3, 20),
                          rng.uniform(-0.5, 0.5, (20, 3))])
    u = rng.uniform(-0.8, 0.8, (20, 2))
    for family, theta, beta in (("position_dependence", [3.5, 3.0, 1.0], [-3.0, -2.5]),
                                ("heading_dependence", [], [0.2, -0.1, 0.05, 0.1]),
                                ("lateral_slip", [], [-2.0, 3.0])):
        ext = ExtendedModel.added(reference_model, family, theta, beta)
        # lateral_slip keeps the forward and yaw equations at the base's drift: vy / slip gain there
        assert (ext.vy_scale != 1.0) == (family == "lateral_slip"), family
        J = ext.accel_and_jacobians(x6, u)[1]
        h = 1e-6
        num = np.stack([(ext.accel(x6 + h * np.eye(6)[k], u) - ext.accel(x6 - h * np.eye(6)[k], u)) / (2 * h)
                        for k in range(6)], axis=-1)
        np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-6, err_msg=family)
        _, F_x, F_u = ext.derivative_and_jacobians(x6, u)
        num_x = np.stack([(ext.derivative(x6 + h * e, u) - ext.derivative(x6 - h * e, u)) / (2 * h)
                          for e in np.eye(6)], axis=-1)
        num_u = np.stack([(ext.derivative(x6, u + h * e) - ext.derivative(x6, u - h * e)) / (2 * h)
                          for e in np.eye(2)], axis=-1)
        np.testing.assert_allclose(F_x, num_x, rtol=1e-5, atol=1e-6, err_msg=family)
        np.testing.assert_allclose(F_u, num_u, rtol=1e-5, atol=1e-6, err_msg=family)
        back = ExtendedModel.load(ext.to_json(tmp_path / f"{family}.json"))
        np.testing.assert_allclose(back.accel(x6, u), ext.accel(x6, u), err_msg=family)


def test_model_trained_on_other_inputs_is_refused(reference_model, tmp_path):
    from sindy_ekf.diagnose import load_model

    d = reference_model.to_dict()
    d["input_names"] = ["throttle", "steer"]
    path = tmp_path / "other_inputs.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"other_inputs\.json: model trained on inputs \['throttle', 'steer'\]"):
        load_model(path)


def test_campaign_too_short_to_score_is_refused(reference_model):
    train, test, a, b = simulate_states_campaign(1, None, n_train=2, n_test=1, run_s=8.0, rate_hz=RATE_HZ)
    with pytest.raises(InputError, match=r"test runs too short to score out of sample: run_03 8\.0 s"):
        diagnose_states(reference_model, train, test, a, b)
    with pytest.raises(InputError, match="no runs marked test"):
        diagnose_states(reference_model, train, [], a, [])


def test_diagnose_command_on_a_trajectory_campaign(reference_model, tmp_path):
    """End to end through the command line: a data-contract trajectory campaign written by hand."""
    from simulation.robot import simulate_run
    from sindy_ekf.cli import main

    root = tmp_path / "camp"
    runs = [("run_01", "train"), ("run_02", "train"), ("run_03", "train"), ("run_04", "test")]
    lines = ["kind: trajectory", "name: hidden", "runs:"]
    rng = np.random.default_rng([MASTER_SEED, 7])
    for i, (name, split) in enumerate(runs):
        r = simulate_run(40.0, rng.spawn(1)[0], effect=Effect("input_delay", 0.25), dt=0.004)
        k = np.arange(0, len(r.t), 10)  # 25 Hz poses
        d = root / "runs" / name
        d.mkdir(parents=True)
        np.savetxt(d / "poses.csv", np.column_stack([r.t[k] + 100.0 * i, r.x[k], r.y[k], r.psi[k]]),
                   delimiter=",", header="t,x,y,yaw", comments="", fmt="%.6f")
        np.savetxt(d / "inputs.csv", np.column_stack([r.t_joy + 100.0 * i, r.u_joy]), delimiter=",",
                   header="t,u1,u2", comments="", fmt="%.6f")
        lines.append(f"  - {{name: {name}, split: {split}}}")
    (root / "campaign.yaml").write_text("\n".join(lines) + "\n")
    model_path = reference_model.to_json(tmp_path / "model.json")
    out = tmp_path / "d.json"
    plots = tmp_path / "plots"
    rc = main(["diagnose", str(root), "--model", str(model_path), "--json", str(out), "--no-ekf", "--quiet",
               "--plots", str(plots)])
    assert rc == 0
    assert {p.name for p in plots.glob("*.png")} == {
        "residual_structure.png", "multistep_structure.png", "lag_profile.png", "family_profiles.png",
        "residual_map.png", "before_after.png"}
    import matplotlib

    assert dict.__getitem__(matplotlib.rcParams, "backend").lower() == "agg"  # the command line chose it
    js = json.loads(out.read_text())
    first = js["causes"][0]
    assert first["name"] == "input_delay", [(c["name"], c.get("gain")) for c in js["causes"][:3]]
    assert abs(first["estimate"]["delay_s"] - 0.25) < 0.0625
    assert first["pos_err_5s_m"]["after"] < first["pos_err_5s_m"]["before"]
    assert set(js["scores"]) == set(EFFECTS)
    # the same command refuses a model of other inputs, naming the file and the inputs
    d = reference_model.to_dict()
    d["input_names"] = ["left", "right"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    assert main(["diagnose", str(root), "--model", str(bad), "--quiet"]) == 2


def test_example_runs_and_finds_its_effect():
    """examples/diagnose_hidden_effect.py runs (so it cannot rot) and names what it hid."""
    import importlib.util

    path = REPO / "examples" / "diagnose_hidden_effect.py"
    spec = importlib.util.spec_from_file_location("diagnose_hidden_effect", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(seed=4, family="deadband")
    assert out["verdict"] == out["hidden"]
    assert out["after"]["pos_err_5s_m"] < out["before"]["pos_err_5s_m"]


def test_measurement_findings_in_cause_correction_gain_language():
    """Preprocessing numbers (preprocess --json) come back as findings; a broken report is named."""
    from sindy_ekf.diagnose.measurement import findings_from_report

    run = {"at960_extra_offset_s": 0.0013, "at960_extra_offset_std_s": 3e-7, "extra_offset_tracker": "at960",
           "baseline_rms_m": {"before": 5e-4, "after": 1.2e-4},
           "timing_error": {"r_baseline_speed_before": -0.96, "r_baseline_speed_after": 0.01},
           "hub": {"r1": 2.1e-4, "r2": 1.2e-4, "r1_std": 8e-6, "r2_std": 1e-5, "phi1_rad": -0.8, "phi2_rad": -1.1,
                   "rms_before_m": 1.2e-4, "rms_after_m": 2e-5}}
    other = {**run, "at960_extra_offset_s": 0.0015}
    found = {f.name: f for f in findings_from_report({"runs": {"a": run, "b": other}, "hub_correction": True})}
    assert set(found) == {"timing_offset", "hub_eccentricity"}
    assert found["timing_offset"].estimate["extra_offset_s"] == pytest.approx(0.0014)  # median of the runs
    assert found["timing_offset"].gain["baseline_rms_m"] == {"before": 5e-4, "after": 1.2e-4}
    assert "-0.96" in found["timing_offset"].cause
    assert found["hub_eccentricity"].gain["baseline_rms_m"]["after"] == 2e-5
    with pytest.raises(InputError, match="p.json: key runs is missing"):
        findings_from_report({"transform": {}}, "p.json")


@pytest.mark.parametrize("family, value", [("deadband", 0.2), ("asymmetry", 0.3), ("time_dependence", 0.5),
                                           ("input_delay", 0.13)])
def test_input_mechanisms_match_the_simulators_motor_inputs(family, value):
    """The families' input transforms against a second implementation: the simulator's motor model."""
    from simulation.robot import TrueDynamics
    from sindy_ekf.diagnose.families import FAMILY_SPECS

    rng = np.random.default_rng(5)
    t_joy = np.cumsum(rng.uniform(0.02, 0.2, 400))
    u_joy = rng.uniform(-1, 1, (400, 2))
    t = np.arange(0.0, t_joy[-1], 0.02)
    u_rec = TrueDynamics().motor_inputs(t, t_joy, u_joy)  # what a recording holds (ZOH, no effect)
    truth = TrueDynamics(effect=Effect(family, value)).motor_inputs(t, t_joy, u_joy)
    mine = FAMILY_SPECS[family].motor_inputs(t, u_rec, [slice(None)], np.array([[value]]))[0]
    if family == "input_delay":  # sampled inputs interpolate the hold's steps: compare away from them
        k = np.searchsorted(t_joy, t - value)
        away = (np.abs(t - value - t_joy[np.minimum(k, len(t_joy) - 1)]) > 0.02) & (
            np.abs(t - value - t_joy[np.maximum(k - 1, 0)]) > 0.02) & (t > value + 0.02)
        np.testing.assert_allclose(mine[away], truth[away], atol=1e-12)
    else:
        np.testing.assert_allclose(mine, truth, atol=1e-12)


def test_binned_effect_recovers_a_known_dependence():
    """eta2 of a residual built from a known function of the regressor, and no signal in pure noise."""
    from sindy_ekf.diagnose.residuals import binned_effect

    rng = np.random.default_rng(11)
    x = rng.uniform(-np.pi, np.pi, 4000)
    noise = rng.normal(0, 0.5, 4000)
    be = binned_effect(np.cos(x) + noise, x, "heading", n_bins=16, circular=True)
    expected = 0.5 / (0.5 + 0.25)  # var(cos) / (var(cos) + var(noise)), less the binning loss
    assert 0.9 * expected < be.eta2 < expected and be.p_value < 1e-10
    np.testing.assert_allclose(be.mean, np.cos(be.centers), atol=0.1)
    null = binned_effect(noise, x, "heading", n_bins=16, circular=True)
    assert null.eta2 < 0.01 and null.p_value > 1e-3


def test_a_cause_whose_extension_predicts_5s_worse_is_not_named(reference_model):
    """The 5 s confirmation on the train runs: a hidden input delay of 0.15 s, offered once at its
    fitted value and once at a wrong 0.55 s (both marked significant); only the first is kept."""
    import dataclasses

    from sindy_ekf.diagnose.data import split_from_states
    from sindy_ekf.diagnose.fitting import equation_weights, score_family
    from sindy_ekf.diagnose.pipeline import confirm_on_train, in_envelope
    from sindy_ekf.diagnose.rank import RankedCause

    seed = int(np.random.default_rng([MASTER_SEED, 31]).integers(2**31))
    train, test, a, b = simulate_states_campaign(seed, Effect("input_delay", 0.15), run_s=RUN_S, rate_hz=RATE_HZ)
    tau = float(reference_model.hyperparameters.get("tau") or 2.0)
    tr = in_envelope(reference_model, split_from_states(train, a, tau))
    te = in_envelope(reference_model, split_from_states(test, b, tau))
    w = equation_weights(reference_model, tr)
    fitted = score_family("input_delay", reference_model, tr, te, w, uncertainty=False, refit=False)
    wrong = dataclasses.replace(fitted, theta=np.array([0.55]), estimate={"delay_s": 0.55})
    causes = [RankedCause("input_delay", 1.0, 0.01, True, wrong), RankedCause("input_delay", 0.5, 0.01, True, fitted)]
    ranked, extended = confirm_on_train(reference_model, causes, tr, w, train, a)
    why = f"(SINDY_EKF_TEST_SEED={MASTER_SEED}, seed {seed})"
    assert not ranked[-1].significant and "not confirmed" in ranked[-1].note, why  # the wrong delay, last
    assert ranked[0].significant and ranked[0].score is fitted, why
    assert extended is not None and extended.theta[0] == pytest.approx(fitted.theta[0]), why


def test_an_extension_that_the_test_runs_contradict_is_said_to_predict_them_worse(reference_model):
    """Train runs of a robot answering 0.2 s late, test runs of one that does not (another day, a
    repaired motor controller): the delay is named from the train runs, and the extension, right
    for them, is wrong for the test runs by the whole delay. The diagnosis says so in its JSON, on
    the terminal and in the report, and counts the windows; on test runs with the same delay
    (:func:`test_hidden_effect_is_found_estimated_and_fixed`) it says nothing."""
    from pathlib import Path

    from sindy_ekf.commands.diagnose import format_diagnosis

    rng = np.random.default_rng([MASTER_SEED, 41])
    seeds = [int(v) for v in rng.integers(2**31, size=2)]
    train, _, a, _ = simulate_states_campaign(seeds[0], Effect("input_delay", 0.2), run_s=RUN_S, rate_hz=RATE_HZ)
    _, test, _, b = simulate_states_campaign(seeds[1], None, run_s=RUN_S, rate_hz=RATE_HZ)
    d = diagnose_states(reference_model, train, test, a, b)
    why = f"(SINDY_EKF_TEST_SEED={MASTER_SEED}, seeds {seeds})"
    assert d.verdict == "input_delay", why
    assert d.after.pos_err_5s_m > d.before.pos_err_5s_m, why
    e = d.to_json()["extension_on_test"]
    before, after = d.evaluations["before"].eps_p[:, -1], d.evaluations["after"].eps_p[:, -1]
    j = np.argmin(after - before)
    assert e == {"lowers": False, "windows_better": int(np.sum(after < before)), "n_windows": len(before),
                 "median_5s_m": [np.median(before), np.median(after)],
                 "most_worsened_5s_m": [before[np.argmax(after - before)], after[np.argmax(after - before)]],
                 "most_improved_5s_m": [before[j], after[j]] if after[j] < before[j] else None}, why
    assert e["windows_better"] < e["n_windows"] / 2, why  # the delay is wrong in most windows, not in a few
    line = d.extension_warning()
    assert line and "predicts the test runs worse" in line and "input_delay" in line, why
    assert "does not hold on the test runs" in line and "most windows" not in line, why
    assert f"warning: {line}" in format_diagnosis(d, Path("model.json"), Path("campaign")).splitlines()


def test_test_runs_too_short_for_an_outage_give_no_outage_errors(reference_model):
    # runs of 15 s hold no 10 s outage after 10 s of GNSS: nothing to score, not a crash
    from sindy_ekf.diagnose.extend import outage_errors

    train, test, _, _ = simulate_states_campaign(7, None, n_train=2, n_test=2, run_s=15.0, rate_hz=RATE_HZ)
    res = outage_errors({"before": reference_model}, train, test)
    assert res.outage_s == 10.0 and res.errors_m["before"].size == 0
    assert np.isnan(res.rms()["before"]) and res.n_diverged() == {"before": 0}


def test_normal_equations_are_the_weighted_sums_over_each_runs_windows():
    # against the definition, written out: G = sum_windows,eq w_e X^T X, b = sum w_e X^T y, yy = sum w_e y^2 per run
    rng = np.random.default_rng(3)
    C, p, m, R = 2, 40, 5, 3
    y, X = rng.normal(size=(C, p, 3)), rng.normal(size=(C, p, 3, m))
    w, run = rng.uniform(0.5, 2.0, size=3), rng.integers(0, R, size=p)
    d = normal_equations(y, X, w, run, R)
    for c in range(C):
        for r in range(R):
            G = sum(w[e] * np.outer(X[c, k, e], X[c, k, e]) for k in np.flatnonzero(run == r) for e in range(3))
            b = sum(w[e] * X[c, k, e] * y[c, k, e] for k in np.flatnonzero(run == r) for e in range(3))
            yy = sum(w[e] * y[c, k, e] ** 2 for k in np.flatnonzero(run == r) for e in range(3))
            np.testing.assert_allclose(d.G[c, r], G, rtol=1e-12)
            np.testing.assert_allclose(d.b[c, r], b, rtol=1e-12)
            np.testing.assert_allclose(d.yy[c, r], yy, rtol=1e-12)
    empty = normal_equations(y, X[..., :0], w, run, R)  # a family without columns: yy only
    assert empty.G.shape == (C, R, 0, 0) and np.allclose(empty.yy, d.yy)


def test_a_model_without_a_lateral_law_is_said_to_miss_one_when_adding_it_clears_its_threshold(reference_model):
    """The lab model with its lateral law taken out (no ``vx omega`` in the vy equation, as the lag
    that identify falls back to), on runs of a robot that drifts sideways in turns: lateral_slip is
    never named for such a model, but the diagnosis says, on the terminal and in its JSON, that
    adding the law clears its threshold. With the law kept it says nothing of the kind."""
    from pathlib import Path

    from sindy_ekf.commands.diagnose import format_diagnosis
    from sindy_ekf.diagnose.families import term_column

    coef = reference_model.coef.copy()
    coef[1, term_column(reference_model.library, "vx omega")] = 0.0
    no_law = reference_model.with_coefficients(coef)
    rng = np.random.default_rng([MASTER_SEED, 43])
    seed = int(rng.integers(2**31))
    # a robot that slips more than the lab's (the family's moderate value): the law is clearly missed
    slipping = Effect("lateral_slip", EFFECTS["lateral_slip"].moderate)
    train, test, a, b = simulate_states_campaign(seed, slipping, run_s=RUN_S, rate_hz=RATE_HZ)
    why = f"(SINDY_EKF_TEST_SEED={MASTER_SEED}, seed {seed})"
    d = diagnose_states(no_law, train, test, a, b, ekf=False)
    slip = next(c for c in d.ranked if c.name == "lateral_slip")
    assert slip.score.estimate["model_has_lateral_law"] is False and not slip.significant, why
    assert slip.gain > slip.threshold, f"adding the law gains {slip.gain:.3f} <= {slip.threshold:.3f} {why}"
    line = d.missing_law_warning()
    assert line and f"gains {100 * slip.gain:.1f} %" in line, why
    assert f"warning: {line}" in format_diagnosis(d, Path("m.json"), Path("c")).splitlines()
    assert d.to_json()["warnings"] == [w for w in (d.extension_warning(), line) if w]
    with_law = diagnose_states(reference_model, train, test, a, b, ekf=False)
    assert with_law.missing_law_warning() is None, why


def test_a_family_the_refit_replaces_keeps_its_own_5s_error_in_the_json(reference_model, monkeypatch):
    """When the model's own terms refitted replace a named family (own_terms.own_terms_question), the verdict's
    errors are the refit's and the family's entry in the JSON keeps what its own extension reached. The
    replacement is forced here (the refit stands in as the given model, errors unchanged); the family's own
    errors are the 5 s errors of the extension the pipeline handed over, recomputed by hand."""
    import sindy_ekf.diagnose.pipeline as pipeline

    handed = {}

    def replaced(name, extended, res_after, model, *rest):
        evidence, res_before = rest[-2], rest[-1]
        handed.update(name=name, after=res_after, before=res_before)
        evidence["unexplained"] = {"equation": "omega", "regressor": "u2", "eta2": 0.5, "instead_of": name}
        return "unexplained", extended, res_before

    monkeypatch.setattr(pipeline, "own_terms_question", replaced)
    seed, value = draw("input_delay", 0)
    why = f"(SINDY_EKF_TEST_SEED={MASTER_SEED}: campaign seed {seed}, input_delay={value:.4g})"
    train, test, a, b = simulate_states_campaign(seed, Effect("input_delay", value), run_s=RUN_S, rate_hz=RATE_HZ)
    d = diagnose_states(reference_model, train, test, a, b, ekf=False)
    assert handed["name"] == "input_delay" and d.verdict == "unexplained", why
    # the family's own 5 s RMS over the windows where neither prediction diverged (here: all of them)
    e_before, e_after = handed["before"].eps_p[:, -1], handed["after"].eps_p[:, -1]
    assert np.all(np.isfinite(e_before) & np.isfinite(e_after)), why
    own = float(np.sqrt(np.mean(e_after ** 2)))
    assert own < 0.8 * float(np.sqrt(np.mean(e_before ** 2))), why  # the delay's extension helps: a real finding
    doc = d.to_json()
    entry = next(c for c in doc["causes"] if c["name"] == "input_delay")
    assert entry["pos_err_5s_m"]["after"] == pytest.approx(own, rel=1e-12), why
    assert doc["causes"][0]["name"] == "unexplained" and doc["causes"][0]["estimate"]["instead_of"] == "input_delay"
    assert doc["causes"][0]["pos_err_5s_m"]["after"] == pytest.approx(d.before.pos_err_5s_m, rel=1e-12), why
