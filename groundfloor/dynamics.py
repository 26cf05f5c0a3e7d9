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
recorded inputs delayed by that much.
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
    c, s = np.cos(psi), np.sin(psi)
    vx, vy, om = v_body[..., 0], v_body[..., 1], v_body[..., 2]
    return np.stack([vx * c - vy * s, vx * s + vy * c, om], axis=-1)


class Dynamics(ABC):
    """Body dynamics of a skid-steered robot: accelerations with Jacobians, kinematics inherited.

    Subclasses implement :meth:`accel_and_jacobians` and may override :meth:`accel` (when the
    accelerations alone are cheaper), :meth:`pose_velocity_and_jacobians` (kinematic models) and
    :meth:`in_envelope` (models trusted only where they were fitted). All methods are vectorised
    over any leading axes of ``x6 (..., 6)`` and ``u (..., 2)``.
    """

    name: str = "dynamics"
    dead_time_s: tuple[float, float] = (0.0, 0.0)  # input dead times (d1, d2): the model sees u_i(t - d_i)

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
        return np.concatenate([pose_rate(x6[..., 2], self.pose_velocity(x6, u)), self.accel(x6, u, t)], axis=-1)

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
        psi = x6[..., 2]
        c, s = np.cos(psi), np.sin(psi)
        vx, vy = v[..., 0], v[..., 1]
        x_dot = c * vx - s * vy
        y_dot = s * vx + c * vy
        f = np.empty(lead + (N_X,))
        f[..., 0], f[..., 1], f[..., 2], f[..., 3:] = x_dot, y_dot, v[..., 2], a
        J_x = np.zeros(lead + (N_X, N_X))
        J_x[..., 0, 2], J_x[..., 1, 2] = -y_dot, x_dot
        J_x[..., 3:, :] = J_a_x
        J_u = np.zeros(lead + (N_X, N_U)) if input_jacobian else None
        if J_v_x is None:  # the pose moves with the velocity states
            J_x[..., 0, 3], J_x[..., 0, 4], J_x[..., 1, 3], J_x[..., 1, 4], J_x[..., 2, 5] = c, -s, s, c, 1.0
        else:  # d pose_rate / d v_pose is the rotation R(psi) on (vx, vy), 1 on omega
            R = np.zeros(lead + (3, 3))
            R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
            J_x[..., :3, :] += R @ J_v_x
            if input_jacobian:
                J_u[..., :3, :] = R @ J_v_u
        if input_jacobian:
            J_u[..., 3:, :] = J_a_u
        return f, J_x, J_u


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
