"""Estimators that fail alone (issue 14, item 2): a diverging estimator is recorded with its time
and reason and scored up to then, the others finish; divergence from the NIS over a sliding
window, recovery by re-initialisation from the next fix."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from groundfloor.gnss import GnssSeries
from identification.sindy.model import model_from_terms
from simulation.gnss import PROFILES, simulate_gnss
from simulation.robot import RobotParams
from sindy_ekf.benchmark.files import read_tum
from sindy_ekf.benchmark.health import (
    MAX_COAST_S,
    NIS_WINDOW,
    RESET_INFLATION,
    guarded,
    guarded_ekf_batch,
    nis_alarm,
    reset_state,
)
from sindy_ekf.benchmark.step_test import _local_median, _segment_rss, fixes_stepped
from sindy_ekf.cli import main
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, inputs_at, simulate_truth, simulate_truths, truth_on
from tests.support.trajectory_synth import write_mini_campaign

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2
GATE = 13.8155  # chi2.ppf(0.999, 2), the EKF's gate


@pytest.fixture(scope="module")
def diverging(tmp_path_factory):
    """The mini campaign and a model with one coefficient a million times too large (issue 14)."""
    tmp = tmp_path_factory.mktemp("health")
    root = write_mini_campaign(tmp / "mini")
    terms = RobotParams().terms()
    terms["omega"]["u2"] *= 1e6
    return root, model_from_terms(terms).to_json(tmp / "huge.json")


def test_one_diverging_estimator_leaves_the_others_complete(diverging, tmp_path, capsys):
    root, model = diverging
    code = main(["benchmark", str(root), "--model", str(model), "--estimators", "cv_ekf,sindy_ekf,sindy_graph",
                 "--json", str(tmp_path / "b.json"), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 0
    rows = json.loads((tmp_path / "b.json").read_text())["estimators"]
    assert set(rows) == {"cv_ekf", "sindy_ekf", "sindy_graph"}
    assert rows["cv_ekf"]["status"] == "ok" and rows["cv_ekf"]["t_s"] is None
    assert rows["cv_ekf"]["reason"] == "" and all(r["recoveries"] == 0 for r in rows.values())
    # the cv_ekf row is exactly what cv_ekf alone gives: the divergence did not touch it
    assert main(["benchmark", str(root), "--model", str(model), "--estimators", "cv_ekf",
                 "--json", str(tmp_path / "alone.json"), "--quiet"]) == 0
    alone = json.loads((tmp_path / "alone.json").read_text())["estimators"]["cv_ekf"]
    for key in ("ate_pos_m", "ate_yaw_deg", "outage_pos_err_m", "nees_mean", "nis_mean"):
        assert rows["cv_ekf"][key] == alone[key]
    for name in ("sindy_ekf", "sindy_graph"):
        row = rows[name]
        assert row["status"] == "diverged" and 0.0 < row["t_s"] < 0.1
        assert "run_c" in row["reason"] and "non-finite" in row["reason"] and "\n" not in row["reason"]
        assert f"warning: {name} diverged at t=" in err
    # the diverged filter is kept, and scored, over the poses before its divergence only
    est = read_tum(tmp_path / "out" / "tum" / "sindy_ekf" / "run_c.tum")
    truth = read_tum(tmp_path / "out" / "tum" / "truth" / "run_c.tum")
    assert 1 <= len(est) and est[-1, 0] - truth[0, 0] < rows["sindy_ekf"]["t_s"]
    d = est[:, 1:3] - truth[:len(est), 1:3]
    assert rows["sindy_ekf"]["ate_pos_m"] == pytest.approx(np.sqrt(np.mean(np.sum(d ** 2, axis=1))), rel=1e-6)


def test_benchmark_exits_non_zero_only_when_no_estimator_finished(diverging, tmp_path, capsys):
    root, model = diverging
    code = main(["benchmark", str(root), "--model", str(model), "--estimators", "sindy_ekf,dead_reckoning",
                 "--json", str(tmp_path / "b.json"), "--quiet"])
    assert code == 1 and "no estimator finished" in capsys.readouterr().err
    rows = json.loads((tmp_path / "b.json").read_text())["estimators"]  # written all the same
    assert {r["status"] for r in rows.values()} == {"diverged"}


def test_nis_alarm_is_silent_on_consistent_innovations_and_fires_when_fixes_are_rejected():
    rng = np.random.default_rng(0)
    nis = rng.chisquare(2, 100_000)  # a consistent filter: 5,000 windows
    assert nis_alarm(nis, GATE)[0] is None
    _, _, bound = nis_alarm(nis, GATE)
    assert bound == pytest.approx(2 * 97.65, rel=1e-3)  # twice chi2(40)'s 1 - 1e-6 quantile (tables)
    # isolated outliers (each clipped at the gate) are no alarm, 20 rejected fixes in a row are
    with_outliers = nis.copy()
    with_outliers[::50] = 1e4
    assert nis_alarm(with_outliers, GATE)[0] is None
    diverged = nis.copy()
    diverged[5000:5000 + NIS_WINDOW] = 1e4
    i = nis_alarm(diverged, GATE)[0]
    assert i is not None and 5000 - NIS_WINDOW < i <= 5000


@pytest.fixture(scope="module")
def jump():
    """A 40 s run of a known model under DGNSS whose fixes jump 20 m east from t = 15 s on."""
    model = fit_process_noise(ProcessModel(PolyBody(), name="oracle"),
                              simulate_truths(ProcessModel(PolyBody(), name="oracle"), 30.0,
                                              np.random.default_rng(100), n_runs=4))
    truth = simulate_truth(model, 40.0, np.random.default_rng(7))
    prof = replace(PROFILES["dgnss"], outlier_prob=0.0)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], prof, seed=1,
                         outages=np.empty((0, 2)))
    t_jump = truth.t[0] + 15.0
    p = gnss.p_local.copy()
    p[gnss.t_valid >= t_jump, 0] += 20.0
    gnss = replace(gnss, p_local=p)
    t = estimation_grid(truth.t, gnss.t_valid)
    return model, truth, EkfRun("jumpy", t, inputs_at(truth, t), truth.x6[0], P0, gnss), t_jump


def test_a_jump_in_the_fixes_is_a_divergence_at_its_time_without_recovery(jump):
    # the NIS alarm and its time on their own: without the step test
    model, truth, run, t_jump = jump
    [(res, status)] = guarded_ekf_batch(model, [run], recover=False, step_test=False)
    t_first = run.gnss.t_valid[run.gnss.t_valid >= t_jump][0]
    assert status.status == "diverged" and status.recoveries == 0
    assert status.t_s == pytest.approx(t_first - run.t[0], abs=1e-6)
    assert "NIS" in status.reason
    # kept up to the jump, identical there to the plain filter
    plain = run_ekf_batch(model, [run])[0]
    assert res.t[-1] < t_first
    np.testing.assert_array_equal(res.x, plain.x[:len(res.t)])


def test_a_jump_in_the_fixes_is_recovered_by_reinitialising_from_the_next_fix(jump):
    # the re-initialisation on its own: without the step test
    model, truth, run, t_jump = jump
    [(res, status)] = guarded_ekf_batch(model, [run], step_test=False)
    assert status.status == "ok" and status.recoveries == 1
    assert status.reason == "" and math.isnan(status.t_s)  # ok: no time, no reason
    assert len(res.t) == len(run.t)
    # after the reset the filter follows the (jumped) fixes again, with fixes accepted
    ref = truth_on(truth, res.t)
    late = res.t > t_jump + 5.0
    err = np.hypot(res.x[late, 0] - (ref[late, 0] + 20.0), res.x[late, 1] - ref[late, 1])
    assert np.sqrt(np.mean(err ** 2)) < 0.5
    assert np.mean(res.accepted[res.nis_t > t_jump + 5.0]) > 0.95


def test_a_jump_of_the_fixes_is_a_step_not_a_lost_filter(jump):
    # with the step test (default) the jumped fixes are recognised as such: no divergence even
    # without recovery, no reset, and the filter keeps the truth on the model (25 s of dead
    # reckoning) instead of following the fixes 20 m off
    model, truth, run, t_jump = jump
    for recover in (False, True):
        [(res, status)] = guarded_ekf_batch(model, [run], recover=recover)
        assert status.status == "ok" and status.recoveries == 0 and status.fix_steps >= 1
        assert len(res.t) == len(run.t)
        ref = truth_on(truth, res.t)
        late = res.t > t_jump
        assert np.sqrt(np.mean((res.x[late, 0] - ref[late, 0]) ** 2 + (res.x[late, 1] - ref[late, 1]) ** 2)) < 0.5
    assert MAX_COAST_S > run.t[-1] - t_jump  # the step outlasting MAX_COAST_S is the next test's


def test_a_step_outlasting_the_coasting_limit_is_taken_as_the_new_level(jump, monkeypatch):
    import sindy_ekf.benchmark.health as health

    model, truth, run, t_jump = jump
    monkeypatch.setattr(health, "MAX_COAST_S", 5.0)
    [(res, status)] = guarded_ekf_batch(model, [run])
    assert status.status == "ok" and status.recoveries == 1 and status.fix_steps >= 1
    late = res.t > t_jump + 15.0
    ref = truth_on(truth, res.t)
    assert np.median(res.x[late, 0] - ref[late, 0]) == pytest.approx(20.0, abs=0.5)


def test_segment_fit_matches_a_direct_computation():
    rng = np.random.default_rng(3)
    y, w = rng.normal(size=(9, 2)), rng.uniform(0.5, 2.0, 9)
    rss = _segment_rss(w, y)
    for a in range(10):
        for b in range(a, 10):
            if b > a:
                m = np.sum(w[a:b, None] * y[a:b], axis=0) / np.sum(w[a:b])
                assert rss[a, b] == pytest.approx(np.sum(w[a:b, None] * (y[a:b] - m) ** 2), abs=1e-9)
            else:
                assert rss[a, b] == 0.0


def _innovations(offset_m, rng, std=0.3, n=40):
    S = np.broadcast_to(std ** 2 * np.eye(2), (n, 2, 2))
    return rng.normal(0, std, (n, 2)) + offset_m, S


def test_step_test_tells_steps_of_the_fixes_from_a_drifting_filter():
    rng = np.random.default_rng(4)
    k = np.arange(40)[:, None]
    hits = {name: 0 for name in ("step", "burst", "burst_outlier", "drift", "noisy", "scatter")}
    for _ in range(200):
        hits["step"] += fixes_stepped(*_innovations(np.where(k >= 17, [2.0, -1.0], 0.0), rng))
        hits["burst"] += fixes_stepped(*_innovations(np.where((k >= 10) & (k < 30), [0.0, 3.0], 0.0), rng))
        y, S = _innovations(np.where(k >= 12, [1.5, 1.5], 0.0), rng)
        y[25] += [8.0, 0.0]  # an outlier inside the step
        hits["burst_outlier"] += fixes_stepped(y, S)
        # a lost filter: the innovations grow instead of jumping, 6 m over the 8 s (0.75 m/s: a
        # heading 45 deg off at 1 m/s); three levels leave a ramp's 1/sqrt(12) per level, so a
        # ramp is told from steps once it is several times the fixes' noise over the window
        hits["drift"] += fixes_stepped(*_innovations(k / 39 * np.array([6.0, 0.0]), rng))
        # a step whose fixes scatter three times more than their covariance says
        y, S = _innovations(np.where(k >= 17, [2.0, -1.0], 0.0), rng, std=0.9)
        hits["noisy"] += fixes_stepped(y, S / 9.0)
        hits["scatter"] += fixes_stepped(*_innovations(rng.normal(0, 1.0, (40, 2)), rng))
    assert hits["step"] >= 195 and hits["burst"] >= 195 and hits["burst_outlier"] >= 190
    assert hits["drift"] <= 5 and hits["noisy"] == 0 and hits["scatter"] == 0


def test_an_outlier_at_either_end_of_the_window_is_left_out_like_one_inside():
    # Monte-Carlo run 41 (bench/results/monte_carlo.md): a multipath burst ran to the alarm
    # window's last fix, and that fix was an outlier 9 m off. Padding the running median with the
    # end fix made the outlier 3 of its own 5 neighbours, so it stayed in, the window was "not a
    # step", and the filter was reset onto the burst.
    rng = np.random.default_rng(7)
    k = np.arange(40)[:, None]
    hits = {"last": 0, "first": 0}
    for _ in range(100):
        y, S = _innovations(np.where(k >= 20, [2.5, -1.0], 0.0), rng)
        y[-1] = [4.4, -8.6]
        hits["last"] += fixes_stepped(y, S, need_step=True)
        y, S = _innovations(np.where(k < 20, [2.5, -1.0], 0.0), rng)
        y[0] = [-6.0, 7.0]
        hits["first"] += fixes_stepped(y, S, need_step=True)
    assert hits["last"] >= 95 and hits["first"] >= 95


def test_running_median_of_five_shifts_inward_at_the_ends():
    y = np.array([[1.0, 0.0], [9.0, 1.0], [3.0, 2.0], [7.0, 3.0], [5.0, 4.0], [100.0, 5.0]])
    # by hand: rows 0-2 take rows 0-4 (x 1 9 3 7 5 -> 5), row 3 rows 1-5 (9 3 7 5 100 -> 7), and
    # so do rows 4 and 5; y the same windows: 2, 3, 3, 3
    np.testing.assert_array_equal(_local_median(y), [[5, 2], [5, 2], [5, 2], [7, 3], [7, 3], [7, 3]])
    np.testing.assert_array_equal(_local_median(y[:3]), np.repeat([[3.0, 1.0]], 3, axis=0))


def test_step_test_takes_several_levels_and_tells_them_from_a_curved_drift():
    # overlapping multipath bursts give four levels in 8 s (the Monte-Carlo runs 419, 433 and 489
    # of the `all` mix, re-initialised onto the burst and lost before the levels were allowed);
    # a filter whose error grows with the square of time (a heading error under acceleration)
    # is a curve, which a staircase follows only with more levels than the curve's coefficients
    rng = np.random.default_rng(5)
    k = np.arange(40)[:, None]
    levels = np.where(k < 8, 0.0, np.where(k < 18, [0.4, 4.7], np.where(k < 27, [-1.9, 7.4], [-2.3, 2.7])))
    hits = {"bursts": 0, "curve": 0, "offset_first": 0, "offset_later": 0, "never_agreed": 0, "agreed_later": 0,
            "between_bursts": 0}
    for _ in range(200):
        hits["bursts"] += fixes_stepped(*_innovations(levels, rng), need_step=True)
        hits["curve"] += fixes_stepped(*_innovations((k / 39) ** 2 * np.array([6.0, 3.0]), rng))
        # a constant offset over the whole window: a filter drifted off before it, unless the
        # episode began with a step earlier (the windows after the first)
        y, S = _innovations(np.full((40, 2), [1.2, 0.0]), rng)
        hits["offset_first"] += fixes_stepped(y, S, need_step=True)
        hits["offset_later"] += fixes_stepped(y, S, need_step=False)
        # a step from fixes that were already 2 m (6.7 sigma) off the filter: the filter did not
        # follow them before either (the start of Monte-Carlo run 734), unless the episode is older
        y, S = _innovations(np.where(k < 15, [2.0, 0.0], [4.0, 2.0]), rng)
        hits["never_agreed"] += fixes_stepped(y, S, need_step=True)
        hits["agreed_later"] += fixes_stepped(y, S, need_step=False)
        # the tail of one burst, the fixes back with the filter, the next burst (Monte-Carlo run 2):
        # the first level is off, the middle one agrees
        y, S = _innovations(np.where(k < 6, [-0.2, 2.3], np.where(k < 20, 0.0, [-2.2, 0.4])), rng)
        hits["between_bursts"] += fixes_stepped(y, S, need_step=True)
    assert hits["bursts"] >= 195 and hits["offset_later"] >= 195 and hits["agreed_later"] >= 195
    assert hits["between_bursts"] >= 195
    assert hits["curve"] <= 5 and hits["offset_first"] == 0 and hits["never_agreed"] == 0


def test_partitions_match_an_exhaustive_search():
    from itertools import combinations

    from sindy_ekf.benchmark.step_test import _partitions

    rng = np.random.default_rng(6)
    y, w = rng.normal(size=(11, 2)), rng.uniform(0.5, 2.0, 11)
    rss = _segment_rss(w, y)
    cost, _ = _partitions(rss, 4, min_len=2)
    for k in range(1, 5):
        best = min((sum(rss[a, b] for a, b in zip((0, *cuts), (*cuts, 11)))
                    for cuts in combinations(range(1, 11), k - 1)
                    if all(b - a >= 2 for a, b in zip((0, *cuts), (*cuts, 11)))), default=np.inf)
        assert cost[k, 11] == pytest.approx(best, abs=1e-9)


def test_reset_takes_the_position_of_the_next_fix_less_the_rotated_lever_arm():
    fixes = np.array([[10.0, 5.0, 0.0], [11.0, 5.5, 0.0], [12.0, 6.0, 0.0]])
    gnss = GnssSeries("rtk", np.array([1.0, 2.0, 3.0]), np.array([1.1, 2.1, 3.1]), fixes,
                      np.full((3, 3), 0.02), np.zeros(3, np.uint8), np.array([0.4, 0.0, 0.0]), np.empty((0, 2)))
    x = np.array([0.0, 0.0, math.pi / 2, 1.0, 0.1, 0.2])
    P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2
    x1, P1 = reset_state(x, P0, gnss, t_from=1.5)
    # by hand: the fix at t = 2 s, the antenna 0.4 m ahead at heading 90 deg is 0.4 m north
    np.testing.assert_allclose(x1, [11.0, 5.1, math.pi / 2, 1.0, 0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(np.diag(P1)[:2], 0.02 ** 2 + RESET_INFLATION ** 2 * 0.05 ** 2)
    np.testing.assert_allclose(np.diag(P1)[2:], RESET_INFLATION ** 2 * np.diag(P0)[2:])
    assert reset_state(x, P0, gnss, t_from=3.0) is None  # no fix after: no reset


def test_guarded_call_names_how_an_estimator_ended():
    from types import SimpleNamespace

    t = np.arange(5) * 0.5 + 10.0
    fine = SimpleNamespace(t=t, x=np.zeros((5, 6)))
    assert guarded(lambda: fine) == (fine, guarded(lambda: fine)[1])
    assert guarded(lambda: fine)[1].status == "ok"
    broken = np.zeros((5, 6))
    broken[3, 2] = np.nan
    value, status = guarded(lambda: SimpleNamespace(t=t, x=broken))
    assert value is None and status.status == "diverged" and status.t_s == 1.5

    def boom():
        raise RuntimeError("gtsam said\nno")

    value, status = guarded(boom)
    assert value is None and status.status == "failed" and status.reason == "RuntimeError: gtsam said no"
