"""Factor graph by hand: Levenberg-Marquardt against a numpy implementation of its documented
schedule on Rosenbrock's function (whose first Gauss-Newton steps increase the error, so the
damping must grow), iSAM2's documented defaults seen in its output, its lag dropping late fixes at
0.8 of the lag, fixes at the grid's inclusive ends, the smoother's starting trajectory and its LM
settings, where marginals are computed, the lateral factor's free components, LM's stop on a relative
decrease (a problem whose minimum error is not zero), the dynamics factor's heading error
across +-pi, and iSAM2 adding a fix arriving exactly on a grid time at that step (against a Kalman
update by hand).
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from groundfloor.gnss import GnssSeries
from sindy_ekf.estimation.graph import (
    V,
    levenberg_marquardt,
    smooth_batch,
    smooth_isam2,
)
from tests.support.estimation_helpers import linear_gaussian_model, simulate_truth

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def _rosenbrock_residual(p):
    return np.array([10.0 * (p[1] - p[0] ** 2), 1.0 - p[0]])


def _rosenbrock_jacobian(p):
    return np.array([[-20.0 * p[0], 10.0], [-1.0, 0.0]])


def _rosenbrock_graph():
    def error(this, values, H):
        p = values.atVector(V(0))
        if H is not None:
            H[0] = _rosenbrock_jacobian(p)
        return _rosenbrock_residual(p)

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [V(0)], error))
    return graph


def _lm_numpy(p, max_iterations, rel_tol, lam, residual=_rosenbrock_residual, jacobian=_rosenbrock_jacobian):
    """Levenberg-Marquardt as graph.levenberg_marquardt documents it: ``(J^T J + lambda I) dx = -J^T r``,
    a step taken when it does not raise the error (then ``lambda / 10``, at least 1e-12), else
    ``lambda x 10`` until 1e10; stop on a relative decrease below ``rel_tol`` or an error below 1e-9."""
    def cost(q):
        r = residual(q)
        return 0.5 * r @ r

    err0 = err = cost(p)
    it, n_rejected = 0, 0
    for it in range(1, max_iterations + 1):
        J, r = jacobian(p), residual(p)
        improved = False
        while lam < 1e10:
            dx = np.linalg.solve(J.T @ J + lam * np.eye(2), -J.T @ r)
            err_trial = cost(p + dx)
            if err_trial <= err:
                improved, lam = True, max(lam / 10.0, 1e-12)
                break
            lam *= 10.0
            n_rejected += 1
        if not improved:
            break
        decrease = (err - err_trial) / err
        p, err = p + dx, err_trial
        if decrease < rel_tol or err < 1e-9:
            break
    return p, it, err0, err, n_rejected


@pytest.mark.parametrize("max_iterations", [1, 2, 3, 40])
def test_levenberg_marquardt_follows_its_damping_schedule_on_rosenbrock(max_iterations):
    start = np.array([-1.2, 1.0])
    values = gtsam.Values()
    values.insert(V(0), start)
    got, it, err0, err = levenberg_marquardt(_rosenbrock_graph(), values, max_iterations=max_iterations)
    p, it_ref, err0_ref, err_ref, n_rejected = _lm_numpy(start, max_iterations, 1e-6, 1e-5)
    assert n_rejected > 0  # steps that raised the error: the damping grew
    np.testing.assert_allclose(got.atVector(V(0)), p, rtol=1e-9, atol=1e-12)
    assert it == it_ref
    assert err0 == pytest.approx(err0_ref, rel=1e-12)
    assert err == pytest.approx(err_ref, rel=1e-9, abs=1e-15)


def test_levenberg_marquardt_defaults_are_20_iterations_from_lambda_1e_5():
    # from (-1.2, 1) the valley takes more than 20 iterations: the default limit decides the result
    start = np.array([-1.2, 1.0])
    values = gtsam.Values()
    values.insert(V(0), start)
    got, it, _, err = levenberg_marquardt(_rosenbrock_graph(), values)
    p, it_ref, _, err_ref, _ = _lm_numpy(start, 20, 1e-6, 1e-5)
    assert it == it_ref == 20
    np.testing.assert_allclose(got.atVector(V(0)), p, rtol=1e-9, atol=1e-12)
    assert err == pytest.approx(err_ref, rel=1e-9)
    # and it converges to the minimum (1, 1) given the iterations
    done, _, _, _ = levenberg_marquardt(_rosenbrock_graph(), values, max_iterations=200)
    np.testing.assert_allclose(done.atVector(V(0)), [1.0, 1.0], atol=1e-3)


def _off_rosenbrock_residual(p):  # a third residual the other two contradict: the minimum error is not 0
    return np.array([10.0 * (p[1] - p[0] ** 2), 1.0 - p[0], 0.5 * (p[0] + p[1]) - 0.3])


def _off_rosenbrock_jacobian(p):
    return np.array([[-20.0 * p[0], 10.0], [-1.0, 0.0], [0.5, 0.5]])


def test_levenberg_marquardt_stops_on_a_relative_decrease_below_1e_6_by_default():
    # the minimum error is not zero, so LM stops on the relative decrease: from (-1.2, 1) one
    # iteration decreases the error by 1.4e-6, which a tolerance of 2e-6 would stop at
    def error(this, values, H):
        p = values.atVector(V(0))
        if H is not None:
            H[0] = _off_rosenbrock_jacobian(p)
        return _off_rosenbrock_residual(p)

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [V(0)], error))
    start = np.array([-1.2, 1.0])
    values = gtsam.Values()
    values.insert(V(0), start)
    got, it, _, _ = levenberg_marquardt(graph, values, max_iterations=200)
    ref = _lm_numpy(start, 200, 1e-6, 1e-5, _off_rosenbrock_residual, _off_rosenbrock_jacobian)
    assert ref[1] != _lm_numpy(start, 200, 2e-6, 1e-5, _off_rosenbrock_residual, _off_rosenbrock_jacobian)[1]
    assert it == ref[1] < 200 and ref[3] > 1e-3
    np.testing.assert_allclose(got.atVector(V(0)), ref[0], rtol=1e-9, atol=1e-12)


def test_the_lateral_factor_leaves_vx_and_omega_free_with_sigma_1e4():
    from sindy_ekf.estimation.graph import _lateral_factor
    from sindy_ekf.estimation.lateral import LateralConstraint

    lateral = LateralConstraint(vy_std_m_s=0.05, every=1)
    values = gtsam.Values()
    values.insert(V(3), np.array([3.0, 0.1, -2.0]))
    np.testing.assert_allclose(_lateral_factor(3, lateral).whitenedError(values), [3.0 / 1e4, 0.1 / 0.05, -2.0 / 1e4],
                               rtol=1e-12)


def _short_run(duration_s=6.0, seed=3):
    """A linear-Gaussian truth at 50 Hz and fixes every 0.2 s on its grid (no latency, no lever arm)."""
    model = linear_gaussian_model()
    truth = simulate_truth(model, duration_s, np.random.default_rng(seed))
    t, u = truth.t, truth.u
    k = np.arange(0, len(t), 10)
    rng = np.random.default_rng(seed + 1)
    p = np.column_stack([truth.x6[k, :2] + 0.05 * rng.standard_normal((len(k), 2)), np.zeros(len(k))])
    gnss = GnssSeries("dgnss", t[k].copy(), t[k].copy(), p, np.full((len(k), 3), 0.05),
                      np.zeros(len(k), np.uint8), np.zeros(3), np.empty((0, 2)))
    return model, truth, t, u, gnss


def _fixes(gnss, keep):
    return replace(gnss, **{f: getattr(gnss, f)[keep] for f in ("t_valid", "t_arrival", "p_local", "std", "flags")})


def test_isam2_updates_every_10_steps_by_default_and_defaults_are_huber_and_a_3_s_lag():
    model, truth, t, u, gnss = _short_run(duration_s=3.0)
    n = len(t)
    got = smooth_isam2(model, t, u, truth.x6[0], P0, gnss)
    # by hand: an update at every 10th step and at the last; its marginal is known only there
    updated = sorted(set(range(10, n, 10)) | {n - 1})
    assert got.iterations == len(updated)
    np.testing.assert_array_equal(np.flatnonzero(np.isfinite(got.P[:, 0, 0])), updated)
    explicit = smooth_isam2(model, t, u, truth.x6[0], P0, gnss, robust="huber", update_every=10, lag_s=3.0)
    np.testing.assert_array_equal(got.x, explicit.x)


@pytest.mark.parametrize("latency_s, used", [(2.3, True), (2.5, False)])
def test_isam2_drops_a_fix_arriving_later_than_0_8_of_its_default_lag(latency_s, used):
    model, truth, t, u, gnss = _short_run()
    j = 10  # the fix valid at 2 s
    late = replace(gnss, t_arrival=gnss.t_arrival.copy())
    late.t_arrival[j] = gnss.t_valid[j] + latency_s  # on the grid: 115 or 125 steps later
    late.t_arrival[j + 1:] = np.maximum(late.t_arrival[j + 1:], late.t_arrival[j])  # arrival order kept
    without = _fixes(late, np.arange(len(gnss.t_valid)) != j)
    got = smooth_isam2(model, t, u, truth.x6[0], P0, late, robust=None)
    ref = smooth_isam2(model, t, u, truth.x6[0], P0, without, robust=None)
    moved = np.abs(got.x - ref.x).max()
    if used:  # 2.3 s < 0.8 x 3 s: the fix joins the window
        assert moved > 1e-4, moved
    else:  # 2.5 s > 2.4 s: dropped, as if it never came
        assert moved < 1e-9, moved


def test_graph_takes_fixes_at_both_ends_of_the_grid_and_none_beyond_them():
    model, truth, t, u, gnss = _short_run(duration_s=2.0)
    assert gnss.t_valid[0] == t[0]
    end = replace(gnss, t_valid=np.append(gnss.t_valid, t[-1]), t_arrival=np.append(gnss.t_arrival, t[-1]),
                  p_local=np.vstack([gnss.p_local, [*truth.x6[-1, :2], 0.0]]),
                  std=np.vstack([gnss.std, gnss.std[:1]]), flags=np.append(gnss.flags, 0))
    base = smooth_batch(model, t, u, truth.x6[0], P0, end, robust=None, marginal_stride=None)
    for j, k in ((0, 0), (-1, -1)):  # a fix at the first and at the last grid time is a factor
        p = end.p_local.copy()
        p[j, 0] += 1.0
        moved = smooth_batch(model, t, u, truth.x6[0], P0, replace(end, p_local=p), robust=None,
                             marginal_stride=None)
        assert moved.x[k, 0] - base.x[k, 0] > 0.05, j
    # fixes 1.5 us beyond either end (more than the 1 us grid tolerance) are outside: left out
    beyond = replace(end, t_valid=end.t_valid.copy(), t_arrival=end.t_arrival.copy())
    beyond.t_valid[0] = beyond.t_arrival[0] = t[0] - 1.5e-6
    beyond.t_valid[-1] = beyond.t_arrival[-1] = t[-1] + 1.5e-6
    inner = _fixes(end, slice(1, -1))
    got = smooth_batch(model, t, u, truth.x6[0], P0, beyond, robust=None, marginal_stride=None)
    ref = smooth_batch(model, t, u, truth.x6[0], P0, inner, robust=None, marginal_stride=None)
    np.testing.assert_allclose(got.x, ref.x, atol=1e-9)


def test_levenberg_marquardt_gives_up_when_no_damping_up_to_1e10_lowers_the_error():
    # a factor whose Jacobian has the wrong sign: every step goes uphill, whatever the damping; by
    # hand, trials at lambda = 1e-5, 1e-4, ..., 1e9 (15 of them), none at 1e10, then the start back
    calls = []

    def error(this, values, H):
        p = values.atVector(V(0))
        if H is not None:
            H[0] = -np.eye(2)
        else:
            calls.append(p.copy())
        return p

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [V(0)], error))
    values = gtsam.Values()
    values.insert(V(0), np.array([1.0, -2.0]))
    got, it, err0, err = levenberg_marquardt(graph, values)
    np.testing.assert_array_equal(got.atVector(V(0)), [1.0, -2.0])
    assert it == 1 and err == err0 == pytest.approx(2.5)
    trials = calls[1:]  # the first evaluation is the starting error
    assert len(trials) == 15
    # the step at lambda is (1 + 1 / (1 + lambda)) times the start: the last at 1e9
    np.testing.assert_allclose(trials[-1], np.array([1.0, -2.0]) * (1.0 + 1.0 / (1.0 + 1e9)), rtol=1e-12)


def test_isam2_without_fixes_is_dead_reckoning():
    # priors and dynamics alone: the most probable trajectory is the model's own from x0
    model, truth, t, u, _ = _short_run(duration_s=1.0)
    got = smooth_isam2(model, t, u, truth.x6[0], P0, None)
    np.testing.assert_allclose(got.x, model.propagate(truth.x6[0], u, t - t[0]), atol=1e-9)


def test_without_iterations_the_smoother_returns_its_starting_trajectory():
    # no LM iteration: the starting trajectory goes into the graph's values and comes back as it
    # was (poses as x, y, heading; velocities as they are), at the error it starts from
    model, truth, t, u, gnss = _short_run(duration_s=1.0)
    x_init = truth.x6 + np.array([0.3, -0.2, 0.1, 0.05, -0.02, 0.04])  # x, y, heading all different
    got = smooth_batch(model, t, u, truth.x6[0], P0, gnss, x_init=x_init, robust=None, marginal_stride=None,
                       max_iterations=0)
    np.testing.assert_allclose(got.x, x_init, atol=1e-12)
    assert got.iterations == 0 and got.error_final == got.error_initial > 0.0


def test_smooth_batch_runs_levenberg_marquardt_with_its_defaults(monkeypatch):
    # the batch smoother's own defaults are LM's (20 iterations, stop below a relative decrease of
    # 1e-6; test_levenberg_marquardt_defaults_are_20_iterations_from_lambda_1e_5): what it hands over
    import sindy_ekf.estimation.graph as graph_module

    seen = []
    lm = graph_module.levenberg_marquardt

    def spy(graph, values, max_iterations, rel_tol):
        seen.append((max_iterations, rel_tol))
        return lm(graph, values, max_iterations, rel_tol)

    monkeypatch.setattr(graph_module, "levenberg_marquardt", spy)
    model, truth, t, u, gnss = _short_run(duration_s=1.0)
    smooth_batch(model, t, u, truth.x6[0], P0, gnss, marginal_stride=None)
    assert seen == [(20, 1e-6)]


def test_the_dynamics_factor_wraps_the_heading_error_across_plus_minus_pi():
    # from a heading of 3.13 rad turning at 0.5 rad/s the step ends past pi, where a Pose2 reads
    # heading - 2 pi: that pose at exactly the predicted state is no error at all (by hand)
    from sindy_ekf.estimation.graph import DynamicsFactors, X
    from sindy_ekf.estimation.process_models import ProcessModel
    from tests.support.estimation_helpers import PolyBody

    model = ProcessModel(PolyBody())
    u = np.array([[0.6, -0.3], [0.0, 0.0]])
    x0 = np.array([1.0, 2.0, 3.13, 0.5, 0.05, 0.5])
    pred = model.step(x0, u[0], 0.0, 0.04)
    assert pred[2] > np.pi
    factor = DynamicsFactors(model, np.array([0.0, 0.04]), u).factor(0, gtsam.noiseModel.Unit.Create(6))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose2(*x0[:3]))
    values.insert(V(0), x0[3:])
    values.insert(X(1), gtsam.Pose2(*pred[:3]))
    values.insert(V(1), pred[3:])
    assert values.atPose2(X(1)).theta() == pytest.approx(pred[2] - 2 * np.pi, abs=1e-12)
    np.testing.assert_allclose(factor.unwhitenedError(values), 0.0, atol=1e-12)


def test_marginals_at_every_step_by_default_else_at_every_stride_th_and_the_last():
    model, truth, t, u, gnss = _short_run(duration_s=0.54)  # 27 grid times
    every = smooth_batch(model, t, u, truth.x6[0], P0, gnss, robust=None)
    assert np.all(np.isfinite(every.P))
    strided = smooth_batch(model, t, u, truth.x6[0], P0, gnss, robust=None, marginal_stride=3)
    k = np.arange(len(t))
    has = np.isfinite(strided.P).all(axis=(1, 2))
    np.testing.assert_array_equal(has, (k % 3 == 0) | (k == len(t) - 1))
    assert len(t) % 3 != 1  # the last step is not on the stride: it is there of its own
    np.testing.assert_allclose(strided.P[has], every.P[has], rtol=1e-9, atol=1e-15)


def test_isam2_adds_a_fix_arriving_exactly_on_a_grid_time_at_that_step_and_1_5_us_later_at_the_next():
    # one fix valid and arriving at t_10, an update step: x[10] right after that update is, for the
    # linear-Gaussian model without robust loss (up to the Pose2 retraction's curvature, 1e-6), the
    # textbook Kalman update of the dead-reckoned
    # x_10, P_10 (the EKF's dead reckoning, a second implementation); arriving 1.5 us later (more
    # than the 1 us grid tolerance) it is added at step 11 and x[10] is dead reckoning
    from sindy_ekf.estimation.ekf import run_ekf

    model, truth, t, u, _ = _short_run(duration_s=1.0)
    dead = run_ekf(model, t, u, truth.x6[0], P0, None)
    z = dead.x[10, :2] + np.array([0.08, -0.06])
    std = 0.05

    def one_fix(t_arrival):
        return GnssSeries("dgnss", t[10:11].copy(), np.array([t_arrival]), np.array([[*z, 0.0]]),
                          np.full((1, 3), std), np.zeros(1, np.uint8), np.zeros(3), np.empty((0, 2)))

    H = np.eye(2, 6)
    P = dead.P[10]
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + std ** 2 * np.eye(2))
    on_grid = smooth_isam2(model, t, u, truth.x6[0], P0, one_fix(t[10]), robust=None)
    np.testing.assert_allclose(on_grid.x[10], dead.x[10] + K @ (z - dead.x[10, :2]), atol=1e-5)
    for b in (slice(0, 3), slice(3, 6)):  # the marginals of pose and velocity (the cross block is not kept)
        np.testing.assert_allclose(on_grid.P[10][b, b], (P - K @ H @ P)[b, b], rtol=1e-5, atol=1e-8)
    later = smooth_isam2(model, t, u, truth.x6[0], P0, one_fix(t[10] + 1.5e-6), robust=None)
    np.testing.assert_allclose(later.x[:11], dead.x[:11], atol=1e-8)
    np.testing.assert_allclose(later.x[20], on_grid.x[20], atol=1e-5)  # by step 20 both have it
