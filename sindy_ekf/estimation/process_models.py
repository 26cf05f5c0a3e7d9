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

Unmodelled states: an identified acceleration equation that is identically zero (e.g. ``dvy/dt =
0``) while that state drives another equation (a ``vy`` term in the yaw equation) makes the state a
random walk seen only through the positions, and the filter drifts with it (``bench/results/real.md``).
:func:`fit_process_noise` gives such a state a first-order Gauss-Markov process instead,
``dv/dt = -v / tau + w`` (Maybeck 1979, sec. 4.11; Gelb 1974, table 3.8-1), with ``tau`` from the
lag-one autocorrelation of the train runs' reference states and the noise density from the
one-step residuals as for every other state, so the state's stationary variance matches the
train runs'. The step applies the exact decay ``exp(-dt / tau)`` after the RK4 step, whose
equation for that state is zero.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numba
import numpy as np

from groundfloor.dynamics import N_U, N_X, Dynamics
from groundfloor.errors import InputError
from groundfloor.input_chain import chain_inputs
from groundfloor.types import BodyStates

log = logging.getLogger(__name__)

ENVELOPE_MARGIN = 0.1  # the identified model's envelope widened by this times its width (its own rule)

__all__ = ["N_X", "N_U", "ProcessModel", "StateSeries", "fit_process_noise", "one_step_residuals",
           "unmodelled_states", "fit_mean_reversion",
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
    # state index -> Gauss-Markov time constant, s, of the unmodelled states (module docstring)
    mean_reverting_: dict[int, float] = {}

    def __init__(self, dynamics: Dynamics, name: str | None = None):
        self.dynamics = dynamics
        self.name = name or dynamics.name
        self.mean_reverting_ = {}

    def _mean_revert(self, x_next: np.ndarray, F: np.ndarray | None, dt) -> None:
        """Decay the unmodelled states of ``x_next`` (and their rows of ``F``) in place by ``exp(-dt/tau)``."""
        for i, tau in self.mean_reverting_.items():
            phi = np.exp(-np.asarray(dt, dtype=float) / tau)
            x_next[..., i] *= phi
            if F is not None:
                F[..., i, :] *= np.asarray(phi)[..., None]

    def f(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the continuous state derivative ``(..., 6)`` (eq. 5.75)."""
        return self.dynamics.derivative(x6, u, t)

    def in_envelope(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return True where ``(x6, u)`` lies where the dynamics may be trusted."""
        return self.dynamics.in_envelope(x6, u)

    def velocity_bounds(self, margin: float = ENVELOPE_MARGIN) -> tuple[np.ndarray, np.ndarray] | None:
        """Return ``(lo, hi)`` of the body velocities ``[vx, vy, omega]`` where the model was fitted,
        widened by ``margin`` times the width on both sides (the rule of ``SindyModel.in_envelope``);
        None for dynamics without an envelope. Unbounded sides are infinite."""
        env = getattr(self.dynamics, "envelope", None) or {}
        if not any(v in env for v in ("vx", "vy", "omega")):
            return None
        lo = np.array([env[v][0] if v in env else -np.inf for v in ("vx", "vy", "omega")], dtype=float)
        hi = np.array([env[v][1] if v in env else np.inf for v in ("vx", "vy", "omega")], dtype=float)
        width = hi - lo
        pad = margin * np.where(np.isfinite(width), width, 0.0)
        return lo - pad, hi + pad

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
        x_next = x6 + hb / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if self.mean_reverting_:
            self._mean_revert(x_next, None, h)
        return x_next

    def step_and_jac(self, x6: np.ndarray, u: np.ndarray, t, dt, input_jacobian: bool = True
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Return the RK4 step ``x_next`` and its exact Jacobians ``F = dx_next/dx``, ``G = dx_next/du``.

        Eqs. 5.70 and 5.71 with ``u`` held over the step, differentiated by the chain rule through
        the four stages: :meth:`groundfloor.dynamics.Dynamics.rk4_step_and_jacobians` (the
        identified model's is compiled). ``input_jacobian=False`` skips ``G`` (returned as ``None``).
        """
        x_next, F, G = self.dynamics.rk4_step_and_jacobians(x6, u, t, dt, input_jacobian)
        if self.mean_reverting_:  # the unmodelled states' rows of F and G are unit rows and zero
            self._mean_revert(x_next, F, dt)
        return x_next, F, G

    def saturated_step_and_jac(self, x6: np.ndarray, u: np.ndarray, t, dt, bounds
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the step, ``F`` and which rows were saturated ``(m,)``, with the model evaluated at
        the body velocities clipped to ``bounds`` (:meth:`velocity_bounds`).

        ``x_next = step(x_sat)``: the mean is projected onto the envelope before the step (estimate
        projection, Simon 2010, sec. 2.3) instead of being extrapolated by the model's polynomial
        (whose cubic terms explode there). The column of ``F`` of a projected velocity is the unit
        column, so its covariance is carried over, not shrunk by the projection. Holding the
        velocity outside instead (``x + step(x_sat) - x_sat``) left it unobservable: the position
        moves with the projected velocity whatever the held one, so nothing pulled it back, and a
        filter's velocity ran to -580 m/s while its position followed the fixes (Monte-Carlo run
        734, ``sindy_ekf_lateral``). ``x6 (m, 6)``.
        """
        x_sat = x6.copy()
        np.clip(x6[:, 3:], bounds[0], bounds[1], out=x_sat[:, 3:])
        x_next, F, _ = self.step_and_jac(x_sat, u, t, dt, input_jacobian=False)
        held = x_sat[:, 3:] != x6[:, 3:]
        rows, cols = np.nonzero(held)
        F[rows, :, 3 + cols] = 0.0
        F[rows, 3 + cols, 3 + cols] = 1.0
        return x_next, F, held.any(axis=1)

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


@numba.njit(cache=True)
def outside_bounds(x6: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Return whether any body velocity of ``x6 (m, 6)`` lies outside ``[lo, hi] (3,)`` (compiled:
    the EKF checks it at every grid step, where a few numpy calls would cost a tenth of the step)."""
    for i in range(x6.shape[0]):
        for j in range(3):
            v = x6[i, 3 + j]
            if v < lo[j] or v > hi[j]:
                return True
    return False


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
    lag = getattr(model.dynamics, "input_lag_s", (0.0, 0.0))
    u0 = np.concatenate([chain_inputs(s.t, s.t, s.u, d, lag)[:-1] for s in series])
    t0 = np.concatenate([s.t[:-1] - s.t[0] for s in series])
    dt = np.concatenate([np.diff(s.t) for s in series])
    if np.any(dt <= 0):
        bad = next(s.name for s in series if np.any(np.diff(s.t) <= 0))
        raise InputError(f"run {bad}: state times are not strictly increasing")
    r = x1 - model.step(x0, u0, t0, dt)
    r[:, 2] = (r[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
    return r, dt


def unmodelled_states(model: ProcessModel, series: list[StateSeries]) -> list[int]:
    """Return the velocity states whose equation is zero on every train sample, with a zero
    Jacobian (identically zero, not zero by chance), while another equation depends on them (the
    random walks of the module docstring)."""
    x = np.concatenate([s.x6 for s in series])
    u = np.concatenate([s.u for s in series])
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(u), axis=1)
    if not ok.any():
        return []
    a, J_a_x, J_a_u = model.dynamics.accel_and_jacobians(x[ok], u[ok])
    out = []
    for j in range(3):
        others = [e for e in range(3) if e != j]
        zero = np.all(a[:, j] == 0.0) and np.all(J_a_x[:, j] == 0.0) and np.all(J_a_u[:, j] == 0.0)
        if zero and np.any(J_a_x[:, others, 3 + j] != 0.0):
            out.append(3 + j)
    return out


def fit_mean_reversion(series: list[StateSeries], i: int) -> float | None:
    """Return the Gauss-Markov time constant, s, of state ``i`` over the train runs, or None.

    Lag-one least squares ``phi = sum v_k v_{k+1} / sum v_k^2`` over all consecutive samples
    (the AR(1) fit of a sampled first-order Gauss-Markov process), ``tau = -dt / ln(phi)`` at the
    median step ``dt``; None when ``phi`` is not in (0, 1) (no mean reversion seen).
    """
    v0 = np.concatenate([s.x6[:-1, i] for s in series])
    v1 = np.concatenate([s.x6[1:, i] for s in series])
    dt = np.concatenate([np.diff(s.t) for s in series])
    ok = np.isfinite(v0) & np.isfinite(v1) & (dt > 0)
    den = float(np.sum(v0[ok] ** 2))
    if den <= 0:
        return None
    phi = float(np.sum(v0[ok] * v1[ok])) / den
    if not 0.0 < phi < 1.0:
        return None
    return float(-np.median(dt[ok]) / np.log(phi))


def fit_process_noise(model: ProcessModel, series: list[StateSeries],
                      floor_std: float = 1e-3, mean_reverting: bool = True) -> ProcessModel:
    """Return ``model`` with ``Q_rate_`` fitted from its one-step residuals on the train runs.

    With ``mean_reverting`` (default), the unmodelled states (:func:`unmodelled_states`) first
    get their Gauss-Markov time constants (:func:`fit_mean_reversion`, module docstring), so that
    their residuals, and with them their noise density, are those of the decaying process.

    The residual of a step of length ``dt`` is treated as white process noise integrated over
    ``dt`` (``Cov r = Q_rate dt``), so ``Q_rate = mean(r r^T / dt)``: the second moment, not the
    covariance, so that a model bias counts as noise rather than being silently subtracted.
    ``floor_std`` (per sqrt-second, in SI units of each state) keeps ``Q_rate`` positive definite
    for a model that is exact on its own data (the oracle on noise-free states).
    """
    model.mean_reverting_ = {}
    if mean_reverting:
        taus = {i: fit_mean_reversion(series, i) for i in unmodelled_states(model, series)}
        model.mean_reverting_ = {i: tau for i, tau in taus.items() if tau is not None}
        if model.mean_reverting_:
            log.info("%s: unmodelled states %s given Gauss-Markov time constants %s s", model.name,
                     list(model.mean_reverting_), [round(v, 3) for v in model.mean_reverting_.values()])
    r, dt = one_step_residuals(model, series)
    w = r / np.sqrt(dt)[:, None]
    Q = w.T @ w / len(w)
    Q = 0.5 * (Q + Q.T) + floor_std ** 2 * np.eye(N_X)
    model.Q_rate_ = Q
    model.residual_std_ = np.sqrt(np.mean(r ** 2, axis=0))
    log.info("process noise of %s from %d one-step residuals: sqrt(diag Q_rate) = %s",
             model.name, len(r), np.array2string(np.sqrt(np.diag(Q)), precision=4))
    return model
