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
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

STATE_NAMES = ("x", "y", "psi", "vx", "vy", "omega")  # the six estimated states, eq. 5.60
BODY_STATE_NAMES = ("vx", "vy", "omega")  # the body velocities a dynamics model predicts
INPUT_NAMES = ("u1", "u2")  # throttle (forward +) and steering (left +)
N_X = len(STATE_NAMES)
N_U = len(INPUT_NAMES)


def broadcast_inputs(x6: np.ndarray, u) -> np.ndarray:
    """Return ``u`` broadcast to the leading shape of ``x6`` plus ``(2,)``."""
    return np.broadcast_to(np.asarray(u, dtype=float), np.shape(x6)[:-1] + (N_U,))


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

    # -- the six-state derivative, written once -------------------------------------------------
    def pose_velocity(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the body velocities that move the pose ``(..., 3)``."""
        return self.pose_velocity_and_jacobians(x6, u)[0]

    def derivative(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return the six-state derivative ``(..., 6)`` of eq. 5.75."""
        x6 = np.asarray(x6, dtype=float)
        u = broadcast_inputs(x6, u)
        return np.concatenate([pose_rate(x6[..., 2], self.pose_velocity(x6, u)), self.accel(x6, u, t)], axis=-1)

    def derivative_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t=0.0
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the derivative ``(..., 6)`` and its Jacobians ``(..., 6, 6)``, ``(..., 6, 2)``.

        Implements eqs. 5.61 and 5.75: the kinematics' Jacobian (rotation of the body
        velocities, its derivative in ``psi``) stacked on the model's acceleration Jacobians.
        """
        x6 = np.asarray(x6, dtype=float)
        u = broadcast_inputs(x6, u)
        a, J_a_x, J_a_u = self.accel_and_jacobians(x6, u, t)
        v, J_v_x, J_v_u = self.pose_velocity_and_jacobians(x6, u)
        lead = np.broadcast_shapes(x6.shape[:-1], np.shape(a)[:-1])
        psi = x6[..., 2]
        c, s = np.cos(psi), np.sin(psi)
        rate = pose_rate(psi, v)
        R = np.zeros(lead + (3, 3))  # d pose_rate / d v_pose
        R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
        J_x = np.zeros(lead + (N_X, N_X))
        J_x[..., 0, 2] = -rate[..., 1]
        J_x[..., 1, 2] = rate[..., 0]
        J_u = np.zeros(lead + (N_X, N_U))
        if J_v_x is None:
            J_x[..., :3, 3:] = R
        else:
            J_x[..., :3, :] += R @ J_v_x
            J_u[..., :3, :] = R @ J_v_u
        J_x[..., 3:, :] = J_a_x
        J_u[..., 3:, :] = J_a_u
        f = np.concatenate([np.broadcast_to(rate, lead + (3,)), np.broadcast_to(a, lead + (3,))], axis=-1)
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
