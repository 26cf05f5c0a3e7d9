"""The generated float code of the simulator's inner loop against the numpy dynamics and scipy's ODE solver."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from simulation.effects import EFFECTS, Effect
from simulation.rk4_codegen import compile_stepper
from simulation.robot import TrueDynamics
from tests.support.robot_synth import random_states

ALL_EFFECTS = [None] + [Effect(n, s.moderate) for n, s in EFFECTS.items()]


@pytest.mark.parametrize("effect", ALL_EFFECTS, ids=lambda e: e.name if e else "none")
def test_float_stepper_matches_numpy_f_and_scipy_ode(effect):
    """The generated float code equals f; its RK4 agrees with scipy's RK45 at tight tolerance."""
    dyn = TrueDynamics(effect=effect)
    integrate, acc = compile_stepper(dyn.params, effect)
    rng = np.random.default_rng(5)
    x6 = random_states(rng, 50, track_max=1.3, w_max=1.6)
    u = rng.uniform(-1, 1, (50, 2))
    a_float = np.array([acc(*s, *v) for s, v in zip(x6.tolist(), u.tolist())])
    np.testing.assert_allclose(a_float, dyn.accel(x6, u), rtol=1e-12, atol=1e-12)

    u_step, n = [0.7, -0.4], 1000
    x0 = (3.0, 2.5, 0.4, 0.2, 0.0, -0.3)
    rows: list = []
    end = integrate(0, n, x0, [u_step] * n, [0.0] * n, [0.0] * n, [0.0] * n, rows, 0.002)

    def rhs(_, s):
        c, sn = math.cos(s[2]), math.sin(s[2])
        return [s[3] * c - s[4] * sn, s[3] * sn + s[4] * c, s[5], *dyn.accel(s, u_step)]

    ref = solve_ivp(rhs, (0, 2.0), x0, rtol=1e-11, atol=1e-12).y[:, -1]
    np.testing.assert_allclose(end, ref, atol=1e-8)
    assert len(rows) == n and rows[0] == x0
