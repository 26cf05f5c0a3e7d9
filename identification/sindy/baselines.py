"""Baseline motion models the identified model must beat, as :class:`groundfloor.dynamics.Dynamics`.

- :class:`UnicycleModel`: kinematic, the pose moves with the velocities the inputs command,
  ``[k1 u1, 0, k2 u2]``, with the gains fitted by least squares on the training runs (the data
  README's unicycle); its velocity states play no part (accelerations 0).
- :class:`LagModel`: first-order lag of ``vx`` toward ``k_v u1`` and of ``omega`` toward
  ``k_w u2``, ``vy`` decaying; gains and time constants fitted on one-step differences.
- :class:`ConstantVelocityModel`: zero accelerations, keeps the initial body velocities.

All three plug into the multi-step evaluation and, through
``sindy_ekf.estimation.process_models.ProcessModel``, into the filters, like the SINDy model.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from groundfloor.dynamics import N_U, N_X, Dynamics
from groundfloor.errors import InputError
from groundfloor.types import BodyStates


def _zero_accel(x6: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return zero accelerations ``(..., 3)`` and zero Jacobians ``(..., 3, 6)``, ``(..., 3, 2)``."""
    lead = np.shape(x6)[:-1]
    return np.zeros(lead + (3,)), np.zeros(lead + (3, N_X)), np.zeros(lead + (3, N_U))


class UnicycleModel(Dynamics):
    """Kinematic unicycle: the pose moves with ``[k1 u1, 0, k2 u2]``, accelerations are zero.

    Follows the scikit-learn contract: ``fit`` returns ``self``; ``k1_``, ``k2_`` are the gains.
    """

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

    def accel_and_jacobians(self, x6, u, t=0.0):
        """Return zero accelerations and Jacobians: the velocity states play no part."""
        return _zero_accel(x6)

    def accel(self, x6, u, t=0.0):
        """Return zero accelerations ``(..., 3)``."""
        return np.zeros(np.shape(x6)[:-1] + (3,))

    def pose_velocity_and_jacobians(self, x6, u):
        """Return the commanded body velocities ``[k1 u1, 0, k2 u2]`` ``(..., 3)`` and their Jacobians."""
        u = np.asarray(u, dtype=float)
        lead = np.broadcast_shapes(np.shape(x6)[:-1], u.shape[:-1])
        u = np.broadcast_to(u, lead + (N_U,))
        v = np.stack([self.k1_ * u[..., 0], np.zeros(lead), self.k2_ * u[..., 1]], axis=-1)
        J_v_u = np.zeros(lead + (3, N_U))
        J_v_u[..., 0, 0], J_v_u[..., 2, 1] = self.k1_, self.k2_
        return v, np.zeros(lead + (3, N_X)), J_v_u


class LagModel(Dynamics):
    """First-order actuator lag per axis, no lateral slip.

    ``vx -> k_v u1`` and ``omega -> k_w u2`` with time constants ``tau_v``, ``tau_w``; ``vy``
    decays to zero with ``tau_v``. Follows the scikit-learn contract: ``fit`` returns ``self``;
    ``k_v_, tau_v_, k_w_, tau_w_`` are the fitted values (or the given ones).
    """

    name = "lag"

    def __init__(self, k_v: float | None = None, tau_v: float | None = None, k_w: float | None = None,
                 tau_w: float | None = None):
        self.k_v, self.tau_v, self.k_w, self.tau_w = k_v, tau_v, k_w, tau_w
        if None not in (k_v, tau_v, k_w, tau_w):
            self.k_v_, self.tau_v_, self.k_w_, self.tau_w_ = float(k_v), float(tau_v), float(k_w), float(tau_w)

    def fit(self, states: Sequence[BodyStates]) -> "LagModel":
        """Fit gains and lags on one-step differences of the training runs; return self.

        Forward differences of the body velocities against the input held over the step and the
        velocity at the step's midpoint (trapezoidal, second order, any step length): for each
        axis a least-squares fit of ``(v_{k+1} - v_k) / dt = b u_k - c (v_k + v_{k+1}) / 2`` gives
        ``k = b / c`` and ``tau = 1 / c``.

        Raises
        ------
        InputError
            If an axis shows no lag to fit (too little excitation).
        """
        def fit_axis(v: np.ndarray, u: np.ndarray, a: np.ndarray, axis: str) -> tuple[float, float]:
            coef, *_ = np.linalg.lstsq(np.column_stack([u, -v]), a, rcond=None)
            b, c = coef
            if c <= 0 or not np.isfinite(c):
                raise InputError(f"train runs: lag fit of {axis} is unstable (no lag to fit); "
                                 "the train runs hold too little excitation")
            return float(b / c), float(1.0 / c)

        dt = np.concatenate([np.diff(s.t) for s in states])[:, None]
        v0 = np.concatenate([s.state[:-1] for s in states])
        v1 = np.concatenate([s.state[1:] for s in states])
        u = np.concatenate([s.inputs[:-1] for s in states])
        acc = (v1 - v0) / dt
        v_mid = 0.5 * (v0 + v1)
        self.k_v_, self.tau_v_ = fit_axis(v_mid[:, 0], u[:, 0], acc[:, 0], "vx")
        self.k_w_, self.tau_w_ = fit_axis(v_mid[:, 2], u[:, 1], acc[:, 2], "omega")
        return self

    def accel_and_jacobians(self, x6, u, t=0.0):
        """Return the lagged accelerations ``(..., 3)`` and their constant Jacobians."""
        x6 = np.asarray(x6, dtype=float)
        lead = x6.shape[:-1]
        u = np.broadcast_to(u, lead + (N_U,))
        a = np.stack([(self.k_v_ * u[..., 0] - x6[..., 3]) / self.tau_v_,
                      -x6[..., 4] / self.tau_v_,
                      (self.k_w_ * u[..., 1] - x6[..., 5]) / self.tau_w_], axis=-1)
        J_x = np.zeros(lead + (3, N_X))
        J_x[..., 0, 3] = J_x[..., 1, 4] = -1.0 / self.tau_v_
        J_x[..., 2, 5] = -1.0 / self.tau_w_
        J_u = np.zeros(lead + (3, N_U))
        J_u[..., 0, 0] = self.k_v_ / self.tau_v_
        J_u[..., 2, 1] = self.k_w_ / self.tau_w_
        return a, J_x, J_u


class ConstantVelocityModel(Dynamics):
    """Body velocities stay at their initial values: zero accelerations."""

    name = "constant_velocity"

    def accel_and_jacobians(self, x6, u, t=0.0):
        """Return zero accelerations and zero Jacobians."""
        return _zero_accel(x6)

    def accel(self, x6, u, t=0.0):
        """Return zero accelerations ``(..., 3)``."""
        return np.zeros(np.shape(x6)[:-1] + (3,))
