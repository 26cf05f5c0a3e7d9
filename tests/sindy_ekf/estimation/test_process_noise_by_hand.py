"""Process noise from one-step residuals (process_models.fit_process_noise) by hand: series built
as the model's own step plus known residuals on uneven steps, so ``Q_rate`` is the mean of
``r r^T / dt`` plus the documented floor (1e-3 per sqrt-second) squared."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from sindy_ekf.estimation.process_models import ProcessModel, StateSeries, fit_process_noise, one_step_residuals
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
