"""Six-state process models behind one interface, discretised by RK4 with an exact Jacobian.

State ``x = [x, y, psi, v_x, v_y, omega]`` (eq. 5.60): position and heading in the local frame,
velocities in the body frame; input ``u = [u1, u2]``. The continuous dynamics are the
kinematics of eq. 5.75 (body velocities rotated into the local frame) stacked on a body-frame
acceleration model (eqs. 5.61 to 5.63)::

    d/dt [x, y]   = R(psi) [v_x, v_y]
    d/dt psi      = omega
    d/dt [v_x, v_y, omega] = a(x, u, t)

Every model only supplies ``a`` and its Jacobians; :meth:`ProcessModel.step` integrates one step
of length ``dt`` with the classical Runge-Kutta scheme of eqs. 5.70 and 5.71 (the input held
constant over the step) and differentiates that step exactly by the chain rule through the four
stages, so the EKF and the factor graph linearise the very map they propagate with.

Models: :class:`BodyModelProcess` (any body model with ``f(x3, u)``, ``J_f_x``, ``J_f_u``, such as
the identified ``identification.sindy.model.SindyModel``), :class:`TrueDynamicsProcess` (the
simulator's true dynamics, the oracle), :class:`ConstantVelocityProcess`,
:class:`UnicycleProcess` (input gains fitted on the train runs) and :class:`LinearProcess` (a
linear-Gaussian reference for tests). Process noise comes from :func:`fit_process_noise` (one-step
residuals on the train runs), never by hand.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from groundfloor.errors import InputError

log = logging.getLogger(__name__)

N_X = 6
N_U = 2
STATE_NAMES = ("x", "y", "psi", "v_x", "v_y", "omega")


class ProcessModel:
    """Base class: continuous six-state dynamics, RK4 discretisation, exact step Jacobian.

    Subclasses implement :meth:`accel_and_jac`. Attributes set by :func:`fit_process_noise`:
    ``Q_rate_`` (6, 6), the process-noise density per second, so that ``Q(dt) = Q_rate_ * dt``.
    """

    name = "process"
    Q_rate_: np.ndarray | None = None

    # -- to implement --------------------------------------------------------------------------
    def accel_and_jac(self, x6: np.ndarray, u: np.ndarray, t) -> tuple[np.ndarray, np.ndarray,
                                                                       np.ndarray]:
        """Return body accelerations ``(..., 3)`` and their Jacobians ``(..., 3, 6)``, ``(..., 3, 2)``."""
        raise NotImplementedError

    def in_envelope(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return True where ``(x6, u)`` lies inside the region the model was fitted on."""
        return np.ones(np.shape(x6)[:-1], dtype=bool)

    # -- shared machinery ----------------------------------------------------------------------
    def f_and_jac(self, x6: np.ndarray, u: np.ndarray, t) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
        """Return the state derivative ``(..., 6)`` and ``J_f_x (..., 6, 6)``, ``J_f_u (..., 6, 2)``.

        Implements eqs. 5.61 and 5.75 (kinematics in the local frame plus body accelerations).
        """
        x6 = np.asarray(x6, dtype=float)
        a, J_a_x, J_a_u = self.accel_and_jac(x6, u, t)
        psi, v_x, v_y, omega = x6[..., 2], x6[..., 3], x6[..., 4], x6[..., 5]
        c, s = np.cos(psi), np.sin(psi)
        xdot = c * v_x - s * v_y
        ydot = s * v_x + c * v_y
        f = np.concatenate([np.stack([xdot, ydot, omega], axis=-1), a], axis=-1)
        J_f_x = np.zeros(x6.shape[:-1] + (N_X, N_X))
        J_f_x[..., 0, 2] = -ydot
        J_f_x[..., 0, 3] = c
        J_f_x[..., 0, 4] = -s
        J_f_x[..., 1, 2] = xdot
        J_f_x[..., 1, 3] = s
        J_f_x[..., 1, 4] = c
        J_f_x[..., 2, 5] = 1.0
        J_f_x[..., 3:, :] = J_a_x
        J_f_u = np.zeros(x6.shape[:-1] + (N_X, N_U))
        J_f_u[..., 3:, :] = J_a_u
        return f, J_f_x, J_f_u

    def f(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the continuous state derivative ``(..., 6)`` (eq. 5.75)."""
        return self.f_and_jac(x6, u, t)[0]

    def step(self, x6: np.ndarray, u: np.ndarray, t, dt) -> np.ndarray:
        """Return the state after one RK4 step of length ``dt`` (eqs. 5.70, 5.71), input held."""
        return self.step_and_jac(x6, u, t, dt)[0]

    def step_and_jac(self, x6: np.ndarray, u: np.ndarray, t, dt) -> tuple[np.ndarray, np.ndarray,
                                                                         np.ndarray]:
        """Return the RK4 step ``x_next`` and its exact Jacobians ``F = dx_next/dx``, ``G = dx_next/du``.

        Implements eqs. 5.70 and 5.71 with ``u`` held over the step; the Jacobians follow the
        chain rule through the four stages (``dk_i/dx = J_f_x(x_i) (I + c_i h dk_{i-1}/dx)``), so
        they are exact for the discrete map, not a finite-difference or first-order approximation.
        Vectorised over leading dimensions of ``x6``, ``u``, ``t`` and ``dt``.
        """
        x6 = np.asarray(x6, dtype=float)
        u = np.asarray(u, dtype=float)
        h = np.asarray(dt, dtype=float)
        t = np.asarray(t, dtype=float)
        hb = h[..., None]
        hbb = h[..., None, None]
        eye = np.eye(N_X)
        k1, A1, B1 = self.f_and_jac(x6, u, t)
        D1x, D1u = A1, B1
        k2, A2, B2 = self.f_and_jac(x6 + 0.5 * hb * k1, u, t + 0.5 * h)
        D2x = A2 @ (eye + 0.5 * hbb * D1x)
        D2u = A2 @ (0.5 * hbb * D1u) + B2
        k3, A3, B3 = self.f_and_jac(x6 + 0.5 * hb * k2, u, t + 0.5 * h)
        D3x = A3 @ (eye + 0.5 * hbb * D2x)
        D3u = A3 @ (0.5 * hbb * D2u) + B3
        k4, A4, B4 = self.f_and_jac(x6 + hb * k3, u, t + h)
        D4x = A4 @ (eye + hbb * D3x)
        D4u = A4 @ (hbb * D3u) + B4
        x_next = x6 + hb / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        F = eye + hbb / 6.0 * (D1x + 2.0 * D2x + 2.0 * D3x + D4x)
        G = hbb / 6.0 * (D1u + 2.0 * D2u + 2.0 * D3u + D4u)
        return x_next, F, G

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


def _embed_body_jac(J3: np.ndarray) -> np.ndarray:
    """Return a body-state Jacobian ``(..., 3, 3)`` padded to the six-state ``(..., 3, 6)``."""
    J = np.zeros(J3.shape[:-1] + (N_X,))
    J[..., 3:] = J3
    return J


class BodyModelProcess(ProcessModel):
    """Process model around a body model ``f(x3, u)`` with ``x3 = [v_x, v_y, omega]`` (eq. 5.63).

    ``body`` needs ``f(x3, u) -> (..., 3)``, ``J_f_x(x3, u) -> (..., 3, 3)`` and
    ``J_f_u(x3, u) -> (..., 3, 2)``; this is the interface of ``identification.sindy.model.SindyModel``
    (its ``f_and_jacobians`` is used when present). An ``envelope`` attribute (variable name to
    ``[min, max]``) drives :meth:`in_envelope`.
    """

    def __init__(self, body, name: str = "sindy"):
        self.body = body
        self.name = name

    def accel_and_jac(self, x6, u, t):
        """Return the body model's accelerations and its Jacobians padded to six states."""
        x3 = x6[..., 3:]
        u = np.broadcast_to(u, x3.shape[:-1] + (N_U,))
        both = getattr(self.body, "f_and_jacobians", None)
        if both is not None:  # one pass through the feature library instead of three
            a, J_x, J_u = both(x3, u)
        else:
            a, J_x, J_u = self.body.f(x3, u), self.body.J_f_x(x3, u), self.body.J_f_u(x3, u)
        return np.asarray(a), _embed_body_jac(np.asarray(J_x)), np.asarray(J_u)

    def in_envelope(self, x6, u, margin: float = 0.1):
        """Return True per sample where ``[v_x, v_y, omega, u1, u2]`` lies in the body model's
        training envelope (``body.envelope``: name -> [min, max]) widened by ``margin`` of its
        width, the rule of ``SindyModel.check_envelope``."""
        env = getattr(self.body, "envelope", None)
        x6 = np.asarray(x6, dtype=float)
        if not env:
            return super().in_envelope(x6, u)
        z = np.concatenate([x6[..., 3:], np.broadcast_to(u, x6.shape[:-1] + (N_U,))], axis=-1)
        names = ("vx", "vy", "omega", "u1", "u2")
        lo = np.array([env[v][0] if v in env else -np.inf for v in names])
        hi = np.array([env[v][1] if v in env else np.inf for v in names])
        pad = margin * np.where(np.isfinite(hi - lo), hi - lo, 0.0)
        return np.all((z >= lo - pad) & (z <= hi + pad), axis=-1)


class TrueDynamicsProcess(ProcessModel):
    """The simulator's true dynamics (the oracle): ``f(x6, u, t)``, ``J_f_x -> (..., 3, 6)``."""

    name = "oracle"

    def __init__(self, dynamics, name: str = "oracle"):
        self.dynamics = dynamics
        self.name = name

    def accel_and_jac(self, x6, u, t):
        """Return the true accelerations and Jacobians (pose and time dependence included)."""
        u = np.broadcast_to(u, x6.shape[:-1] + (N_U,))
        d = self.dynamics
        if hasattr(d, "jacobians"):  # TrueDynamics: both Jacobians from one pass
            J_x, J_u = d.jacobians(x6, u, t)
        else:
            J_x, J_u = d.J_f_x(x6, u, t), d.J_f_u(x6, u, t)
        return np.asarray(d.f(x6, u, t)), np.asarray(J_x), np.asarray(J_u)


class ConstantVelocityProcess(ProcessModel):
    """Constant body velocity: ``a = 0``; the pose still follows the kinematics of eq. 5.75."""

    name = "cv"

    def accel_and_jac(self, x6, u, t):
        """Return zero accelerations and zero Jacobians."""
        lead = np.shape(x6)[:-1]
        return np.zeros(lead + (3,)), np.zeros(lead + (3, N_X)), np.zeros(lead + (3, N_U))


@dataclass
class UnicycleProcess(ProcessModel):
    """Unicycle with first-order actuator lag and no lateral slip.

    ``v_x -> k_v u1`` and ``omega -> k_w u2`` with time constants ``tau_v``, ``tau_w``; ``v_y``
    decays to zero with ``tau_v``. Gains come from :func:`fit_unicycle` on the train runs.
    """

    k_v: float = 1.0
    tau_v: float = 0.2
    k_w: float = 1.0
    tau_w: float = 0.2
    name: str = "unicycle"

    def accel_and_jac(self, x6, u, t):
        """Return the lagged unicycle accelerations and their constant Jacobians."""
        lead = np.shape(x6)[:-1]
        u = np.broadcast_to(u, lead + (N_U,))
        a = np.stack([(self.k_v * u[..., 0] - x6[..., 3]) / self.tau_v,
                      -x6[..., 4] / self.tau_v,
                      (self.k_w * u[..., 1] - x6[..., 5]) / self.tau_w], axis=-1)
        J_x = np.zeros(lead + (3, N_X))
        J_x[..., 0, 3] = J_x[..., 1, 4] = -1.0 / self.tau_v
        J_x[..., 2, 5] = -1.0 / self.tau_w
        J_u = np.zeros(lead + (3, N_U))
        J_u[..., 0, 0] = self.k_v / self.tau_v
        J_u[..., 2, 1] = self.k_w / self.tau_w
        return a, J_x, J_u


class LinearProcess(ProcessModel):
    """Linear continuous dynamics ``x_dot = A x + B u`` on all six states (tests, references).

    Not a vehicle model: the pose rows are whatever ``A`` says, so that the EKF and the factor
    graph can be compared on an exactly linear-Gaussian problem.
    """

    name = "linear"

    def __init__(self, A: np.ndarray, B: np.ndarray):
        self.A = np.asarray(A, dtype=float)
        self.B = np.asarray(B, dtype=float)

    def f_and_jac(self, x6, u, t):
        """Return ``A x + B u`` and the constant Jacobians ``A``, ``B``."""
        x6 = np.asarray(x6, dtype=float)
        lead = x6.shape[:-1]
        f = x6 @ self.A.T + np.broadcast_to(u, lead + (N_U,)) @ self.B.T
        return f, np.broadcast_to(self.A, lead + (N_X, N_X)), np.broadcast_to(self.B, lead + (N_X, N_U))


# -- fitting on the train runs ----------------------------------------------------------------

@dataclass(frozen=True)
class StateSeries:
    """Six-state series of one run on its own time grid, with the inputs at those times."""

    name: str
    t: np.ndarray  # (n,) s
    x6: np.ndarray  # (n, 6) [x, y, psi (unwrapped), v_x, v_y, omega]
    u: np.ndarray  # (n, 2)


def state_series_from_body_states(states, name: str = "run") -> StateSeries:
    """Return a :class:`StateSeries` from an ``groundfloor.types.BodyStates``."""
    x6 = np.column_stack([states.x, states.y, states.yaw, states.vx, states.vy, states.omega])
    return StateSeries(name, np.asarray(states.t, float), x6,
                       np.column_stack([states.u1, states.u2]))


def one_step_residuals(model: ProcessModel, series: list[StateSeries]) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """Return the one-step residuals ``x_{k+1} - step(x_k)`` ``(m, 6)`` and the step lengths ``(m,)``.

    All steps of all runs are predicted in one vectorised call.
    """
    x0 = np.concatenate([s.x6[:-1] for s in series])
    x1 = np.concatenate([s.x6[1:] for s in series])
    u0 = np.concatenate([s.u[:-1] for s in series])
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


def fit_unicycle(series: list[StateSeries]) -> UnicycleProcess:
    """Return a :class:`UnicycleProcess` whose gains and lags are fitted on the train runs.

    Forward differences of the body velocities against the input held over the step and the
    velocity at the step's midpoint (trapezoidal, second order, any step length): for each axis a
    least-squares fit of ``(v_{k+1} - v_k) / dt = b u_k - c (v_k + v_{k+1}) / 2`` gives
    ``k = b / c`` and ``tau = 1 / c``.
    """
    def fit_axis(v: np.ndarray, u: np.ndarray, a: np.ndarray, axis: str) -> tuple[float, float]:
        coef, *_ = np.linalg.lstsq(np.column_stack([u, -v]), a, rcond=None)
        b, c = coef
        if c <= 0 or not np.isfinite(c):
            raise InputError(f"train runs: unicycle fit of {axis} is unstable (no lag to fit); "
                             "the train runs hold too little excitation")
        return float(b / c), float(1.0 / c)

    dt = np.concatenate([np.diff(s.t) for s in series])[:, None]
    v0 = np.concatenate([s.x6[:-1, 3:] for s in series])
    v1 = np.concatenate([s.x6[1:, 3:] for s in series])
    u = np.concatenate([s.u[:-1] for s in series])
    acc = (v1 - v0) / dt
    v_mid = 0.5 * (v0 + v1)
    k_v, tau_v = fit_axis(v_mid[:, 0], u[:, 0], acc[:, 0], "v_x")
    k_w, tau_w = fit_axis(v_mid[:, 2], u[:, 1], acc[:, 2], "omega")
    log.info("unicycle fit: k_v=%.3f m/s tau_v=%.3f s k_w=%.3f rad/s tau_w=%.3f s",
             k_v, tau_v, k_w, tau_w)
    return UnicycleProcess(k_v=k_v, tau_v=tau_v, k_w=k_w, tau_w=tau_w)
