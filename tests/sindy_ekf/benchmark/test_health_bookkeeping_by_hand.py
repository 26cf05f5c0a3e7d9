"""The health monitor's bookkeeping by hand: ``fix_steps`` counts exactly the alarms the step test
explains (none on a quiet run), the first alarm of an episode asks for a step inside its window and
the next, right after it, does not, and each sees the alarm's window and the one before (module
docstring); the reset's heading and velocity std are ten times P0's, its time the window's first
fix beyond the gate (its start if none is), its fixes' variance factor the one learnt before the
alarm (1 at the first fix); a run's score cut short keeps the outages that ended by its last
estimated pose, including one ending exactly on it."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from groundfloor.errors import DivergenceError
from groundfloor.gnss import GnssSeries
from sindy_ekf.benchmark import health
from sindy_ekf.benchmark.health import (
    NIS_FALSE_ALARM,
    NIS_TOLERANCE,
    NIS_WINDOW,
    RunStatus,
    guarded,
    reset_state,
    score_partial,
    watch_nis,
)
from sindy_ekf.benchmark.result import Estimate
from sindy_ekf.estimation.ekf import EkfResult, EkfRun

GATE_NIS = 13.8


def _res(nis: np.ndarray) -> SimpleNamespace:
    """The part of an EkfResult the monitor reads before any reset: NIS at 5 Hz and innovations."""
    n = len(nis)
    return SimpleNamespace(nis=np.asarray(nis, float), nis_t=100.0 + 0.2 * np.arange(n), gate_nis=GATE_NIS,
                           innovation=np.zeros((n, 2)), innovation_cov=np.repeat(np.eye(2)[None], n, 0))


def _run_with(monkeypatch, nis, stepped: bool):
    calls = []

    def fake_fixes_stepped(innovation, innovation_cov, t, need_step=False):
        calls.append((float(t[0]), need_step))
        return stepped

    monkeypatch.setattr(health, "fixes_stepped", fake_fixes_stepped)
    run = SimpleNamespace(name="r", t=np.array([100.0]))
    res = _res(nis)
    out, status = watch_nis(None, run, res, 0.999, None, recover=False)
    return res, out, status, calls


def test_a_quiet_run_has_no_fix_steps_and_asks_no_step_test(monkeypatch):
    res, out, status, calls = _run_with(monkeypatch, np.ones(100), stepped=True)
    assert out is res and calls == []
    assert status == RunStatus()  # ok, no recovery, no fix step


def test_each_alarm_the_step_test_explains_is_one_fix_step(monkeypatch):
    # fixes 30 to 99 all at the gate (13.8 each): windows of 20 alarm from where most of their
    # fixes are gated; each explained alarm moves the check one window on, so the episode's
    # alarms follow each other at most a window apart and every one is counted once
    nis = np.ones(100)
    nis[30:] = GATE_NIS
    res, out, status, calls = _run_with(monkeypatch, nis, stepped=True)
    assert out is res
    assert len(calls) >= 2
    assert status == RunStatus(fix_steps=len(calls))
    # the first alarm of the episode must hold a step (need_step), the ones right after it not
    assert [need for _, need in calls] == [True] + [False] * (len(calls) - 1)
    # the windows asked about are one window (20 fixes, 4 s) apart
    np.testing.assert_allclose(np.diff([t for t, _ in calls]), 4.0, atol=1e-9)


P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def test_a_reset_sets_heading_and_velocity_std_to_ten_times_p0s():
    gnss = GnssSeries("rtk", np.array([1.0, 2.0]), np.array([1.1, 2.1]), np.array([[3.0, 4.0, 0.0], [5.0, 6.0, 0.0]]),
                      np.full((2, 3), 0.02), np.zeros(2, np.uint8), np.zeros(3), np.empty((0, 2)))
    x1, P1 = reset_state(np.array([0.0, 0.0, 0.3, 1.0, 0.0, 0.1]), P0, gnss, t_from=0.0)
    np.testing.assert_allclose(np.sqrt(np.diag(P1)[2:]), 10.0 * np.sqrt(np.diag(P0)[2:]), rtol=1e-12)
    # position: the fix's variance plus P0's inflated the same way
    np.testing.assert_allclose(np.diag(P1)[:2], 0.02 ** 2 + 100.0 * np.diag(P0)[:2], rtol=1e-12)
    np.testing.assert_allclose(x1[:2], [3.0, 4.0], atol=1e-12)


def test_a_score_cut_short_keeps_the_outages_that_ended_by_its_last_pose():
    # truth every 0.5 s over 10 s, the estimate stops after 6 s (13 poses), 1 m off in x throughout;
    # outages of 5 s ending on the last pose (kept), 1 s inside (kept) and 2 s after it (dropped)
    t = np.arange(21) * 0.5
    truth = np.column_stack([t, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t)])
    n = 13
    x = np.zeros((n, 6))
    x[:, 0] = 1.0
    est = Estimate(t[:n], x, np.full((n, 6, 6), np.nan))
    outages = np.array([[1.0, 6.0], [2.0, 3.0], [6.5, 8.5]])
    score, curves = score_partial({"r": est}, {"r": truth}, {"r": outages}, 1.0, RunStatus())
    assert sorted(curves) == ["1", "5"]
    assert score.outage_pos_err_m == {"1": pytest.approx(1.0), "5": pytest.approx(1.0)}
    assert score.ate_pos_m == pytest.approx(1.0)
    assert math.isclose(curves["5"][-1, 0], 5.0, abs_tol=1e-9)


def test_the_step_test_sees_the_alarm_window_and_the_window_before_it(monkeypatch):
    # every fix at the gate from the first on: alarms at fixes 0, 20, 40, 60 and 80 (each explained
    # one moves the check a window on); each step test gets the fixes of the window before the
    # alarm's (none before fix 0) and of the alarm's: [0, 20), [0, 40), [20, 60), [40, 80), [60, 100)
    calls = []

    def fake_fixes_stepped(innovation, innovation_cov, t, need_step=False):
        assert len(innovation) == len(innovation_cov) == len(t)
        calls.append((round(float(t[0]), 9), len(t)))
        return True

    monkeypatch.setattr(health, "fixes_stepped", fake_fixes_stepped)
    res = _res(np.full(100, GATE_NIS))
    _, status = watch_nis(None, SimpleNamespace(name="r", t=np.array([100.0])), res, 0.999, None, recover=False)
    assert calls == [(100.0, 20), (100.0, 40), (104.0, 40), (108.0, 40), (112.0, 40)]
    assert status == RunStatus(fix_steps=5)


# -- a reset by hand: a run of 20 s on a 50 Hz grid, fixes at 5 Hz, the EKF's tail run stubbed --------

def _ekf_result(nis: np.ndarray, r_scale: np.ndarray) -> EkfResult:
    t = 100.0 + 0.02 * np.arange(1001)
    m = len(nis)
    return EkfResult("r", t, np.zeros((len(t), 6)), np.repeat(P0[None], len(t), 0), nis, 100.0 + 0.2 * np.arange(m),
                     np.ones(m, bool), GATE_NIS, 0, np.zeros(len(t), bool), 1.0,
                     innovation=np.zeros((m, 2)), innovation_cov=np.repeat(np.eye(2)[None], m, 0), r_scale=r_scale)


def _reset_run(nis: np.ndarray, r_scale: np.ndarray, monkeypatch):
    m = len(nis)
    t_fix = 100.0 + 0.2 * np.arange(m)
    p = np.column_stack([np.arange(m, dtype=float), np.zeros(m), np.zeros(m)])
    gnss = GnssSeries("rtk", t_fix, t_fix.copy(), p, np.full((m, 3), 0.02), np.zeros(m, np.uint8), np.zeros(3),
                      np.empty((0, 2)))
    res = _ekf_result(nis, r_scale)
    run = EkfRun("r", res.t, np.zeros((len(res.t), 2)), np.zeros(6), P0, gnss)
    tails = []

    def fake_run_alone(model, tail_run, gate_prob, lateral):
        tails.append(tail_run)
        return None, RunStatus("failed", 0.0, "stub")

    monkeypatch.setattr(health, "_run_alone", fake_run_alone)
    _, status = watch_nis(None, run, res, 0.999, None, recover=True, step_test=False)
    return status, tails


def _window_bound() -> float:
    return NIS_TOLERANCE * chi2.ppf(1.0 - NIS_FALSE_ALARM, 2 * NIS_WINDOW)


def test_an_alarm_without_a_gated_fix_diverges_from_its_windows_start_and_resets_at_unit_variance_factor(
        monkeypatch):
    # every NIS 12, inside the gate (13.8) yet 20 of them beyond the window's bound: the alarm is the
    # first window, no fix in it beyond the gate, so the divergence dates from its start (fix 0,
    # 100 s); no variance factor learnt before fix 0: the reset uses the fixes' own std
    assert 20 * 12.0 > _window_bound()
    status, tails = _reset_run(np.full(100, 12.0), np.full(100, 9.0), monkeypatch)
    assert status.status == "diverged" and status.t_s == 0.0 and status.recoveries == 1  # the tail failed
    [tail] = tails
    assert tail.t[0] == 100.0
    np.testing.assert_allclose(tail.x0[:2], [1.0, 0.0])  # the first fix after 100 s: fix 1 at 100.2 s
    np.testing.assert_allclose(np.diag(tail.P0)[:2], 0.02 ** 2 + 100.0 * np.diag(P0)[:2], rtol=1e-12)
    np.testing.assert_allclose(tail.gnss.std, 0.02, rtol=1e-12)
    np.testing.assert_allclose(tail.gnss.t_valid[0], 100.2, atol=1e-9)


def test_a_reset_after_the_first_fix_carries_the_variance_factor_learnt_by_then(monkeypatch):
    # fix 0 quiet, then NIS x (inside the gate) such that the window at 0 stays under the bound
    # and the one at 1 does not: the alarm is at fix 1 (100.2 s), the factor learnt by then is the
    # one applied to fix 0, 4: the reset position's variance and the tail's fixes use 4 x 0.02^2
    b = _window_bound()
    x = 0.5 * (b / 20 + (b - 1.0) / 19)
    assert 1.0 + 19 * x <= b < 20 * x < 20 * GATE_NIS
    nis = np.full(100, x)
    nis[0] = 1.0
    r_scale = np.full(100, 9.0)
    r_scale[0] = 4.0
    status, tails = _reset_run(nis, r_scale, monkeypatch)
    assert status.t_s == pytest.approx(0.2, abs=1e-9)
    [tail] = tails
    assert tail.t[0] == pytest.approx(100.2, abs=1e-9)
    np.testing.assert_allclose(tail.x0[:2], [2.0, 0.0])  # fix 2, at 100.4 s
    np.testing.assert_allclose(np.diag(tail.P0)[:2], 4.0 * 0.02 ** 2 + 100.0 * np.diag(P0)[:2], rtol=1e-12)
    np.testing.assert_allclose(tail.gnss.std, 2.0 * 0.02, rtol=1e-12)


def test_a_tail_that_diverges_again_dates_its_divergence_on_the_runs_clock(monkeypatch):
    # the alarm at fix 0 (every NIS 12, as above): reset at 100 s; the tail diverges 1.5 s after its
    # own start, which is 1.5 s after the run's; its reason is the tail's, one recovery counted
    nis = np.full(100, 12.0)
    res = _ekf_result(nis, np.full(100, 9.0))
    m = len(nis)
    t_fix = 100.0 + 0.2 * np.arange(m)
    gnss = GnssSeries("rtk", t_fix, t_fix.copy(), np.zeros((m, 3)), np.full((m, 3), 0.02), np.zeros(m, np.uint8),
                      np.zeros(3), np.empty((0, 2)))
    run = EkfRun("r", res.t - 0.5, np.zeros((len(res.t), 2)), np.zeros(6), P0, gnss)  # run starts 0.5 s earlier

    def fake_run_alone(model, tail_run, gate_prob, lateral):
        n = 76  # 1.5 s of the 50 Hz grid
        tail = _ekf_result(np.ones(5), np.ones(5))
        tail = replace(tail, t=tail_run.t[:n], x=tail.x[:n], P=tail.P[:n], outside_envelope=tail.outside_envelope[:n])
        return tail, RunStatus("diverged", 1.5, "tail lost")

    monkeypatch.setattr(health, "_run_alone", fake_run_alone)
    got, status = watch_nis(None, run, res, 0.999, None, recover=True, step_test=False)
    assert status.status == "diverged" and status.reason == "tail lost" and status.recoveries == 1
    assert status.t_s == pytest.approx(1.5 + 0.5, abs=1e-9)  # the tail's 1.5 s from 100 s, the run from 99.5 s
    assert got.t[0] == 100.0 and got.t[-1] == pytest.approx(101.5, abs=1e-9)


def test_an_estimator_that_raises_failed_from_the_runs_start():
    # no estimate at all: failed at 0 s (RunStatus.t_s is where it failed; nothing came out of it);
    # a DivergenceError keeps its own time
    def boom():
        raise ValueError("no")

    assert guarded(boom) == (None, RunStatus("failed", 0.0, "ValueError: no"))

    def lost():
        raise DivergenceError("state non-finite", 2.5)

    value, status = guarded(lost)
    assert value is None and status.status == "diverged" and status.t_s == 2.5
