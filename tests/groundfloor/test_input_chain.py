"""The motor's view of the recorded inputs (groundfloor.input_chain) against an ODE solver."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from groundfloor.input_chain import chain_inputs, first_order_lag, first_order_lags


def _reference(t_query, t, u, dead_s, lag_s):
    """Return ``T w' = u(t) - w`` by RK45 at tight tolerances, delayed by ``dead_s``."""
    sol = solve_ivp(lambda tt, w: (np.interp(tt, t, u) - w) / lag_s, (t[0], t[-1]), [u[0]], dense_output=True,
                    rtol=1e-10, atol=1e-12, max_step=0.002)
    q = t_query - dead_s
    return np.where(q <= t[0], u[0], sol.sol(np.clip(q, t[0], t[-1]))[0])


@pytest.mark.parametrize("lag_s, dead_s", [((0.2, 0.07), (0.05, 0.1)), ((0.5, 0.01), (0.0, 0.0))])
def test_lagged_and_delayed_inputs_equal_the_ode_solution(lag_s, dead_s):
    t = np.arange(0.0, 10.0, 0.01)
    u = np.column_stack([np.sin(1.3 * t) + (t > 3.0) * 0.5, np.cos(2.0 * t) * (t < 7.0)])
    tq = np.linspace(0.0, 10.0, 333)
    w = chain_inputs(tq, t, u, dead_s, lag_s)
    for i in range(2):
        np.testing.assert_allclose(w[:, i], _reference(tq, t, u[:, i], dead_s[i], lag_s[i]), atol=2e-3)


def test_a_step_rises_by_one_minus_one_over_e_in_one_time_constant():
    h, T = 0.01, 0.25
    u = np.zeros((201, 2))
    u[1:, :] = 1.0  # a step (linear over the first step)
    w = first_order_lag(u, h, (T, 0.0))
    k = int(round(T / h))
    # the exact response of the ramp-then-step: 1 - (T / h)(1 - e^-h/T) e^-(t - h)/T after the ramp
    expected = 1.0 - (T / h) * (1.0 - np.exp(-h / T)) * np.exp(-(k * h - h) / T)
    assert w[k, 0] == pytest.approx(expected, rel=1e-9)
    assert w[k, 0] == pytest.approx(1.0 - np.exp(-1.0), abs=0.03)
    np.testing.assert_array_equal(w[:, 1], u[:, 1])  # no lag: unchanged


def test_no_lag_is_a_pure_shift_and_the_lag_starts_at_rest():
    t = np.linspace(0.0, 5.0, 251)
    u = np.column_stack([2.0 + np.sin(t), -1.0 + 0.0 * t])
    np.testing.assert_allclose(chain_inputs(t, t, u, (0.2, 0.0)), np.column_stack(
        [np.interp(t - 0.2, t, u[:, 0]), u[:, 1]]), atol=1e-12)
    w = chain_inputs(t, t, u, (0.0, 0.0), (0.3, 0.3))
    assert w[0, 0] == pytest.approx(2.0) and np.allclose(w[:, 1], -1.0)


@pytest.mark.parametrize("k", [1, 3, 4, 6, 9])
def test_lags_side_by_side_equal_the_ode_solution_and_one_recursion_at_a_time(k):
    """Groups of four with a short last group (k = 1, 3, 6, 9) and rows repeated, a zero lag among them."""
    h = 0.01
    t = np.arange(0.0, 6.0, h)
    u = np.vstack([np.sin(1.3 * t) + (t > 2.0) * 0.5, np.cos(2.0 * t) * (t < 4.0), np.sign(np.sin(0.7 * t))])
    rows = [(0, 2, 1)[j % 3] for j in range(k)]
    lags = [0.0 if j == 1 else 0.05 + 0.04 * j for j in range(k)]
    w = first_order_lags(u, h, rows, lags)
    assert w.shape == (k, len(t))
    for j, (r, T) in enumerate(zip(rows, lags)):
        if T == 0.0:
            np.testing.assert_array_equal(w[j], u[r])
            continue
        # the recursion written out, one sample at a time (the same arithmetic, so the same bits)
        a = float(np.exp(-h / T))
        c = T * (1.0 - a) / h
        ref = np.empty(len(t))
        ref[0] = u[r, 0]
        for n in range(len(t) - 1):
            ref[n + 1] = a * ref[n] + (1.0 - c) * u[r, n + 1] + (c - a) * u[r, n]
        np.testing.assert_array_equal(w[j], ref)
        np.testing.assert_allclose(w[j], _reference(t, t, u[r], 0.0, T), atol=2e-3)
