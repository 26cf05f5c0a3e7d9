"""The process model of the filters: any dynamics, discretised by RK4 with an exact Jacobian.

State ``x = [x, y, psi, vx, vy, omega]`` (eq. 5.60, :data:`groundfloor.dynamics.STATE_NAMES`),
input ``u = [u1, u2]``. :class:`ProcessModel` wraps any :class:`groundfloor.dynamics.Dynamics`
(the identified ``identification.sindy.model.SindyModel``, the baselines of
``identification.sindy.baselines``, the simulator's ``simulation.robot.TrueDynamics``, the
diagnosis's extended model): :meth:`ProcessModel.step` integrates one step of length ``dt``
with the classical Runge-Kutta scheme of eqs. 5.70 and 5.71 (the input held constant over the
step) on the dynamics' six-state derivative (eq. 5.75) and differentiates that step exactly by
the chain rule through the four stages, so the EKF and the factor graph linearise the very map
they propagate with. Process noise comes from :func:`fit_process_noise` (one-step residuals on
the train runs), never by hand.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from groundfloor.dynamics import N_U, N_X, Dynamics
from groundfloor.errors import InputError
from groundfloor.types import BodyStates

log = logging.getLogger(__name__)

__all__ = ["N_X", "N_U", "ProcessModel", "StateSeries", "fit_process_noise", "one_step_residuals",
           "state_series_from_body_states", "body_states_from_state_series"]


class ProcessModel:
    """A dynamics model discretised for the filters: RK4 step, exact step Jacobian, process noise.

    Parameters
    ----------
    dynamics : Dynamics
        The continuous six-state dynamics.
    name : str, optional
        Name in logs and error messages (default: the dynamics' name).

    Attributes set by :func:`fit_process_noise`: ``Q_rate_`` (6, 6), the process-noise density
    per second, so that ``Q(dt) = Q_rate_ * dt``, and ``residual_std_`` (6,).
    """

    Q_rate_: np.ndarray | None = None

    def __init__(self, dynamics: Dynamics, name: str | None = None):
        self.dynamics = dynamics
        self.name = name or dynamics.name

    def f(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the continuous state derivative ``(..., 6)`` (eq. 5.75)."""
        return self.dynamics.derivative(x6, u, t)

    def in_envelope(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return True where ``(x6, u)`` lies where the dynamics may be trusted."""
        return self.dynamics.in_envelope(x6, u)

    def step(self, x6: np.ndarray, u: np.ndarray, t, dt) -> np.ndarray:
        """Return the state after one RK4 step of length ``dt`` (eqs. 5.70, 5.71), input held."""
        x6 = np.asarray(x6, dtype=float)
        h = np.asarray(dt, dtype=float)
        t = np.asarray(t, dtype=float)
        hb = h[..., None]
        d = self.dynamics.derivative
        k1 = d(x6, u, t)
        k2 = d(x6 + 0.5 * hb * k1, u, t + 0.5 * h)
        k3 = d(x6 + 0.5 * hb * k2, u, t + 0.5 * h)
        k4 = d(x6 + hb * k3, u, t + h)
        return x6 + hb / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def step_and_jac(self, x6: np.ndarray, u: np.ndarray, t, dt, input_jacobian: bool = True
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Return the RK4 step ``x_next`` and its exact Jacobians ``F = dx_next/dx``, ``G = dx_next/du``.

        Eqs. 5.70 and 5.71 with ``u`` held over the step, differentiated by the chain rule through
        the four stages: :meth:`groundfloor.dynamics.Dynamics.rk4_step_and_jacobians` (the
        identified model's is compiled). ``input_jacobian=False`` skips ``G`` (returned as ``None``).
        """
        return self.dynamics.rk4_step_and_jacobians(x6, u, t, dt, input_jacobian)

    def Q(self, dt) -> np.ndarray:
        """Return the discrete process-noise covariance ``(..., 6, 6)`` for steps of ``dt`` seconds."""
        if self.Q_rate_ is None:
            raise InputError(f"process model {self.name!r}: no process noise fitted "
                             "(call fit_process_noise on the train runs first)")
        return self.Q_rate_ * np.asarray(dt, dtype=float)[..., None, None]

    def propagate(self, x0: np.ndarray, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Return states ``(n, 6)`` integrated from ``x0`` over the grid ``t`` with inputs ``u (n, 2)``.

        Dead reckoning: the model alone, step by step (each step needs the previous state).
        """
        x = np.empty((len(t), N_X))
        x[0] = x0
        dt = np.diff(t)
        for k in range(len(t) - 1):
            x[k + 1] = self.step(x[k], u[k], t[k], dt[k])
        return x


# -- fitting on the train runs ----------------------------------------------------------------

@dataclass(frozen=True)
class StateSeries:
    """Six-state series of one run on its own time grid, with the inputs at those times."""

    name: str
    t: np.ndarray  # (n,) s
    x6: np.ndarray  # (n, 6) [x, y, psi (unwrapped), v_x, v_y, omega]
    u: np.ndarray  # (n, 2)


def state_series_from_body_states(states: BodyStates, name: str = "run") -> StateSeries:
    """Return a :class:`StateSeries` from an ``groundfloor.types.BodyStates``."""
    x6 = np.column_stack([states.x, states.y, states.yaw, states.vx, states.vy, states.omega])
    return StateSeries(name, np.asarray(states.t, float), x6,
                       np.column_stack([states.u1, states.u2]))


def body_states_from_state_series(series: StateSeries) -> BodyStates:
    """Return the ``groundfloor.types.BodyStates`` of a :class:`StateSeries` (the inverse of
    :func:`state_series_from_body_states`), e.g. to fit a baseline of ``identification.sindy.baselines``."""
    x, u = series.x6, series.u
    return BodyStates(t=series.t, vx=x[:, 3], vy=x[:, 4], omega=x[:, 5], u1=u[:, 0], u2=u[:, 1],
                      x=x[:, 0], y=x[:, 1], yaw=x[:, 2])


def one_step_residuals(model: ProcessModel, series: list[StateSeries]) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """Return the one-step residuals ``x_{k+1} - step(x_k)`` ``(m, 6)`` and the step lengths ``(m,)``.

    All steps of all runs are predicted in one vectorised call; a model with input dead time
    sees each series' inputs that much later (interpolated at ``t - d``).
    """
    x0 = np.concatenate([s.x6[:-1] for s in series])
    x1 = np.concatenate([s.x6[1:] for s in series])
    d = getattr(model.dynamics, "dead_time_s", (0.0, 0.0))
    u0 = np.concatenate([np.column_stack([np.interp(s.t - d[i], s.t, s.u[:, i]) for i in range(2)])[:-1]
                         for s in series])
    t0 = np.concatenate([s.t[:-1] - s.t[0] for s in series])
    dt = np.concatenate([np.diff(s.t) for s in series])
    if np.any(dt <= 0):
        bad = next(s.name for s in series if np.any(np.diff(s.t) <= 0))
        raise InputError(f"run {bad}: state times are not strictly increasing")
    r = x1 - model.step(x0, u0, t0, dt)
    r[:, 2] = (r[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
    return r, dt


def fit_process_noise(model: ProcessModel, series: list[StateSeries],
                      floor_std: float = 1e-3) -> ProcessModel:
    """Return ``model`` with ``Q_rate_`` fitted from its one-step residuals on the train runs.

    The residual of a step of length ``dt`` is treated as white process noise integrated over
    ``dt`` (``Cov r = Q_rate dt``), so ``Q_rate = mean(r r^T / dt)``: the second moment, not the
    covariance, so that a model bias counts as noise rather than being silently subtracted.
    ``floor_std`` (per sqrt-second, in SI units of each state) keeps ``Q_rate`` positive definite
    for a model that is exact on its own data (the oracle on noise-free states).
    """
    r, dt = one_step_residuals(model, series)
    w = r / np.sqrt(dt)[:, None]
    Q = w.T @ w / len(w)
    Q = 0.5 * (Q + Q.T) + floor_std ** 2 * np.eye(N_X)
    model.Q_rate_ = Q
    model.residual_std_ = np.sqrt(np.mean(r ** 2, axis=0))
    log.info("process noise of %s from %d one-step residuals: sqrt(diag Q_rate) = %s",
             model.name, len(r), np.array2string(np.sqrt(np.diag(Q)), precision=4))
    return model
