"""The filter settings reach the estimators (issue 16 item 3): for each kind of key, a benchmark
run with a setting changed gives what the filter API called directly with that setting gives (or
what the setting means, worked out by hand), and the effective settings are recorded."""

from __future__ import annotations

import numpy as np
import pytest

from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
from simulation.gnss import simulate_gnss
from sindy_ekf.benchmark.run import (
    ESTIMATORS,
    LATERAL_EVERY,
    P0_STD,
    _prepare_run,
    benchmark_campaign,
    fit_models,
    train_series,
)
from sindy_ekf.config import config_from_dict
from sindy_ekf.estimation.ekf import (
    GATE_PROB,
    EkfRun,
    LateralConstraint,
    fit_lateral_constraint,
    run_ekf_batch,
)
from sindy_ekf.estimation.graph import smooth_batch
from sindy_ekf.estimation.process_models import ProcessModel

SEED, WARMUP_S, RECOVERY_S = 3, 10.0, 12.0  # outages of 5 and 10 s on the 45 s test run
P0 = np.diag(P0_STD ** 2)


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    """Two train runs and one test run of the simulator, and the true terms as the identified model."""
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from identification.sindy.model import model_from_terms
    from simulation.robot import RobotParams
    from tests.support.trajectory_synth import write_mini_campaign

    root = write_mini_campaign(tmp_path_factory.mktemp("bench_config") / "mini")
    return read_trajectory_campaign(root), model_from_terms(RobotParams().terms())


def _merged(base: dict, change: dict) -> dict:
    out = dict(base)
    for k, v in change.items():
        out[k] = _merged(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def _bench(mini, change: dict, run=("sindy_ekf",), **kw):
    """Return the benchmark with only ``run`` enabled and ``change`` applied to the settings."""
    campaign, model = mini
    data = {"gnss": {"seed": SEED, "outages": {"warmup_s": WARMUP_S, "recovery_s": RECOVERY_S}},
            "estimators": {n: {"enabled": n in run} for n in ESTIMATORS}}
    return benchmark_campaign(campaign, model, config=config_from_dict(_merged(data, change), "test.yaml"), **kw)


def _direct(mini, *, P0=P0, gate_prob=GATE_PROB, lateral=None, Q_rate=None, fuse=True):
    """Return the test run prepared as the benchmark does, the SINDy process model (fitted, or
    with ``Q_rate``) and run_ekf_batch's result on it called with the given settings."""
    campaign, model = mini
    train = campaign.split("train")
    pm = fit_models(train, model, series=train_series(train))["sindy_ekf"]
    if Q_rate is not None:
        pm = ProcessModel(model, "sindy")
        pm.Q_rate_ = Q_rate
    r = _prepare_run(campaign.split("test")[0], "dgnss", SEED, None, DEFAULT_SMOOTHING, WARMUP_S, RECOVERY_S)
    res = run_ekf_batch(pm, [EkfRun("direct", r.grid, r.u, r.x0, P0, r.gnss if fuse else None)], gate_prob,
                        lateral)[0]
    return r, pm, res


def _at_poses(r, res):
    return res.x[r.at_pose], res.P[r.at_pose]


def test_the_defaults_run_the_filter_with_the_code_constants(mini):
    result = _bench(mini, {}, run=("sindy_ekf", "sindy_ekf_lateral"))
    campaign, _ = mini
    r, _, res = _direct(mini)
    x, P = _at_poses(r, res)
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, x)
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].P, P)
    train = train_series(campaign.split("train"))
    lateral = fit_lateral_constraint([s.x6[:, 4] for s in train], every=LATERAL_EVERY)
    r, _, res = _direct(mini, lateral=lateral)
    assert np.array_equal(result.estimates["sindy_ekf_lateral"]["run_c"].x, _at_poses(r, res)[0])


def test_gate_prob_reaches_the_gate(mini):
    result = _bench(mini, {"estimators": {"sindy_ekf": {"gate_prob": 0.5}}})
    r, _, res = _direct(mini, gate_prob=0.5)
    _, _, default = _direct(mini)
    assert (~res.accepted).sum() > 10 * max((~default.accepted).sum(), 1)  # the setting matters here
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, _at_poses(r, res)[0])


def test_initial_std_is_the_first_covariance(mini):
    std = [0.3, 0.2, 0.1, 0.4, 0.05, 0.2]
    result = _bench(mini, {"estimators": {"sindy_ekf": {"initial_std": std},
                                          "dead_reckoning": {"initial_std": std[::-1]}}},
                    run=("sindy_ekf", "dead_reckoning"))
    # no fix arrives at the first pose (every fix has latency): P there is P0
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].P[0], np.diag(np.square(std)))
    assert np.array_equal(result.estimates["dead_reckoning"]["run_c"].P[0], np.diag(np.square(std[::-1])))
    r, _, res = _direct(mini, P0=np.diag(np.square(std)))
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, _at_poses(r, res)[0])


def test_process_noise_replaces_the_fitted_one_for_that_estimator_only(mini):
    q_std = [0.02, 0.02, 0.01, 0.3, 0.2, 0.4]
    Q_rate = np.diag(np.square(q_std))
    # sindy_ekf runs before dead_reckoning, which shares the SINDy process model
    result = _bench(mini, {"estimators": {"sindy_ekf": {"process_noise": q_std}}},
                    run=("sindy_ekf", "dead_reckoning"))
    r, _, res = _direct(mini, Q_rate=Q_rate)
    x, P = _at_poses(r, res)
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].P, P)
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, x)
    # dead_reckoning keeps the fitted Q
    r, fitted, res = _direct(mini, fuse=False)
    assert not np.allclose(fitted.Q_rate_, Q_rate)  # the setting matters here
    assert np.array_equal(result.estimates["dead_reckoning"]["run_c"].P, _at_poses(r, res)[1])
    # the same density as a 6 x 6 matrix
    as_matrix = _bench(mini, {"estimators": {"sindy_ekf": {"process_noise": Q_rate.tolist()}}})
    assert np.array_equal(as_matrix.estimates["sindy_ekf"]["run_c"].P, P)


@pytest.mark.parametrize("lateral, expected", [
    ({"enabled": True, "every": 3, "vy_std_m_s": 0.05}, LateralConstraint(0.05, 3)),
    ({"enabled": True, "every": 7}, "fit"),
])
def test_lateral_is_the_constraint_of_run_ekf(mini, lateral, expected):
    campaign, _ = mini
    if expected == "fit":
        train = train_series(campaign.split("train"))
        expected = LateralConstraint(fit_lateral_constraint([s.x6[:, 4] for s in train]).vy_std_m_s, 7)
    result = _bench(mini, {"estimators": {"sindy_ekf": {"lateral": lateral}}})
    r, _, res = _direct(mini, lateral=expected)
    assert np.array_equal(result.estimates["sindy_ekf"]["run_c"].x, _at_poses(r, res)[0])
    off = _bench(mini, {"estimators": {"sindy_ekf_lateral": {"lateral": {"enabled": False}}}},
                 run=("sindy_ekf_lateral",))
    r, _, res = _direct(mini)
    assert np.array_equal(off.estimates["sindy_ekf_lateral"]["run_c"].x, _at_poses(r, res)[0])


def test_no_sensor_is_dead_reckoning(mini):
    result = _bench(mini, {"estimators": {"sindy_ekf": {"sensors": []}}}, run=("sindy_ekf", "dead_reckoning"))
    est, dr = result.estimates["sindy_ekf"]["run_c"], result.estimates["dead_reckoning"]["run_c"]
    assert np.array_equal(est.x, dr.x) and np.array_equal(est.P, dr.P) and est.nis.size == 0


def test_the_graph_takes_its_initial_std_process_noise_lateral_and_sensors(mini):
    std, q_std = [0.1, 0.1, 0.05, 0.1, 0.05, 0.1], [0.02, 0.02, 0.01, 0.3, 0.2, 0.4]
    result = _bench(mini, {"estimators": {"sindy_graph": {
        "initial_std": std, "process_noise": q_std, "lateral": {"enabled": True, "every": 5, "vy_std_m_s": 0.05},
        "sensors": ["gnss"]}}}, run=("sindy_graph",))
    campaign, model = mini
    pm = ProcessModel(model, "sindy")
    pm.Q_rate_ = np.diag(np.square(q_std))
    r = _prepare_run(campaign.split("test")[0], "dgnss", SEED, None, DEFAULT_SMOOTHING, WARMUP_S, RECOVERY_S)
    res = smooth_batch(pm, r.grid, r.u, r.x0, np.diag(np.square(std)), r.gnss, marginal_stride=10,
                       lateral=LateralConstraint(0.05, 5))
    assert np.array_equal(result.estimates["sindy_graph"]["run_c"].x, res.x[r.at_pose])


def test_the_outage_schedule_is_the_one_configured(mini):
    result = _bench(mini, {"gnss": {"outages": {"warmup_s": 5, "recovery_s": 4, "durations_s": [3, 7]}}})
    t0, t_end = result.truth["run_c"][[0, -1], 0]
    # by hand: 5 s of GNSS, then 3 s out, 4 s in, 7 s out, 4 s in, ... while a whole outage fits
    by_hand = np.array([[5, 8], [12, 19], [23, 26], [30, 37], [41, 44]], float)
    by_hand = by_hand[by_hand[:, 1] <= t_end - t0]
    assert len(by_hand) >= 4
    np.testing.assert_allclose(result.outages["run_c"] - t0, by_hand, atol=1e-9)
    t_fix = result.gnss["run_c"].t_valid - t0
    assert not np.any((t_fix[:, None] >= by_hand[:, 0]) & (t_fix[:, None] < by_hand[:, 1]))
    assert set(result.scores["sindy_ekf"].outage_pos_err_m) == {"3", "7"}


def test_a_named_profile_and_the_seed_give_its_fixes(mini):
    result = _bench(mini, {"gnss": {"profile": "rtk", "seed": 11}})
    truth, g = result.truth["run_c"], result.gnss["run_c"]
    assert result.profile == "rtk"
    expected = simulate_gnss(truth[:, 0], truth[:, 1], truth[:, 2], truth[:, 3], "rtk", seed=11, outages=g.outages)
    assert np.array_equal(g.p_local, expected.p_local) and np.array_equal(g.t_arrival, expected.t_arrival)


def test_a_custom_profile_is_simulated_as_given(mini):
    custom = {"name": "mybox", "rate_hz": 2, "std_m": 0.4, "std_up_m": 0.8, "latency_s": 0.3,
              "latency_jitter_s": 0.0}
    result = _bench(mini, {"gnss": {"profile": custom}})
    g = result.gnss["run_c"]
    assert result.profile == "mybox" and g.profile == "mybox"
    np.testing.assert_allclose(np.diff(g.t_valid)[np.diff(g.t_valid) < 1.0], 0.5, atol=1e-6)  # 2 Hz
    np.testing.assert_allclose(g.t_arrival - g.t_valid, 0.3, atol=1e-6)  # latency, no jitter (t ~ 1.7e9 s)
    np.testing.assert_allclose(g.std[:, :2], 0.4, rtol=1e-6)  # reported: its white noise (no bias; float32)
    assert result.to_json()["config"]["gnss"]["profile"]["rate_hz"] == 2.0


def test_enabled_picks_the_estimators_and_arguments_win_over_the_file(mini):
    result = _bench(mini, {"gnss": {"profile": "standalone"}}, run=("sindy_ekf", "dead_reckoning"))
    assert set(result.scores) == {"sindy_ekf", "dead_reckoning"}
    # explicit arguments (the command line's) win: profile, seed and estimators
    over = _bench(mini, {"gnss": {"profile": "standalone", "seed": 9}}, run=("sindy_ekf",),
                  profile="dgnss", seed=SEED, estimators=("cv_ekf",))
    assert set(over.scores) == {"cv_ekf"} and over.profile == "dgnss"
    recorded = over.to_json()["config"]
    assert recorded["gnss"]["profile"] == "dgnss" and recorded["gnss"]["seed"] == SEED
    assert [n for n, e in recorded["estimators"].items() if e["enabled"]] == ["cv_ekf"]
    # the effective settings load back as the same settings
    again = config_from_dict(recorded, "benchmark.json")
    assert again.to_dict() == recorded
