"""Baseline motion models the identified model must beat, as :class:`groundfloor.dynamics.Dynamics`.

- :class:`UnicycleModel`: kinematic, the pose moves with the velocities the inputs command,
  ``[k1 u1, 0, k2 u2]``, with the gains fitted by least squares on the training runs (the data
  README's unicycle); its velocity states play no part (accelerations 0).
- :class:`LagModel`: first-order lag of ``vx`` toward ``k_v u1`` and of ``omega`` toward
  ``k_w u2``, ``vy`` decaying, each input seen after a dead time: the hand-written model a user
  writes in twenty lines (a DRIVE-style lag), six parameters. ``fit`` estimates gains and time
  constants on one-step differences; :func:`fit_lag` refines them and the dead times by output
  error on the train runs' reference windows (:mod:`identification.sindy.output_error`), which
  is how the package's ``lag`` baseline is made.
- :class:`ConstantVelocityModel`: zero accelerations, keeps the initial body velocities.

All three plug into the multi-step evaluation and, through
``sindy_ekf.estimation.process_models.ProcessModel``, into the filters, like the SINDy model.
"""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np

from groundfloor.dynamics import N_U, N_X, Dynamics
from groundfloor.types import BodyStates, TrajectoryRun
from identification.sindy.evaluate import Windows, errors_from_rollout, rollout
from identification.sindy.output_error import (
    OE_DT,
    OE_MAX_WINDOWS,
    OE_WINDOW_S,
    OutputErrorFit,
    ParametricModel,
    fit_output_error,
)
from identification.sindy.reference import Reference, reference, thin_windows

log = logging.getLogger(__name__)


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
        """Fit ``vx ~ k1 u1`` and ``omega ~ k2 u2`` by least squares over all samples; return self.

        An input that is zero throughout gets gain 0 (with a warning)."""
        u1 = np.concatenate([s.u1 for s in states])
        u2 = np.concatenate([s.u2 for s in states])
        vx = np.concatenate([s.vx for s in states])
        om = np.concatenate([s.omega for s in states])
        for name, u in (("u1", u1), ("u2", u2)):
            if not np.any(np.abs(u) > 1e-6):
                log.warning("unicycle fit: input %s is zero in all training runs; its gain is 0", name)
        self.k1_ = float(u1 @ vx / (u1 @ u1)) if np.any(np.abs(u1) > 1e-6) else 0.0
        self.k2_ = float(u2 @ om / (u2 @ u2)) if np.any(np.abs(u2) > 1e-6) else 0.0
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
    """First-order actuator lag per axis with input dead time, no lateral slip.

    ``vx' = (k_v u1(t - d1) - vx) / tau_v``, ``omega' = (k_w u2(t - d2) - omega) / tau_w``, ``vy``
    decays with ``tau_v``. Follows the scikit-learn contract: ``fit`` returns ``self``;
    ``k_v_, tau_v_, k_w_, tau_w_`` are the fitted values (or the given ones), ``dead_time_s``
    the dead times ``(d1, d2)`` and ``fit_`` the output-error fit when there was one.
    """

    name = "lag"

    def __init__(self, k_v: float | None = None, tau_v: float | None = None, k_w: float | None = None,
                 tau_w: float | None = None, dead_time_s=(0.0, 0.0)):
        self.k_v, self.tau_v, self.k_w, self.tau_w = k_v, tau_v, k_w, tau_w
        self.dead_time_s = tuple(float(d) for d in dead_time_s)
        self.fit_: OutputErrorFit | None = None
        if None not in (k_v, tau_v, k_w, tau_w):
            self.k_v_, self.tau_v_, self.k_w_, self.tau_w_ = float(k_v), float(tau_v), float(k_w), float(tau_w)

    @property
    def params(self) -> np.ndarray:
        """Return ``[k_v, tau_v, k_w, tau_w]``."""
        return np.array([self.k_v_, self.tau_v_, self.k_w_, self.tau_w_])

    def to_dict(self) -> dict:
        """Return the parameters as a JSON-ready dict (with standard deviations after an output-error fit)."""
        out = {"k_v": self.k_v_, "tau_v_s": self.tau_v_, "k_w": self.k_w_, "tau_w_s": self.tau_w_,
               "dead_time_s": list(self.dead_time_s)}
        if self.fit_ is not None:
            out["std"] = dict(zip(("k_v", "tau_v_s", "k_w", "tau_w_s", "d1_s", "d2_s"), map(float, self.fit_.std)))
            out["rms_pos_m"] = self.fit_.rms_pos_m
        return out

    def fit(self, states: Sequence[BodyStates]) -> "LagModel":
        """Fit gains and lags on one-step differences of the training runs; return self.

        Forward differences of the body velocities against the input held over the step and the
        velocity at the step's midpoint (trapezoidal, second order, any step length): for each
        axis a least-squares fit of ``(v_{k+1} - v_k) / dt = b u_k - c (v_k + v_{k+1}) / 2`` gives
        ``k = b / c`` and ``tau = 1 / c``. The dead times are left as they are.

        An axis that shows no lag to fit (too little excitation) gets gain 0 and a time
        constant of 1 s, with a warning.
        """
        def fit_axis(v: np.ndarray, u: np.ndarray, a: np.ndarray, axis: str) -> tuple[float, float]:
            coef, *_ = np.linalg.lstsq(np.column_stack([u, -v]), a, rcond=None)
            b, c = coef
            if c <= 0 or not np.isfinite(c):
                log.warning("train runs: no lag of %s to fit (too little excitation); gain 0, time constant 1 s",
                            axis)
                return 0.0, 1.0
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

    def fit_output_error(self, windows: Windows, fit_dead_time: bool = True) -> "LagModel":
        """Refine the parameters (and dead times) by output error on ``windows``; return self.

        Starts from the current parameters (:meth:`fit` first) and dead times.
        """
        spec = LagParameters()
        theta0 = np.clip(self.params, spec.lower * 1.0001, spec.upper * 0.9999)
        self.fit_ = fit_output_error(spec, theta0, windows, self.dead_time_s, fit_dead_time)
        self.k_v_, self.tau_v_, self.k_w_, self.tau_w_ = map(float, self.fit_.theta)
        self.dead_time_s = self.fit_.dead_time_s
        return self

    def accel_and_jacobians(self, x6, u, t=0.0):
        """Return the lagged accelerations ``(..., 3)`` and their constant Jacobians."""
        x6 = np.asarray(x6, dtype=float)
        lead = np.broadcast_shapes(x6.shape[:-1], np.shape(u)[:-1])
        x6 = np.broadcast_to(x6, lead + (N_X,))
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


class LagParameters(ParametricModel):
    """:class:`LagModel`'s ``[k_v, tau_v, k_w, tau_w]`` as parameters for output-error fitting."""

    names = ("k_v", "tau_v_s", "k_w", "tau_w_s")
    lower = np.array([-np.inf, 0.005, -np.inf, 0.005])  # time constants positive (at least 5 ms)
    upper = np.array([np.inf, 100.0, np.inf, 100.0])

    def build(self, theta, dead_time_s, input_lag_s=(0.0, 0.0)) -> LagModel:
        model = LagModel(*map(float, theta), dead_time_s=dead_time_s)
        model.input_lag_s = tuple(float(v) for v in input_lag_s)  # the hand-written baseline fits none
        return model

    def accel_param_jacobian(self, dynamics: LagModel, x6, u):
        x6 = np.asarray(x6, dtype=float)
        u = np.broadcast_to(u, x6.shape[:-1] + (N_U,))
        k_v, tau_v, k_w, tau_w = dynamics.params
        J = np.zeros(x6.shape[:-1] + (3, 4))
        J[..., 0, 0] = u[..., 0] / tau_v
        J[..., 0, 1] = -(k_v * u[..., 0] - x6[..., 3]) / tau_v**2
        J[..., 1, 1] = x6[..., 4] / tau_v**2
        J[..., 2, 2] = u[..., 1] / tau_w
        J[..., 2, 3] = -(k_w * u[..., 1] - x6[..., 5]) / tau_w**2
        return J


#: dead times tried before the output-error fit (it is local; the cost is not convex in them)
DEAD_TIME_GRID_S = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5)


def best_dead_time(model: Dynamics, windows: Windows, grid=DEAD_TIME_GRID_S) -> tuple[float, float]:
    """Return the dead time of ``grid`` (the same for both inputs) with the smallest pose error of ``model``."""
    sse = []
    for d in grid:
        model.dead_time_s = (d, d)
        eps_p, eps_h = errors_from_rollout(rollout(model, windows), windows)
        sse.append(float(np.sum(eps_p**2) + np.sum(eps_h**2)))
    d = grid[int(np.argmin(sse))]
    return (d, d)


def fit_lag(runs: Sequence[TrajectoryRun] | Reference) -> LagModel:
    """Return the ``lag`` baseline fitted on train runs (or on their :class:`Reference`).

    One-step fit on the reference states, the best dead time of :data:`DEAD_TIME_GRID_S`, then
    output error on non-overlapping :data:`~identification.sindy.output_error.OE_WINDOW_S`
    windows of the reference (:meth:`LagModel.fit_output_error`).
    """
    ref = runs if isinstance(runs, Reference) else reference(runs)
    windows = thin_windows(ref.windows(OE_WINDOW_S, 0.0, OE_DT), OE_MAX_WINDOWS)
    lag = LagModel().fit(ref.states)
    lag.dead_time_s = best_dead_time(lag, windows)
    return lag.fit_output_error(windows)


class ConstantVelocityModel(Dynamics):
    """Body velocities stay at their initial values: zero accelerations."""

    name = "constant_velocity"

    def accel_and_jacobians(self, x6, u, t=0.0):
        """Return zero accelerations and zero Jacobians."""
        return _zero_accel(x6)

    def accel(self, x6, u, t=0.0):
        """Return zero accelerations ``(..., 3)``."""
        return np.zeros(np.shape(x6)[:-1] + (3,))
