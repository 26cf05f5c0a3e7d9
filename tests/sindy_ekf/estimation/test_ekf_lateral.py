"""The lateral non-holonomic pseudo-measurement ``v_y = 0`` of the EKF."""
from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.stats import chi2

from groundfloor.errors import InputError
from sindy_ekf.estimation.ekf import (
    EkfRun,
    LateralConstraint,
    estimation_grid,
    fit_lateral_constraint,
    lateral_update,
    run_ekf_batch,
)
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import (
    PolyBody,
    inputs_at,
    nees_at_epochs,
    outage_runs,
    simulate_truths,
    truth_on,
)

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


class SpuriousVyBody(PolyBody):
    """PolyBody whose lateral law is replaced by a spurious constant lateral acceleration (an
    integrator: ``v_y`` drifts in dead reckoning, as with identified models without a lateral law)."""

    def f_and_jacobians(self, x, u):
        f, J_x, J_u = super().f_and_jacobians(x, u)
        f, J_x = f.copy(), J_x.copy()
        f[..., 1] = 0.15
        J_x[..., 1, :] = 0.0
        return f, J_x, J_u


@pytest.fixture(scope="module")
def trained():
    """Return the oracle process (Q fitted) and the lateral constraint fitted on train truths."""
    model = ProcessModel(PolyBody(), name="oracle")
    train = simulate_truths(model, 30.0, np.random.default_rng(100), n_runs=4)
    fit_process_noise(model, train)
    return model, fit_lateral_constraint([s.x6[:, 4] for s in train], every=10), train


def test_fitted_std_is_the_rms_of_the_train_vy(trained):
    _, lateral, train = trained
    vy = np.concatenate([s.x6[:, 4] for s in train])
    assert lateral.vy_std_m_s == pytest.approx(2.0 * np.sqrt(np.mean(vy ** 2)), rel=1e-12)
    assert fit_lateral_constraint(vy, inflation=1.0).vy_std_m_s == pytest.approx(np.sqrt(np.mean(vy ** 2)))
    assert 0.005 < lateral.vy_std_m_s < 0.2 and lateral.every == 10
    # non-finite samples ignored, floor applied
    assert fit_lateral_constraint([np.array([np.nan, 0.0, 0.0])]).vy_std_m_s == 1e-3


def test_lateral_update_equals_the_textbook_kalman_update():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 6, 6))
    P = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(6)
    x = rng.standard_normal((5, 6))
    r_std = 0.07
    x_new, P_new, IKH = lateral_update(x, P, r_std)
    H = np.zeros((1, 6))
    H[0, 4] = 1.0
    for i in range(5):  # K = P H^T S^-1, x += K (0 - H x), P = (I - K H) P
        S = H @ P[i] @ H.T + r_std ** 2
        K = P[i] @ H.T @ np.linalg.inv(S)
        np.testing.assert_allclose(x_new[i], x[i] + (K @ (0.0 - H @ x[i])), atol=1e-12)
        np.testing.assert_allclose(P_new[i], (np.eye(6) - K @ H) @ P[i], atol=1e-10)
        np.testing.assert_allclose(IKH[i], np.eye(6) - K @ H, atol=1e-12)
    assert np.all(P_new[:, 4, 4] < r_std ** 2)


def test_ekf_with_the_constraint_stays_consistent_with_the_oracle(trained):
    """Average NEES over independent runs inside the two-sided 95 % chi-square band (6 dof),
    with a GNSS outage, and the constraint does not make the estimate worse."""
    model, lateral, _ = trained
    truths, runs = outage_runs(model, P0, np.random.default_rng(1))
    nees, err_on, err_off = [], [], []
    with_lateral = run_ekf_batch(model, runs, lateral=lateral)
    for truth, on, off in zip(truths, with_lateral, run_ekf_batch(model, runs)):
        ref = truth_on(truth, on.t)
        nees += nees_at_epochs(truth, on)
        err_on.append(on.x[:, 4] - ref[:, 4])
        err_off.append(off.x[:, 4] - ref[:, 4])
        assert on.P[-1, 4, 4] < off.P[-1, 4, 4]  # the pseudo-measurement was applied
    n = len(nees)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n) / n
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)
    assert np.sqrt(np.mean(np.square(err_on))) <= 1.05 * np.sqrt(np.mean(np.square(err_off)))


def test_constraint_bounds_vy_drift_in_dead_reckoning(trained):
    """A model with a spurious lateral acceleration drifts in v_y without GNSS; the constraint
    keeps v_y near the truth and the position drift far smaller."""
    model, lateral, _ = trained
    bad = ProcessModel(SpuriousVyBody(), name="spurious_vy")
    bad.Q_rate_ = copy.deepcopy(model.Q_rate_)
    truth = simulate_truths(model, 30.0, np.random.default_rng(7), n_runs=1)[0]
    t = estimation_grid(truth.t, None)
    run = EkfRun("dr", t, inputs_at(truth, t), truth.x6[0], P0, None)
    off = run_ekf_batch(bad, [run])[0]
    on = run_ekf_batch(bad, [run], lateral=LateralConstraint(lateral.vy_std_m_s, every=1))[0]
    ref = truth_on(truth, t)
    # 0.15 m/s^2 would reach 4.5 m/s over 30 s; the projection onto the model's envelope stops
    # it at the envelope's edge, still three times the constraint's band
    lo, hi = bad.velocity_bounds()
    assert np.max(np.abs(off.x[:, 4] - ref[:, 4])) > 3 * (3 * lateral.vy_std_m_s + 0.05)
    assert lo[1] - 0.01 <= off.x[-1, 4] <= hi[1] + 0.01
    assert np.max(np.abs(on.x[:, 4] - ref[:, 4])) < 3 * lateral.vy_std_m_s + 0.05
    assert on.P[-1, 4, 4] < lateral.vy_std_m_s ** 2
    drift_on = np.hypot(*(on.x[-1, :2] - ref[-1, :2]))
    drift_off = np.hypot(*(off.x[-1, :2] - ref[-1, :2]))
    assert drift_on < 0.2 * drift_off


@pytest.mark.parametrize("kwargs, culprit", [({"vy_std_m_s": 0.0}, "vy_std_m_s"),
                                             ({"vy_std_m_s": np.nan}, "vy_std_m_s"),
                                             ({"vy_std_m_s": 0.1, "every": 0}, "every"),
                                             ({"vy_std_m_s": 0.1, "every": 1.5}, "every")])
def test_bad_constraint_is_an_error_naming_the_field(kwargs, culprit):
    with pytest.raises(InputError, match=culprit):
        LateralConstraint(**kwargs)


def test_no_finite_train_vy_is_an_error():
    with pytest.raises(InputError, match="train v_y"):
        fit_lateral_constraint([np.array([np.nan]), np.empty(0)])
    with pytest.raises(InputError, match="inflation"):
        fit_lateral_constraint(np.ones(3), inflation=-1.0)
