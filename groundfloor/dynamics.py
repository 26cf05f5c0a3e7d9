"""The one dynamics interface of the project, and the eq. 5.75 kinematics written once.

State ``x6 = [x, y, psi, vx, vy, omega]`` (eq. 5.60): position and heading in the local frame,
velocities in the body frame; inputs ``u = [u1, u2]`` as the model sees them. Every motion model
of the project (the identified SINDy model, the baselines, the simulator's true dynamics, the
diagnosis's extended model) is a :class:`Dynamics`: it supplies the body accelerations and their
Jacobians, and inherits the six-state derivative

.. math::  \\dot x = v_x\\cos\\psi - v_y\\sin\\psi,\\quad \\dot y = v_x\\sin\\psi + v_y\\cos\\psi,
           \\quad \\dot\\psi = \\omega,\\quad \\dot{\\mathbf v}^b = \\mathbf a(\\mathbf x, \\mathbf u, t)

(eq. 5.75 with the body velocities as state, which is exact) with its exact Jacobians. The
multi-step evaluation integrates :meth:`Dynamics.derivative`; the EKF and the factor graph
discretise :meth:`Dynamics.derivative_and_jacobians` (``sindy_ekf.estimation.process_models``).

A kinematic model, whose pose follows velocities commanded by the inputs (the data README's
unicycle), overrides :meth:`Dynamics.pose_velocity_and_jacobians`; that method is the only
place where models differ in how the pose moves, so no caller asks a model what kind it is.

Time ``t`` (s) is the time since the start of the run; no model of the project reads it today
(time-dependent mechanisms act on the inputs), but every call passes it.

Input dead time: a model that sees its inputs late, ``u_i(t - d_i)``, says so in
:attr:`Dynamics.dead_time_s` (``(d1, d2)`` in seconds, zero by default). The model's methods take
the inputs it sees; whoever drives it (the multi-step evaluation, the filters) feeds it the
recorded inputs delayed by that much. A model whose motors also smooth their command says so in
:attr:`Dynamics.input_lag_s` (first-order lags ``(T1, T2)``, applied before the dead time's shift;
:mod:`groundfloor.input_chain` is the one place the chain is computed).
"""

from __future__ import annotations

import logging
import warnings
from abc import ABC, abstractmethod

import numpy as np

log = logging.getLogger(__name__)

STATE_NAMES = ("x", "y", "psi", "vx", "vy", "omega")  # the six estimated states, eq. 5.60
BODY_STATE_NAMES = ("vx", "vy", "omega")  # the body velocities a dynamics model predicts
INPUT_NAMES = ("u1", "u2")  # throttle (forward +) and steering (left +)
N_X = len(STATE_NAMES)
N_U = len(INPUT_NAMES)
_CONJUGATE = np.array([1.0, -1.0])  # [cos, sin] -> [cos, -sin], the first row of R(psi)
_QUARTER_TURN = np.array([-1.0, 1.0])  # [y_dot, x_dot] -> [-y_dot, x_dot] = d R(psi) v / d psi
_EYE = np.eye(N_X)


class EnvelopeWarning(UserWarning):
    """States or inputs outside the range a model was trained on."""


def broadcast_inputs(x6: np.ndarray, u) -> tuple[np.ndarray, np.ndarray]:
    """Return ``x6 (..., 6)`` and ``u (..., 2)`` as float arrays broadcast to one leading shape."""
    x6 = np.asarray(x6, dtype=float)
    u = np.asarray(u, dtype=float)
    if u.shape[:-1] != x6.shape[:-1]:  # the common case (same leading shape) costs nothing
        lead = np.broadcast_shapes(x6.shape[:-1], u.shape[:-1])
        x6, u = np.broadcast_to(x6, lead + (N_X,)), np.broadcast_to(u, lead + (N_U,))
    return x6, u


def pose_rate(psi: np.ndarray, v_body: np.ndarray) -> np.ndarray:
    """Return ``[x_dot, y_dot, psi_dot]`` ``(..., 3)``: body velocities into the local frame (eq. 5.75)."""
    psi, v_body = np.asarray(psi, dtype=float), np.asarray(v_body, dtype=float)
    lead = np.broadcast_shapes(psi.shape, v_body.shape[:-1])
    out = np.empty(lead + (3,))
    _pose_rate_into(out, np.empty(lead + (2,)), psi, v_body)
    return out


def _pose_rate_into(out: np.ndarray, cs: np.ndarray, psi: np.ndarray, v_body: np.ndarray) -> None:
    """Write :func:`pose_rate` into ``out (..., 3)`` and ``[cos psi, sin psi]`` into ``cs (..., 2)``.

    The rotation by ``psi`` is the complex product ``e^{i psi} (vx + i vy) = x_dot + i y_dot``:
    one numpy call instead of six, on the small batches of the filters where each call, not the
    arithmetic, is the cost.
    """
    np.cos(psi, out=cs[..., 0])
    np.sin(psi, out=cs[..., 1])
    rotated = out[..., :2].view(np.complex128)[..., 0]
    np.multiply(cs.view(np.complex128)[..., 0], _complex(v_body[..., :2]), out=rotated)
    out[..., 2] = v_body[..., 2]


def _complex(xy: np.ndarray) -> np.ndarray:
    """Return pairs ``xy (..., 2)`` as complex numbers ``x + i y`` ``(...)``: a view when each pair is
    contiguous in memory (the filters' states), else a new array."""
    if xy.strides[-1] == xy.itemsize:
        return xy.view(np.complex128)[..., 0]
    return xy[..., 0] + 1j * xy[..., 1]


class Dynamics(ABC):
    """Body dynamics of a skid-steered robot: accelerations with Jacobians, kinematics inherited.

    Subclasses implement :meth:`accel_and_jacobians` and may override :meth:`accel` (when the
    accelerations alone are cheaper), :meth:`pose_velocity_and_jacobians` (kinematic models) and
    :meth:`in_envelope` (models trusted only where they were fitted). All methods are vectorised
    over any leading axes of ``x6 (..., 6)`` and ``u (..., 2)``.
    """

    name: str = "dynamics"
    dead_time_s: tuple[float, float] = (0.0, 0.0)  # input dead times (d1, d2): the model sees u_i(t - d_i)
    input_lag_s: tuple[float, float] = (0.0, 0.0)  # first-order input lags (T1, T2), groundfloor.input_chain

    # -- to implement --------------------------------------------------------------------------
    @abstractmethod
    def accel_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t=0.0
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return body accelerations ``(..., 3)`` and ``J_a_x (..., 3, 6)``, ``J_a_u (..., 3, 2)``."""

    def accel(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the body accelerations ``[vx_dot, vy_dot, omega_dot]`` ``(..., 3)``."""
        return self.accel_and_jacobians(x6, u, t)[0]

    def pose_velocity_and_jacobians(self, x6: np.ndarray, u: np.ndarray
                                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Return the body velocities that move the pose ``(..., 3)`` and their Jacobians.

        Default: the state's own velocities, with ``None`` for the Jacobians (identity on the
        velocity states, zero on the inputs). A kinematic model returns the velocities its
        inputs command and ``J_v_x (..., 3, 6)``, ``J_v_u (..., 3, 2)``.
        """
        return np.asarray(x6, dtype=float)[..., 3:], None, None

    def in_envelope(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return True per sample where ``(x6, u)`` lies where the model may be trusted."""
        return np.ones(np.shape(x6)[:-1], dtype=bool)

    def warn_outside_envelope(self, x6: np.ndarray, u: np.ndarray, name: str = "data") -> float:
        """Return the fraction of samples outside :meth:`in_envelope`; warn (:class:`EnvelopeWarning`)
        naming ``name`` when there are any. Models that know their variables name them too."""
        inside = np.asarray(self.in_envelope(x6, u)).reshape(-1)
        frac = float(np.mean(~inside)) if inside.size else 0.0
        if frac > 0:
            msg = f"{name}: {100 * frac:.1f} % of samples outside the model's training envelope"
            log.warning(msg)
            warnings.warn(msg, EnvelopeWarning, stacklevel=2)
        return frac

    # -- the six-state derivative, written once -------------------------------------------------
    def pose_velocity(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the body velocities that move the pose ``(..., 3)``."""
        return self.pose_velocity_and_jacobians(x6, u)[0]

    def derivative(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the six-state derivative ``(..., 6)`` of eq. 5.75."""
        x6, u = broadcast_inputs(x6, u)
        f = np.empty(x6.shape)
        _pose_rate_into(f[..., :3], np.empty(x6.shape[:-1] + (2,)), x6[..., 2], self.pose_velocity(x6, u))
        f[..., 3:] = self.accel(x6, u, t)
        return f

    def derivative_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t=0.0, input_jacobian: bool = True
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Return the derivative ``(..., 6)`` and its Jacobians ``J_f_x (..., 6, 6)``, ``J_f_u (..., 6, 2)``.

        Implements eqs. 5.61 and 5.75: the kinematics' Jacobian (rotation of the body
        velocities, its derivative in ``psi``) stacked on the model's acceleration Jacobians.
        ``input_jacobian=False`` returns ``None`` for ``J_f_u`` (the EKF's prediction needs only
        ``J_f_x``). Written with few numpy calls: the filters call it four times per step on
        small batches, where the per-call overhead, not the arithmetic, is the cost.
        """
        x6, u = broadcast_inputs(x6, u)
        a, J_a_x, J_a_u = self.accel_and_jacobians(x6, u, t)
        v, J_v_x, J_v_u = self.pose_velocity_and_jacobians(x6, u)
        lead = x6.shape[:-1]
        f, cs = np.empty(lead + (N_X,)), np.empty(lead + (2,))
        _pose_rate_into(f[..., :3], cs, x6[..., 2], v)
        f[..., 3:] = a
        J_x = np.zeros(lead + (N_X, N_X))
        np.multiply(f[..., 1::-1], _QUARTER_TURN, out=J_x[..., :2, 2])  # d pose_rate / d psi
        J_x[..., 3:, :] = J_a_x
        # d pose_rate / d v_pose: the rotation R(psi) on (vx, vy), 1 on omega
        R = J_x[..., :3, 3:] if J_v_x is None else np.zeros(lead + (3, 3))
        np.multiply(cs, _CONJUGATE, out=R[..., 0, :2])
        R[..., 1, :2] = cs[..., ::-1]
        R[..., 2, 2] = 1.0
        J_u = None
        if input_jacobian:
            J_u = np.empty(lead + (N_X, N_U))
            J_u[..., 3:, :] = J_a_u
            J_u[..., :3, :] = 0.0 if J_v_u is None else R @ J_v_u
        if J_v_x is not None:  # a kinematic model: the pose moves with velocities of its own
            J_x[..., :3, :] += R @ J_v_x
        return f, J_x, J_u

    def rk4_step_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t, dt, input_jacobian: bool = True
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Return the RK4 step ``x_next`` and its exact Jacobians ``F = dx_next/dx``, ``G = dx_next/du``.

        Implements eqs. 5.70 and 5.71 with ``u`` held over the step (the filters' discretisation);
        the Jacobians follow the chain rule through the four stages (``dk_i/dx = J_f_x(x_i)
        (I + c_i h dk_{i-1}/dx)``), so they are exact for the discrete map, not a finite-difference
        or first-order approximation. Vectorised over leading dimensions of ``x6``, ``u``, ``t``
        and ``dt``. ``input_jacobian=False`` skips ``G`` (returned as ``None``; the filters need
        only ``F``). A model may override it with a compiled step that computes the same map.
        """
        x6 = np.asarray(x6, dtype=float)
        h = np.asarray(dt, dtype=float)
        t = np.asarray(t, dtype=float)
        hb = h[..., None]
        hh = 0.5 * hb
        t_mid = t + 0.5 * h
        dj = self.derivative_and_jacobians
        k1, A1, B1 = dj(x6, u, t, input_jacobian)
        k2, A2, B2 = dj(x6 + hh * k1, u, t_mid, input_jacobian)
        k3, A3, B3 = dj(x6 + hh * k2, u, t_mid, input_jacobian)
        k4, A4, B4 = dj(x6 + hb * k3, u, t + h, input_jacobian)
        x_next = x6 + (hh / 3.0) * (k1 + 2.0 * (k2 + k3) + k4)
        # dk_i/dx = A_i (I + c_i h dk_{i-1}/dx), in place: fewer temporaries
        h2 = hh[..., None]
        D2x = A2 @ A1
        D2x *= h2
        D2x += A2
        D3x = A3 @ D2x
        D3x *= h2
        D3x += A3
        D4x = A4 @ D3x
        D4x *= h2 + h2
        D4x += A4
        h6 = h2 / 3.0
        F = D2x + D3x
        F *= 2.0
        F += A1
        F += D4x
        F *= h6
        F += _EYE
        G = None
        if input_jacobian:
            D2u = h2 * (A2 @ B1) + B2
            D3u = h2 * (A3 @ D2u) + B3
            D4u = (h2 + h2) * (A4 @ D3u) + B4
            G = h6 * (B1 + 2.0 * (D2u + D3u) + D4u)
        return x_next, F, G


def rk4_rollout_step(dynamics: Dynamics, x6: np.ndarray, u0: np.ndarray, u_mid: np.ndarray,
                     u1: np.ndarray, t: np.ndarray, dt: float) -> np.ndarray:
    """Return the state after one classical RK4 step (eqs. 5.70, 5.71) with the input interpolated.

    The input is ``u0`` at the step's start, ``u_mid`` at its middle and ``u1`` at its end (the
    multi-step evaluation's linear interpolation); the EKF's step holds the input instead
    (``sindy_ekf.estimation.process_models``).
    """
    k1 = dynamics.derivative(x6, u0, t)
    k2 = dynamics.derivative(x6 + 0.5 * dt * k1, u_mid, t + 0.5 * dt)
    k3 = dynamics.derivative(x6 + 0.5 * dt * k2, u_mid, t + 0.5 * dt)
    k4 = dynamics.derivative(x6 + dt * k3, u1, t + dt)
    return x6 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
