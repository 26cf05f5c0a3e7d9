"""Baseline motion models the identified model must beat in the multi-step evaluation.

- :class:`UnicycleModel`: kinematic, the velocities follow the inputs instantly,
  ``vx = k1 u1``, ``vy = 0``, ``omega = k2 u2``, with the gains fitted by least squares on the
  training runs.
- :class:`ConstantVelocityModel`: ``f = 0``, keeps the initial body velocities.

Both plug into :func:`identification.sindy.evaluate.evaluate_model` like a SINDy model.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from groundfloor.errors import InputError
from groundfloor.types import BodyStates


class UnicycleModel:
    """Kinematic unicycle: body velocities ``[k1 u1, 0, k2 u2]`` (``kinematic = True``).

    Follows the scikit-learn contract: ``fit`` returns ``self``; ``k1_``, ``k2_`` are the gains.
    """

    kinematic = True
    name = "unicycle"

    def __init__(self, k1: float | None = None, k2: float | None = None):
        self.k1 = k1
        self.k2 = k2
        if k1 is not None and k2 is not None:
            self.k1_, self.k2_ = float(k1), float(k2)

    def fit(self, states: Sequence[BodyStates]) -> "UnicycleModel":
        """Fit ``vx ~ k1 u1`` and ``omega ~ k2 u2`` by least squares over all samples; return self."""
        u1 = np.concatenate([s.u1 for s in states])
        u2 = np.concatenate([s.u2 for s in states])
        vx = np.concatenate([s.vx for s in states])
        om = np.concatenate([s.omega for s in states])
        for name, u in (("u1", u1), ("u2", u2)):
            if not np.any(np.abs(u) > 1e-6):
                raise InputError(f"unicycle fit: input {name} is zero in all training runs")
        self.k1_ = float(u1 @ vx / (u1 @ u1))
        self.k2_ = float(u2 @ om / (u2 @ u2))
        return self

    def velocities(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return body velocities ``(..., 3)`` commanded by the inputs ``u (..., 2)``."""
        u = np.asarray(u, dtype=float)
        lead = np.broadcast_shapes(np.shape(x)[:-1], u.shape[:-1])
        u = np.broadcast_to(u, lead + (2,))
        return np.stack([self.k1_ * u[..., 0], np.zeros(lead), self.k2_ * u[..., 1]], axis=-1)


class ConstantVelocityModel:
    """Body velocities stay at their initial values: ``f(x, u) = 0``."""

    kinematic = False
    name = "constant_velocity"

    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return zero body accelerations ``(..., 3)``."""
        lead = np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1])
        return np.zeros(lead + (3,))

    def J_f_x(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the zero Jacobian ``(..., 3, 3)``."""
        return np.zeros(np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1]) + (3, 3))

    def J_f_u(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the zero Jacobian ``(..., 3, 2)``."""
        return np.zeros(np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1]) + (3, 2))
