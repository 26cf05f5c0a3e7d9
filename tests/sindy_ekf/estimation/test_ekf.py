"""EKF: consistency against simulated truth, latency handling against the no-latency filter,
gating of multipath outliers, dead reckoning, and every kind of bad input."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from groundfloor.errors import InputError
from simulation.gnss import FLAG_OUTLIER, PROFILES, simulate_gnss
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import (
    LinearDynamics,
    PolyBody,
    inputs_at,
    nees_at_epochs,
    outage_runs,
    simulate_truth,
    simulate_truths,
    truth_on,
)

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def _grid(truth, gnss):
    return estimation_grid(truth.t, gnss.t_valid if gnss is not None else None)


@pytest.fixture(scope="module")
def oracle():
    model = ProcessModel(PolyBody(), name="oracle")
    rng = np.random.default_rng(100)
    return fit_process_noise(model, simulate_truths(model, 30.0, rng, n_runs=4))


def test_ekf_is_consistent_with_the_oracle_model(oracle):
    """Average NEES over independent runs inside the two-sided 95 % chi-square band (6 dof)."""
    truths, runs = outage_runs(oracle, P0, np.random.default_rng(1))
    nees = [v for truth, res in zip(truths, run_ekf_batch(oracle, runs)) for v in nees_at_epochs(truth, res)]
    n = len(nees)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n) / n
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def test_gnss_makes_the_estimate_better_than_dead_reckoning_and_gates_outliers(oracle):
    rng = np.random.default_rng(2)
    truth = simulate_truth(oracle, 60.0, rng)
    prof = replace(PROFILES["dgnss"], outlier_prob=0.05, outlier_m=(4.0, 8.0))
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], prof, seed=4,
                         outages=np.empty((0, 2)))
    t = _grid(truth, gnss)
    u = inputs_at(truth, t)
    ekf, dr = run_ekf_batch(oracle, [EkfRun("ekf", t, u, truth.x6[0], P0, gnss),
                                     EkfRun("dr", t, u, truth.x6[0], P0, None)])
    ref = truth_on(truth, t)
    err_ekf = np.hypot(*(ekf.x[:, :2] - ref[:, :2]).T)
    err_dr = np.hypot(*(dr.x[:, :2] - ref[:, :2]).T)
    assert np.sqrt(np.mean(err_ekf ** 2)) < 0.25  # below the 0.3 m GNSS noise
    assert np.sqrt(np.mean(err_dr[-500:] ** 2)) > 3 * np.sqrt(np.mean(err_ekf[-500:] ** 2))
    outlier = (gnss.flags & FLAG_OUTLIER) > 0
    # every multipath fix rejected, almost no good fix (gate at 0.999)
    assert not np.any(ekf.accepted[outlier])
    assert np.mean(~ekf.accepted[~outlier]) < 0.01
    # NIS of accepted fixes averages to its dof
    assert np.mean(ekf.nis[ekf.accepted]) == pytest.approx(2.0, rel=0.25)


def test_latency_at_time_of_validity_equals_the_filter_without_latency():
    """Linear-Gaussian: stochastic cloning is exact, so the final state matches a zero-latency run."""
    rng = np.random.default_rng(5)
    A = np.zeros((6, 6))
    A[0, 3] = A[1, 4] = A[2, 5] = 1.0
    A[3:, 3:] = -np.diag([1.0, 4.0, 2.0])
    B = np.zeros((6, 2))
    B[3, 0], B[5, 1] = 1.0, 0.8
    model = ProcessModel(LinearDynamics(A, B))
    model.Q_rate_ = np.diag([1e-4, 1e-4, 1e-4, 1e-2, 1e-3, 1e-2])
    truth = simulate_truth(model, 30.0, rng)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2],
                         replace(PROFILES["dgnss"], outlier_prob=0.0, latency_jitter_s=0.01), seed=3,
                         lever_arm_body=(0, 0, 0),
                         outages=np.empty((0, 2)))
    gnss = replace(gnss, t_valid=gnss.t_valid[:-1], t_arrival=gnss.t_arrival[:-1],
                   p_local=gnss.p_local[:-1], std=gnss.std[:-1], flags=gnss.flags[:-1])
    t = _grid(truth, gnss)
    u = inputs_at(truth, t)
    late = run_ekf(model, t, u, truth.x6[0], P0, gnss, gate_prob=1.0)
    now = run_ekf(model, t, u, truth.x6[0], P0, replace(gnss, t_arrival=gnss.t_valid), gate_prob=1.0)
    delay = gnss.t_arrival - gnss.t_valid
    assert np.all(delay > 0.1) and np.all(delay < 0.2)  # late, but before the next fix is valid
    np.testing.assert_allclose(late.x[-1], now.x[-1], atol=1e-9)
    np.testing.assert_allclose(late.P[-1], now.P[-1], atol=1e-12)
    assert not np.allclose(late.x[len(t) // 2], now.x[len(t) // 2], atol=1e-6)  # real-time differs


def test_envelope_warning_names_the_run(oracle, caplog):
    rng = np.random.default_rng(6)
    truth = simulate_truth(oracle, 5.0, rng)
    fast = truth.x6[0].copy()
    fast[3] = 3.0  # far beyond the 1 m/s training envelope
    with caplog.at_level(logging.WARNING):
        res = run_ekf(oracle, truth.t, truth.u, fast, P0, None, name="run_09_dr")
    assert res.outside_envelope[0]
    assert any("run_09_dr" in r.message and "envelope" in r.message for r in caplog.records)


def test_covariance_losing_positive_definiteness_is_repaired_and_counted(caplog):
    model = ProcessModel(PolyBody())
    model.Q_rate_ = np.diag([1e-4, 1e-4, -5e-2, 1e-3, 1e-3, 1e-3])  # an indefinite Q
    t = np.arange(0, 2.0, 0.02)
    with caplog.at_level(logging.WARNING):
        res = run_ekf(model, t, np.zeros((len(t), 2)), np.zeros(6), P0 * 1e-4)
    assert res.pd_repairs > 0
    assert np.all(np.isfinite(res.P)) and np.all(np.linalg.eigvalsh(res.P) > 0)
    assert any("positive definiteness" in r.message for r in caplog.records)


class Exploding(PolyBody):
    def f_and_jacobians(self, x, u):
        f, J_x, J_u = super().f_and_jacobians(x, u)
        return f + 50.0 * x ** 3, J_x + np.eye(3) * 150.0 * x[..., None] ** 2, J_u


def test_diverging_model_is_an_error_naming_the_time():
    class NoEnvelope(Exploding):  # nothing to saturate at: the cubic terms run away
        envelope = {}

    model = ProcessModel(NoEnvelope(), name="bad_model")
    model.Q_rate_ = np.eye(6) * 1e-4
    t = np.arange(0, 20.0, 0.02)
    with np.errstate(all="ignore"), pytest.raises(InputError, match=r"bad_model.*non-finite at t="):
        run_ekf(model, t, np.ones((len(t), 2)), np.r_[0, 0, 0, 1.0, 0, 0], P0)


def test_saturated_steps_counts_the_steps_that_start_outside_the_envelope():
    # dead reckoning with the small body model (vx in [-1.2, 1.2] after the 10 % margin) and no
    # input: vx decays as exp(-3 t). From vx = 1.5 only the first step starts outside (by hand:
    # projected to 1.2, it ends near 1.2 exp(-0.06) = 1.13); from vx = 1.0 none does. The seven-state
    # EKF steps its model as it is (no envelope) and counts none (nor records innovations).
    from sindy_ekf.estimation.ekf_motion import MotionSensors, run_ekf_motion

    model = ProcessModel(PolyBody())
    model.Q_rate_ = np.eye(6) * 1e-4
    t = np.arange(51) * 0.02
    u = np.zeros((len(t), 2))
    out = run_ekf(model, t, u, np.r_[0, 0, 0, 1.5, 0, 0], P0)
    assert out.saturated_steps == 1
    assert out.x[1, 3] == pytest.approx(1.2 * np.exp(-0.06), rel=1e-6)
    assert run_ekf(model, t, u, np.r_[0, 0, 0, 1.0, 0, 0], P0).saturated_steps == 0
    seven = run_ekf_motion(model, EkfRun("r", t, u, np.r_[0, 0, 0, 1.0, 0, 0], P0), MotionSensors())
    assert seven.saturated_steps == 0
    # without GNSS no fix was processed: no NIS, and no innovations (of their documented shapes)
    assert seven.nis.shape == (0,) and seven.innovation.shape == (0, 2)
    assert seven.innovation_cov.shape == (0, 2, 2) and seven.r_scale.shape == (0,)


def test_model_evaluated_inside_its_envelope_stays_finite_and_counts_saturated_steps():
    # the same exploding model, with an envelope: projected onto it, the velocities stay within
    # one step of its edge
    model = ProcessModel(Exploding(), name="bad_model")
    model.Q_rate_ = np.eye(6) * 1e-4
    t = np.arange(0, 20.0, 0.02)
    res = run_ekf(model, t, np.ones((len(t), 2)), np.r_[0, 0, 0, 1.0, 0, 0], P0)
    assert np.all(np.isfinite(res.x)) and np.all(np.isfinite(res.P))
    assert res.saturated_steps > 0.9 * len(t)
    lo, hi = model.velocity_bounds()
    assert hi[0] == pytest.approx(1.2)  # edge 1 + 10 % of the width 2
    one_step = model.step(np.r_[0, 0, 0, 1.2, 0, 0], np.ones(2), 0.0, 0.02)[3] - 1.2
    assert res.x[:, 3].max() <= 1.2 + one_step + 1e-9
    # a velocity far outside is projected onto the edge, then stepped by the model there (hand
    # computation: vx = 1.2, u = 1, vy = omega = 0), its covariance carried over (unit column)
    x = np.array([[0, 0, 0, 5.0, 0, 0]])
    x_next, F, held = model.saturated_step_and_jac(x, np.ones((1, 2)), np.zeros(1), np.full(1, 0.02), (lo, hi))
    edge = x.copy()
    edge[0, 3] = 1.2
    assert held[0]
    np.testing.assert_allclose(x_next[0], model.step(edge[0], np.ones(2), 0.0, 0.02), atol=1e-12)
    assert F[0, :, 3] == pytest.approx(np.eye(6)[3])


def test_gnss_off_the_grid_is_an_error(oracle):
    rng = np.random.default_rng(7)
    truth = simulate_truth(oracle, 5.0, rng)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], "rtk",
                         outages=np.empty((0, 2)))
    gnss = replace(gnss, t_valid=gnss.t_valid + 0.003, t_arrival=gnss.t_arrival + 0.003)
    with pytest.raises(InputError, match="not on the estimation grid"):
        run_ekf(oracle, truth.t, truth.u, truth.x6[0], P0, gnss, name="run_01")


def test_gnss_with_duplicate_stamps_is_an_error_naming_the_run(oracle):
    rng = np.random.default_rng(8)
    truth = simulate_truth(oracle, 5.0, rng)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], "rtk",
                         outages=np.empty((0, 2)))
    tv = gnss.t_valid.copy()
    tv[5] = tv[4]
    with pytest.raises(InputError, match="run_01 GNSS: duplicate"):
        run_ekf(oracle, truth.t, truth.u, truth.x6[0], P0, replace(gnss, t_valid=tv), name="run_01")


def test_non_positive_definite_initial_covariance_is_an_error(oracle):
    t = np.arange(0, 1.0, 0.02)
    with pytest.raises(InputError, match="run_02.*P0 is not positive definite"):
        run_ekf(oracle, t, np.zeros((len(t), 2)), np.zeros(6), -P0, name="run_02")


def test_estimation_grid_holds_every_stamp_and_no_long_step():
    t_poses = np.r_[0.0, 0.02, 0.04, 0.08, 0.10, 0.30]  # a skipped pulse and a dropout
    t_gnss = np.r_[0.0, 0.1 + 1e-9, 0.2]
    g = estimation_grid(t_poses, t_gnss)
    for s in np.r_[t_poses, t_gnss]:
        assert np.min(np.abs(g - s)) < 1e-6
    assert np.all(np.diff(g) <= 0.025 + 1e-12) and np.all(np.diff(g) > 1e-6)
