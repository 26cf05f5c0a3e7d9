"""The health monitor's bookkeeping by hand: ``fix_steps`` counts exactly the alarms the step test
explains (none on a quiet run), the first alarm of an episode asks for a step inside its window and
the next, right after it, does not (module docstring); the reset's heading and velocity std are
ten times P0's; a run's score cut short keeps the outages that ended by its last estimated pose,
including one ending exactly on it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

import sindy_ekf.benchmark.health as health
from groundfloor.gnss import GnssSeries
from sindy_ekf.benchmark.health import RunStatus, _recover, reset_state, score_partial
from sindy_ekf.benchmark.result import Estimate

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
    out, status = _recover(None, run, res, 0.999, None, recover=False)
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
