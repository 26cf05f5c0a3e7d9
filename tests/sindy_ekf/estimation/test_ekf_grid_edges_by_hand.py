"""EKF fixes at the edges where the 1 us grid tolerance decides, against a hand Kalman update.

A fix valid at the first or the last grid time is applied there (the grid's ends are inclusive);
1.5 us beyond either end it is outside the run and ignored; 0.5 us off a grid time it is that grid
time. A fix arriving exactly at a grid time is applied at that step, 1.5 us later at the next one,
after the last grid time at the last step.
The model is linear-Gaussian and there is no lever arm, so the update at a step is the textbook
``K = P H^T (H P H^T + R)^-1`` with ``H = [I 0]``. Also by hand: the filterpy object's update and
its predict's defaults, and the eigenvalue clipping of a covariance that is not positive definite.
A delayed fix after on-time updates inside its latency is checked against an augmented-state filter
by hand, and a finished run of a batch against the model's propagation by hand (it is no longer
propagated on the batch's padding).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundfloor.gnss import GnssSeries
from sindy_ekf.estimation.ekf import run_ekf
from tests.support.estimation_helpers import linear_gaussian_model, simulate_truth

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2
STD = 0.03


def _kalman(x, P, z):
    H = np.eye(2, 6)
    R = STD ** 2 * np.eye(2)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    return x + K @ (z - H @ x)


def _setup():
    model = linear_gaussian_model()
    truth = simulate_truth(model, 1.0, np.random.default_rng(7))
    return model, truth.t, truth.u, truth.x6[0] + np.array([0.02, -0.03, 0.01, 0.02, 0.0, -0.01])


def _gnss(t_valid, t_arrival, p):
    m = len(t_valid)
    return GnssSeries("dgnss", np.asarray(t_valid, float), np.asarray(t_arrival, float),
                      np.column_stack([p, np.zeros(m)]), np.full((m, 3), STD), np.zeros(m, np.uint8),
                      np.zeros(3), np.empty((0, 2)))


def test_fixes_at_the_first_and_last_grid_time_are_applied_there():
    model, t, u, x0 = _setup()
    z = np.array([[x0[0] + 0.1, x0[1] - 0.05], [0.7, -0.4]])
    res = run_ekf(model, t, u, x0, P0, _gnss([t[0], t[-1]], [t[0], t[-1]], z), gate_prob=1.0)
    np.testing.assert_array_equal(res.nis_t, [t[0], t[-1]])
    np.testing.assert_allclose(res.x[0], _kalman(x0, P0, z[0]), atol=1e-12)
    first_only = run_ekf(model, t, u, x0, P0, _gnss([t[0]], [t[0]], z[:1]), gate_prob=1.0)
    np.testing.assert_allclose(res.x[:-1], first_only.x[:-1], atol=1e-12)
    np.testing.assert_allclose(res.x[-1], _kalman(first_only.x[-1], first_only.P[-1], z[1]), atol=1e-10)


def test_fixes_half_a_tolerance_off_are_on_the_grid_one_and_a_half_beyond_the_ends_are_not():
    model, t, u, x0 = _setup()
    z = np.array([[x0[0] + 0.1, x0[1] - 0.05], [0.7, -0.4]])
    near = run_ekf(model, t, u, x0, P0, _gnss([t[0] - 0.5e-6, t[-1] + 0.5e-6], [t[0], t[-1] + 0.5e-6], z),
                   gate_prob=1.0)
    exact = run_ekf(model, t, u, x0, P0, _gnss([t[0], t[-1]], [t[0], t[-1]], z), gate_prob=1.0)
    np.testing.assert_allclose(near.x, exact.x, atol=1e-12)
    beyond = run_ekf(model, t, u, x0, P0, _gnss([t[0] - 1.5e-6, t[-1] + 1.5e-6], [t[0], t[-1] + 1.5e-6], z),
                     gate_prob=1.0)
    assert beyond.nis.size == 0
    dead = run_ekf(model, t, u, x0, P0, None)
    np.testing.assert_allclose(beyond.x, dead.x, atol=1e-12)


def test_a_fix_arriving_on_a_grid_time_is_applied_there_and_1_5_us_later_at_the_next_step():
    model, t, u, x0 = _setup()
    z = np.array([[0.3, -0.2]])
    instant = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[5]], z), gate_prob=1.0)
    dead = run_ekf(model, t, u, x0, P0, None)
    np.testing.assert_allclose(instant.x[5], _kalman(dead.x[5], dead.P[5], z[0]), atol=1e-12)
    on_time = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[20]], z), gate_prob=1.0)
    np.testing.assert_allclose(on_time.x[:20], dead.x[:20], atol=1e-12)
    # linear-Gaussian, one fix: the delayed update equals the update at the time of validity
    np.testing.assert_allclose(on_time.x[20:], instant.x[20:], atol=1e-10)
    later = run_ekf(model, t, u, x0, P0, replace(_gnss([t[5]], [t[20] + 1.5e-6], z)), gate_prob=1.0)
    np.testing.assert_allclose(later.x[:21], dead.x[:21], atol=1e-12)
    np.testing.assert_allclose(later.x[21:], instant.x[21:], atol=1e-10)
    within = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[20] + 0.5e-6], z), gate_prob=1.0)
    np.testing.assert_allclose(within.x, on_time.x, atol=1e-12)


def test_the_grid_splits_a_step_longer_than_dt_max_evenly_and_merges_stamps_within_1_us():
    from sindy_ekf.estimation.ekf import estimation_grid

    # by hand (steps of at most 25 ms): 0.04 s is two steps of 0.02, 0.06 s three, 0.05 s two of
    # 0.025; 0.02 s stays one step; a fix 0.5 us after a pose is that pose's stamp
    np.testing.assert_allclose(estimation_grid(np.array([0.0, 0.04, 0.06])), [0.0, 0.02, 0.04, 0.06], atol=1e-15)
    np.testing.assert_allclose(estimation_grid(np.array([0.0, 0.06]), np.array([0.06 + 0.5e-6])),
                               [0.0, 0.02, 0.04, 0.06], atol=1e-15)
    np.testing.assert_allclose(estimation_grid(np.array([0.0, 0.05])), [0.0, 0.025, 0.05], atol=1e-15)
    np.testing.assert_allclose(estimation_grid(np.array([0.0, 0.02, 0.04])), [0.0, 0.02, 0.04], atol=0)


def test_a_fix_rejected_by_the_gate_leaves_the_estimate_as_predicted():
    model, t, u, x0 = _setup()
    dead = run_ekf(model, t, u, x0, P0, None)
    z = np.array([dead.x[5, :2] + 0.02, [100.0, 100.0]])  # the second 100 m off: beyond the 0.999 gate
    res = run_ekf(model, t, u, x0, P0, _gnss([t[5], t[10]], [t[5], t[10]], z))
    np.testing.assert_array_equal(res.accepted, [True, False])
    first = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[5]], z[:1]))
    np.testing.assert_allclose(res.x, first.x, atol=1e-12)


def test_the_filterpy_predict_propagates_by_the_model_and_f_p_ft_plus_q():
    from sindy_ekf.estimation.ekf import ModelEKF

    model, _, u, x0 = _setup()
    ekf = ModelEKF(model, x0, P0)
    x_next = model.step(x0, u[0], 0.3, 0.05)
    F = np.empty((6, 6))
    for j in range(6):  # central differences of the step: the linear model's exact Jacobian
        e = np.zeros(6)
        e[j] = 1e-6
        F[:, j] = (model.step(x0 + e, u[0], 0.3, 0.05) - model.step(x0 - e, u[0], 0.3, 0.05)) / 2e-6
    ekf.predict(u[0], 0.3, 0.05)
    np.testing.assert_allclose(ekf.x, x_next, atol=1e-14)
    np.testing.assert_allclose(ekf.P, F @ P0 @ F.T + 0.05 * model.Q_rate_, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(ekf.F, F, atol=1e-8)
    assert ekf.pd_repairs == 0


def test_a_fix_arriving_after_the_last_grid_time_is_applied_at_the_last_step():
    # valid inside the run, arriving 0.5 s after its end (a late fix of a cut run): the last step is
    # the last chance to apply it, so it is applied there, as if it had arrived on the last grid time
    model, t, u, x0 = _setup()
    z = np.array([[0.3, -0.2]])
    dead = run_ekf(model, t, u, x0, P0, None)
    instant = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[5]], z), gate_prob=1.0)
    late = run_ekf(model, t, u, x0, P0, _gnss([t[5]], [t[-1] + 0.5], z), gate_prob=1.0)
    np.testing.assert_array_equal(late.nis_t, [t[5]])
    np.testing.assert_allclose(late.x[:-1], dead.x[:-1], atol=1e-12)
    # linear-Gaussian, one fix: the delayed update equals the update at the time of validity
    np.testing.assert_allclose(late.x[-1], instant.x[-1], atol=1e-10)
    assert np.abs(late.x[-1, :2] - dead.x[-1, :2]).max() > 1e-3  # the fix moved it


def test_a_covariance_that_is_not_positive_definite_has_its_eigenvalues_clipped_at_1e_12():
    from sindy_ekf.estimation.ekf import repair_covariance

    # by hand: eigenvectors (1, 1) / sqrt 2 and (1, -1) / sqrt 2 with eigenvalues 3 and -1; the
    # negative one is clipped to 1e-12
    P = np.array([[1.0, 2.0], [2.0, 1.0]])
    repaired, done = repair_covariance(P)
    v, w = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    assert done
    np.testing.assert_allclose(repaired, 3.0 * np.outer(v, v) + 1e-12 * np.outer(w, w), rtol=0, atol=1e-15)
    np.testing.assert_allclose(repaired @ w, 1e-12 * w, rtol=0, atol=1e-15)
    same, done = repair_covariance(np.array([[2.0, 0.5], [0.5, 1.0]]))  # positive definite: only symmetrised
    assert not done
    np.testing.assert_array_equal(same, [[2.0, 0.5], [0.5, 1.0]])


def test_the_filterpy_update_without_a_lever_arm_is_the_textbook_kalman_update_and_predict_defaults():
    from sindy_ekf.estimation.ekf import ModelEKF

    model, _, _, x0 = _setup()
    ekf = ModelEKF(model, x0, P0, gate_prob=1.0)  # no lever arm: the fix measures the body's x, y
    z = x0[:2] + np.array([0.05, -0.04])
    nis, ok, _ = ekf.update_delayed(z, STD ** 2 * np.eye(2), ekf.x, ekf.P)
    assert ok
    np.testing.assert_allclose(ekf.x, _kalman(x0, P0, z), atol=1e-14)
    S = P0[:2, :2] + STD ** 2 * np.eye(2)
    assert nis == pytest.approx((z - x0[:2]) @ np.linalg.solve(S, z - x0[:2]), rel=1e-12)
    # predict() without arguments: no input, time 0, a 20 ms step (50 Hz); a model that pushes vx
    # by 0.5 t tells the time: by hand, RK4 is exact for x'' = 0.5 t
    from sindy_ekf.estimation.process_models import ProcessModel
    from tests.support.estimation_helpers import LinearDynamics

    class Clock(LinearDynamics):
        def derivative_and_jacobians(self, x6, u, t=0.0, input_jacobian=True):
            f, J_x, J_u = super().derivative_and_jacobians(x6, u, t, input_jacobian)
            f = f.copy()
            f[..., 3] += 0.5 * np.asarray(t)
            return f, J_x, J_u

    A = np.zeros((6, 6))
    A[0, 3] = 1.0  # x' = vx, vx' = 0.5 t + u1
    clock = ProcessModel(Clock(A, np.eye(6, 2, -3)))
    clock.Q_rate_ = np.eye(6) * 1e-4
    ekf = ModelEKF(clock, np.array([0.0, 0.0, 0.0, 0.2, 0.0, 0.0]), P0)
    ekf.predict()
    h = 0.02  # from t = 0: vx gains 0.5 h^2 / 2, x gains 0.2 h + 0.5 h^3 / 6
    np.testing.assert_allclose(ekf.x, [0.2 * h + 0.5 * h ** 3 / 6, 0.0, 0.0, 0.2 + 0.25 * h ** 2, 0.0, 0.0], atol=1e-15)
    ekf.predict(np.array([1.0, 0.0]), 1.0, 0.1)  # from t = 1 s: vx gains 0.1 + 0.5 (1.1^2 - 1) / 2
    np.testing.assert_allclose(ekf.x[3], 0.2 + 0.25 * h ** 2 + 0.1 + 0.0525, atol=1e-14)


def test_a_delayed_fix_sees_on_time_updates_between_its_validity_and_arrival_through_the_cross_covariance():
    # fixes A1, A2 valid and arriving at steps 19 and 20; fix B valid at step 16, arriving at step 24
    # (after A1 is valid: the module docstring's first-order case, the clone of step 16 is not
    # updated by A1, A2). Two on-time updates in a row, so that M_18 and M_19 differ (the model is
    # linear and time-invariant on a uniform grid: without them every M_k is the same F). By hand, a
    # second implementation: the state augmented with a clone of x_16, propagated with
    # blkdiag(F, I), each A applied with the gain [K_A; 0] (the clone left as it is) in Joseph form,
    # which keeps the augmented covariance the true one of these errors; B then updates the
    # augmented state with H = [0 I_2] and only the x block is kept. No products of M_k: the
    # cross-covariance of x_24 and x_16 comes from the augmented covariance.
    model, t, u, x0 = _setup()
    z_on_time = {19: np.array([0.22, -0.12]), 20: np.array([0.25, -0.15])}
    z_b = np.array([0.2, -0.1])
    res = run_ekf(model, t, u, x0, P0, _gnss([t[16], t[19], t[20]], [t[24], t[19], t[20]],
                                             [z_b, z_on_time[19], z_on_time[20]]), gate_prob=1.0)
    np.testing.assert_array_equal(res.nis_t, [t[19], t[20], t[16]])
    R = STD ** 2 * np.eye(2)
    x, P = np.concatenate([x0, x0]), np.zeros((12, 12))
    P[:6, :6] = P0
    for k in range(24):
        dt = t[k + 1] - t[k]
        F = np.empty((6, 6))
        for j in range(6):  # central differences of the step: the linear model's exact Jacobian
            e = np.zeros(6)
            e[j] = 1e-6
            F[:, j] = (model.step(x[:6] + e, u[k], t[k] - t[0], dt)
                       - model.step(x[:6] - e, u[k], t[k] - t[0], dt)) / 2e-6
        F_aug = np.eye(12)
        F_aug[:6, :6] = F
        x[:6] = model.step(x[:6], u[k], t[k] - t[0], dt)
        P = F_aug @ P @ F_aug.T
        P[:6, :6] += dt * model.Q_rate_
        if k + 1 == 16:  # the clone of the estimate at B's time of validity
            x[6:] = x[:6]
            P = np.block([[P[:6, :6], P[:6, :6]], [P[:6, :6], P[:6, :6]]])
        if k + 1 in (19, 20, 24):
            H = np.zeros((2, 12))
            if k + 1 < 24:
                H[:, :2] = np.eye(2)
                K = np.zeros((12, 2))
                K[:6] = P[:6] @ H.T @ np.linalg.inv(H @ P @ H.T + R)  # A's gain, none for the clone
                zk = z_on_time[k + 1]
            else:
                H[:, 6:8] = np.eye(2)
                K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
                zk = z_b
            x = x + K @ (zk - H @ x)
            IKH = np.eye(12) - K @ H
            P = IKH @ P @ IKH.T + K @ R @ K.T
            np.testing.assert_allclose(res.x[k + 1], x[:6], atol=1e-10)
    np.testing.assert_allclose(res.P[24], P[:6, :6], rtol=1e-8, atol=1e-14)
    # B moved the estimate at its arrival by more than the tolerance above
    before = run_ekf(model, t, u, x0, P0, _gnss([t[19], t[20]], [t[19], t[20]], [z_on_time[19], z_on_time[20]]),
                     gate_prob=1.0)
    assert np.abs(before.x[24] - res.x[24]).max() > 1e-4


def test_a_run_that_ended_is_no_longer_propagated_while_a_longer_one_of_its_batch_goes_on():
    # an unstable linear model (vx' = 5 vx): fine over the 0.2 s of the short run and the 2 s of
    # the long one, but a finished run propagated further on the batch's padding (steps of 1 s,
    # growth 65 per RK4 step) would overflow within 90 steps and raise a DivergenceError. By the
    # docstring the runs are filtered independently: the short run's estimates are those of the
    # run alone, whose mean is the model's propagation from x0 by hand (dead reckoning)
    from sindy_ekf.estimation.ekf import EkfRun, run_ekf_batch
    from sindy_ekf.estimation.process_models import ProcessModel
    from tests.support.estimation_helpers import LinearDynamics

    A = np.zeros((6, 6))
    A[0, 3] = A[1, 4] = A[2, 5] = 1.0
    A[3, 3] = 5.0
    model = ProcessModel(LinearDynamics(A, np.eye(6, 2, -3)))
    model.Q_rate_ = np.eye(6) * 1e-4
    t = np.arange(101) * 0.02
    x0 = np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0])
    long_run = EkfRun("long", t, np.zeros((101, 2)), x0, P0)
    short_run = EkfRun("short", t[:11], np.zeros((11, 2)), x0, P0)
    long_res, short_res = run_ekf_batch(model, [long_run, short_run])
    # by hand: RK4 of vx' = 5 vx, x' = vx over a step h multiplies vx by g = 1 + 5h + (5h)^2 / 2
    # + (5h)^3 / 6 + (5h)^4 / 24 and adds (g - 1) / 5 of vx to x (exact for this linear pair)
    h = 0.02
    g = 1 + 5 * h + (5 * h) ** 2 / 2 + (5 * h) ** 3 / 6 + (5 * h) ** 4 / 24
    vx = 0.1 * g ** np.arange(11)
    np.testing.assert_allclose(short_res.x[:, 3], vx, rtol=1e-12)
    np.testing.assert_allclose(short_res.x[:, 0], (vx - 0.1) / 5, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(long_res.x[:11], short_res.x, rtol=1e-12, atol=1e-15)
    assert np.all(np.isfinite(short_res.P)) and short_res.saturated_steps == 0
