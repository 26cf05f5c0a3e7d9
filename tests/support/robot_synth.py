"""Robot states to test at, and the former per-monomial Jacobian loop as an independent reference."""

from __future__ import annotations

import numpy as np

from simulation.robot import TrueDynamics
from simulation.robot_params import RobotParams


def random_states(rng: np.random.Generator, n: int, track_max: float = 0.9, w_max: float = 1.2) -> np.ndarray:
    """Return ``(n, 6)`` states in and around the driving area; velocities inside the limiters'
    bounds (track speed ``|vx| + b |omega|`` and yaw rate) unless larger bounds are asked for."""
    omega = rng.uniform(-w_max, w_max, n)
    v_lim = track_max - RobotParams().track_half_width_m * np.abs(omega)
    return np.column_stack([rng.uniform(0.5, 6.5, n), rng.uniform(0.5, 5.5, n),
                            rng.uniform(-4, 4, n), rng.uniform(-1, 1, n) * v_lim,
                            rng.uniform(-0.08, 0.08, n), omega])


def loop_poly_jacobian(dyn: TrueDynamics, z: np.ndarray) -> np.ndarray:
    """Return d(poly)/d[vx, vy, omega, u1, u2] by the previous implementation (a Python loop
    over equations, monomials and variables), the independent reference."""
    powers = np.stack([np.ones_like(z), z, z * z, z * z * z], axis=-1)
    J = np.zeros(z.shape[:-1] + (3, 5))
    for row, eq in enumerate(dyn._eqs):
        for c, ex in eq:
            for v in np.flatnonzero(ex):
                e = ex.copy()
                e[v] -= 1
                J[..., row, v] += c * ex[v] * np.prod(powers[..., np.arange(5), e], axis=-1)
    return J
