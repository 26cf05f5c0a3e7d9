"""Process noise from one-step residuals (process_models.fit_process_noise) by hand: series built
as the model's own step plus known residuals on uneven steps, so ``Q_rate`` is the mean of
``r r^T / dt`` plus the documented floor (1e-3 per sqrt-second) squared."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from sindy_ekf.estimation.process_models import (
    ProcessModel,
    StateSeries,
    fit_process_noise,
    one_step_residuals,
)
from tests.support.estimation_helpers import PolyBody


def _series(model: ProcessModel, name: str, seed: int, n: int = 200):
    rng = np.random.default_rng(seed)
    t = 50.0 + np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.03, n - 1))])  # uneven steps
    u = np.column_stack([np.sin(0.3 * t), np.cos(0.2 * t)])
    r = rng.normal(0.0, 1e-3, (n - 1, 6)) * np.array([1.0, 2.0, 0.5, 3.0, 1.0, 2.0])
    x = np.empty((n, 6))
    x[0] = [1.0, -1.0, 0.3, 0.4, 0.0, 0.1]
    for k in range(n - 1):
        x[k + 1] = model.step(x[k], u[k], t[k] - t[0], t[k + 1] - t[k]) + r[k]
    return StateSeries(name, t, x, u), r, np.diff(t)


def test_q_rate_is_the_mean_of_r_rt_over_dt_plus_the_floor():
    model = ProcessModel(PolyBody(), name="poly")
    (a, r_a, dt_a), (b, r_b, dt_b) = _series(model, "a", 1), _series(model, "b", 2, n=120)
    r, dt = np.vstack([r_a, r_b]), np.concatenate([dt_a, dt_b])
    got_r, got_dt = one_step_residuals(model, [a, b])
    np.testing.assert_allclose(got_r, r, atol=1e-12)
    np.testing.assert_allclose(got_dt, dt, rtol=1e-12)
    expected = sum(np.outer(ri, ri) / di for ri, di in zip(r, dt)) / len(r) + 1e-3 ** 2 * np.eye(6)
    fitted = fit_process_noise(model, [a, b])
    np.testing.assert_allclose(fitted.Q_rate_, expected, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(fitted.residual_std_, np.sqrt(np.mean(r ** 2, axis=0)), rtol=1e-9)
    # the floor alone on a model exact on its own data
    exact, _, _ = _series(model, "exact", 3, n=50)
    x = exact.x6.copy()
    for k in range(49):  # rebuilt by the model's own step: every residual is zero
        x[k + 1] = model.step(x[k], exact.u[k], exact.t[k] - exact.t[0], exact.t[k + 1] - exact.t[k])
    q = fit_process_noise(model, [StateSeries("exact", exact.t, x, exact.u)], floor_std=0.05).Q_rate_
    np.testing.assert_allclose(q, 0.05 ** 2 * np.eye(6), atol=1e-20)


def test_times_not_increasing_name_the_run_they_are_in():
    model = ProcessModel(PolyBody(), name="poly")
    good, _, _ = _series(model, "good_run", 1, n=30)
    bad, _, _ = _series(model, "bad_run", 2, n=30)
    t = bad.t.copy()
    t[10] = t[9]
    with pytest.raises(InputError, match="run bad_run: state times are not strictly increasing"):
        one_step_residuals(model, [good, StateSeries("bad_run", t, bad.x6, bad.u)])


class _ForcedBody(PolyBody):
    """PolyBody plus a forward acceleration ``0.5 cos(2 t)`` in seconds since the run's start."""

    def accel_and_jacobians(self, x6, u, t=0.0):
        f, J_x, J_u = super().accel_and_jacobians(x6, u, t)
        f = f.copy()
        f[..., 0] += 0.5 * np.cos(2.0 * np.asarray(t, float))
        return f, J_x, J_u


def test_residuals_of_a_time_dependent_model_use_time_since_each_runs_start():
    model = ProcessModel(_ForcedBody(), name="forced")
    # series built by the model's own step at the time since its start: every residual is zero
    a, _, _ = _series(model, "a", 4, n=60)
    b, _, _ = _series(model, "b", 5, n=40)
    exact = []
    for s in (a, b):
        x = s.x6.copy()
        for k in range(len(s.t) - 1):
            x[k + 1] = model.step(x[k], s.u[k], s.t[k] - s.t[0], s.t[k + 1] - s.t[k])
        exact.append(StateSeries(s.name, s.t, x, s.u))
    r, _ = one_step_residuals(model, exact)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)


def test_heading_residuals_are_wrapped_to_minus_pi_pi():
    model = ProcessModel(PolyBody(), name="poly")
    s, r_true, _ = _series(model, "a", 6, n=40)
    x = s.x6.copy()
    x[20:, 2] += 2.0 * np.pi  # one turn added from sample 20 on: the same headings
    x[30:, 2] -= 6.0 * np.pi
    r, _ = one_step_residuals(model, [StateSeries("a", s.t, x, s.u)])
    np.testing.assert_allclose(r, r_true, atol=1e-9)
    # a residual of 3.5 rad is -2.78 rad (by hand: 3.5 - 2 pi)
    y = s.x6.copy()
    y[10, 2] = model.step(y[9], s.u[9], s.t[9] - s.t[0], s.t[10] - s.t[9])[2] + 3.5
    r, _ = one_step_residuals(model, [StateSeries("a", s.t, y, s.u)])
    assert r[9, 2] == pytest.approx(3.5 - 2.0 * np.pi, abs=1e-12)


def test_step_of_a_time_dependent_model_is_classical_rk4_with_stage_times_t_t_half_t_half_t_plus_h():
    model = ProcessModel(_ForcedBody(), name="forced")
    f = model.dynamics.derivative
    x = np.array([[1.0, -1.0, 0.3, 0.4, 0.05, 0.1], [0.0, 2.0, -2.0, -0.2, 0.0, 0.4]])
    u = np.array([[0.5, -0.2], [0.1, 0.3]])
    t, h = np.array([0.7, 2.1]), np.array([0.05, 0.2])
    k1 = f(x, u, t)
    k2 = f(x + h[:, None] / 2 * k1, u, t + h / 2)
    k3 = f(x + h[:, None] / 2 * k2, u, t + h / 2)
    k4 = f(x + h[:, None] * k3, u, t + h)
    np.testing.assert_allclose(model.step(x, u, t, h), x + h[:, None] / 6 * (k1 + 2 * k2 + 2 * k3 + k4),
                               rtol=1e-13, atol=1e-14)


class _NoInputChainAttributes:
    """Dynamics that are no :class:`groundfloor.dynamics.Dynamics` and have neither ``dead_time_s``
    nor ``input_lag_s``: they see the recorded inputs as they are. ``x' = vx``, ``vx' = u1``,
    ``psi' = omega``, ``omega' = u2``."""

    name = "no_input_chain_attributes"

    def derivative(self, x6, u, t=0.0):
        f = np.zeros(np.shape(x6))
        f[..., 0] = x6[..., 3]
        f[..., 2] = x6[..., 5]
        f[..., 3] = u[..., 0]
        f[..., 5] = u[..., 1]
        return f


def test_residuals_of_dynamics_without_dead_time_or_lag_attributes_use_the_recorded_inputs():
    # by hand, the inputs held over each (uneven) step: vx gains u1 dt and x gains vx dt + u1 dt^2 / 2
    # (exact, and exact for RK4), omega and psi likewise with u2; the inputs vary, so a dead time or a
    # lag of either would leave residuals
    rng = np.random.default_rng(4)
    t = 20.0 + np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.03, 149))])
    u = np.column_stack([np.sin(2.0 * t), np.cos(1.5 * t)])
    x = np.zeros((len(t), 6))
    x[0, 3], x[0, 5] = 0.5, -0.2
    for k, dt in enumerate(np.diff(t)):
        for pos, vel, i in ((0, 3, 0), (2, 5, 1)):
            x[k + 1, vel] = x[k, vel] + u[k, i] * dt
            x[k + 1, pos] = x[k, pos] + x[k, vel] * dt + u[k, i] * dt ** 2 / 2
    r, dt = one_step_residuals(ProcessModel(_NoInputChainAttributes()), [StateSeries("held", t, x, u)])
    np.testing.assert_allclose(dt, np.diff(t), rtol=1e-15)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
