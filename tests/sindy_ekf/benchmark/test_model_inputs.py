"""What the filters feed a model with a dead time and an input lag (benchmark.run.held_inputs_for),
against the same motor written as an ODE on the held command messages."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from identification.sindy.baselines import LagModel
from sindy_ekf.benchmark.run import held_inputs_for


def _held(t_msg, u_msg, t):
    k = np.clip(np.searchsorted(t_msg, t, side="right") - 1, 0, len(t_msg) - 1)
    return u_msg[k]


def test_held_messages_through_a_lag_and_a_dead_time_equal_the_ode():
    rng = np.random.default_rng(3)
    t_msg = np.arange(0.0, 20.0, 0.05)
    u_msg = np.column_stack([np.cumsum(rng.normal(0, 0.1, len(t_msg))), np.sign(np.sin(0.7 * t_msg))])
    grid = np.arange(2.0, 19.0, 0.02)
    model = LagModel(1.0, 0.3, 1.0, 0.3, dead_time_s=(0.1, 0.04))
    model.input_lag_s = (0.2, 0.08)
    got = held_inputs_for(model, t_msg, u_msg, grid)
    for i in range(2):
        T, d = model.input_lag_s[i], model.dead_time_s[i]
        sol = solve_ivp(lambda tt, w: (_held(t_msg, u_msg[:, i], np.array([tt]))[0] - w) / T, (0.0, 20.0),
                        [u_msg[0, i]], dense_output=True, max_step=0.002, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(got[:, i], sol.sol(grid - d)[0], atol=0.015 * np.ptp(u_msg[:, i]))
    no_lag = LagModel(1.0, 0.3, 1.0, 0.3, dead_time_s=(0.1, 0.04))
    np.testing.assert_array_equal(held_inputs_for(no_lag, t_msg, u_msg, grid)[:, 1],
                                  _held(t_msg, u_msg[:, 1], grid - 0.04 + 1e-9))
