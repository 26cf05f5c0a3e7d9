"""Shared by the estimation tests: a small body model, a linear-Gaussian reference and a noisy
truth simulator.

The truth is generated with known process noise, so that an oracle filter (same dynamics, Q
fitted from one-step residuals of a separate training simulation) must be consistent.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from groundfloor.dynamics import N_U, N_X, Dynamics
from simulation.gnss import PROFILES, simulate_gnss
from sindy_ekf.estimation.process_models import ProcessModel, StateSeries, fit_process_noise

ACCEL_STD = np.array([0.05, 0.02, 0.05])  # white acceleration noise density of the truth, SI/sqrt(s)


class PolyBody(Dynamics):
    """Stand-in body model: SINDy-style ``f_and_jacobians(x3, u)`` with analytic Jacobians, a
    :class:`groundfloor.dynamics.Dynamics` through :meth:`accel_and_jacobians` (subclasses change
    ``f_and_jacobians`` only); trusted inside ``envelope`` widened by 10 % as the SINDy model."""

    name = "poly_body"
    envelope = {"vx": [-1.0, 1.0], "vy": [-0.3, 0.3], "omega": [-1.0, 1.0], "u1": [-1, 1], "u2": [-1, 1]}

    def accel_and_jacobians(self, x6, u, t=0.0):
        x6 = np.asarray(x6, dtype=float)
        f, J3, J_u = self.f_and_jacobians(x6[..., 3:], np.broadcast_to(u, x6.shape[:-1] + (N_U,)))
        J_x = np.zeros(np.shape(f)[:-1] + (3, N_X))
        J_x[..., 3:] = J3
        return f, J_x, J_u

    def in_envelope(self, x6, u):
        z = np.concatenate([np.asarray(x6, float)[..., 3:], np.broadcast_to(u, np.shape(x6)[:-1] + (N_U,))], -1)
        lo, hi = np.array([self.envelope[v] for v in ("vx", "vy", "omega", "u1", "u2")]).T
        pad = 0.1 * (hi - lo)
        return np.all((z >= lo - pad) & (z <= hi + pad), axis=-1)

    def f_and_jacobians(self, x, u):
        vx, vy, w = x[..., 0], x[..., 1], x[..., 2]
        u1, u2 = u[..., 0], u[..., 1]
        z = np.zeros_like(vx)
        f = np.stack([2.0 * u1 - 3.0 * vx + 0.4 * w * vy,
                      -5.0 * vy - 0.3 * vx * w,
                      1.5 * u2 - 2.5 * w + 0.1 * vx * u2], axis=-1)
        J_x = np.stack([np.stack([-3.0 + z, 0.4 * w, 0.4 * vy], -1),
                        np.stack([-0.3 * w, -5.0 + z, -0.3 * vx], -1),
                        np.stack([0.1 * u2, z, -2.5 + z], -1)], axis=-2)
        J_u = np.stack([np.stack([2.0 + z, z], -1), np.stack([z, z], -1),
                        np.stack([z, 1.5 + 0.1 * vx], -1)], axis=-2)
        return f, J_x, J_u

    def f(self, x, u):
        return self.f_and_jacobians(x, u)[0]

    def J_f_x(self, x, u):
        return self.f_and_jacobians(x, u)[1]

    def J_f_u(self, x, u):
        return self.f_and_jacobians(x, u)[2]


class LinearDynamics(Dynamics):
    """Linear continuous dynamics ``x_dot = A x + B u`` on all six states (the linear-Gaussian
    reference of the tests). Not a vehicle model: the pose rows are whatever ``A`` says, so it
    overrides the six-state derivative instead of inheriting the kinematics; the EKF and the
    factor graph can then be compared on an exactly linear-Gaussian problem."""

    name = "linear"

    def __init__(self, A: np.ndarray, B: np.ndarray):
        self.A = np.asarray(A, dtype=float)
        self.B = np.asarray(B, dtype=float)

    def accel_and_jacobians(self, x6, u, t=0.0):
        f, J_x, J_u = self.derivative_and_jacobians(x6, u, t)
        return f[..., 3:], J_x[..., 3:, :], J_u[..., 3:, :]

    def derivative(self, x6, u, t=0.0):
        return self.derivative_and_jacobians(x6, u, t, input_jacobian=False)[0]

    def derivative_and_jacobians(self, x6, u, t=0.0, input_jacobian=True):
        x6 = np.asarray(x6, dtype=float)
        lead = x6.shape[:-1]
        f = x6 @ self.A.T + np.broadcast_to(u, lead + (N_U,)) @ self.B.T
        J_u = np.broadcast_to(self.B, lead + (N_X, N_U)) if input_jacobian else None
        return f, np.broadcast_to(self.A, lead + (N_X, N_X)), J_u


def smooth_inputs(t: np.ndarray, rng) -> np.ndarray:
    """Return (n, 2) joystick-like inputs: a few random sinusoids, clipped to [-1, 1]."""
    f = rng.uniform(0.02, 0.2, (2, 3))
    ph = rng.uniform(0, 2 * np.pi, (2, 3))
    u = np.stack([np.sin(2 * np.pi * f[i][:, None] * t + ph[i][:, None]).sum(0) for i in range(2)], -1)
    u[:, 0] = 0.5 + 0.3 * u[:, 0]
    return np.clip(u * [1.0, 0.4], -1, 1)


def simulate_truths(process, duration_s: float, rng, n_runs: int = 1, dt: float = 0.02,
                    t0: float = 1000.0, accel_std=ACCEL_STD) -> list[StateSeries]:
    """Return ``n_runs`` truth runs of ``process`` (simulated side by side, vectorised) driven by
    smooth inputs, with white acceleration noise of density ``accel_std``."""
    t = t0 + np.arange(0.0, duration_s, dt)
    u = np.stack([smooth_inputs(t - t0, rng) for _ in range(n_runs)], axis=1)  # (n, runs, 2)
    x = np.zeros((len(t), n_runs, 6))
    x[0, :, 3] = 0.3
    w = rng.standard_normal((len(t), n_runs, 3)) * accel_std * np.sqrt(dt)
    for k in range(len(t) - 1):
        x[k + 1] = process.step(x[k], u[k], np.full(n_runs, t[k] - t0), np.full(n_runs, dt))
        x[k + 1, :, 3:] += w[k]
    return [StateSeries(f"truth_{i}", t, x[:, i], u[:, i]) for i in range(n_runs)]


def simulate_truth(process, duration_s: float, rng, **kw) -> StateSeries:
    """Return one truth run (:func:`simulate_truths`)."""
    return simulate_truths(process, duration_s, rng, 1, **kw)[0]


def fitted_oracle():
    """Return the :class:`PolyBody` process model with its process noise fitted on four 30 s truth
    runs (seed 100): the oracle the estimation and health tests filter with."""
    model = ProcessModel(PolyBody(), name="oracle")
    return fit_process_noise(model, simulate_truths(model, 30.0, np.random.default_rng(100), n_runs=4))


def clean_dgnss(truth: StateSeries, seed: int, outages: np.ndarray | None = None):
    """Return dgnss fixes of ``truth`` without multipath outliers (``simulation.gnss``), with ``outages``."""
    return simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2],
                         replace(PROFILES["dgnss"], outlier_prob=0.0), seed=seed,
                         outages=np.empty((0, 2)) if outages is None else outages)


def inputs_at(truth: StateSeries, t: np.ndarray) -> np.ndarray:
    """Return the truth's inputs held (zero-order) at the times ``t``."""
    idx = np.searchsorted(truth.t, t, side="right") - 1
    return truth.u[np.clip(idx, 0, len(truth.t) - 1)]


def truth_on(truth: StateSeries, t: np.ndarray) -> np.ndarray:
    """Return the truth's 6-state linearly interpolated at the times ``t``, (n, 6)."""
    return np.column_stack([np.interp(t, truth.t, truth.x6[:, i]) for i in range(6)])


NEES_EPOCHS = (1010.0, 1016.0, 1024.0)  # 6 s apart (errors decorrelated), one in the outage of outage_runs


def outage_runs(model, P0: np.ndarray, rng, n_runs: int = 24, duration_s: float = 26.0):
    """Return ``(truths, runs)``: truth runs of ``model`` and EKF runs under DGNSS without outliers
    with an outage from 1012 to 1020 s, each started from the truth perturbed by ``P0``."""
    from sindy_ekf.estimation.ekf import EkfRun, estimation_grid

    truths = simulate_truths(model, duration_s, rng, n_runs=n_runs)
    runs = []
    for i, truth in enumerate(truths):
        gnss = clean_dgnss(truth, seed=i, outages=np.array([[1012.0, 1020.0]]))
        t = estimation_grid(truth.t, gnss.t_valid)
        x0 = truth.x6[0] + rng.multivariate_normal(np.zeros(6), P0)
        runs.append(EkfRun(f"run_{i}", t, inputs_at(truth, t), x0, P0, gnss))
    return truths, runs


def nees_at_epochs(truth: StateSeries, res, epochs=NEES_EPOCHS) -> list[float]:
    """Return the 6-dof NEES of an EKF result against the truth at ``epochs``."""
    ref = truth_on(truth, res.t)
    out = []
    for te in epochs:
        k = np.searchsorted(res.t, te)
        e = res.x[k] - ref[k]
        out.append(float(e @ np.linalg.solve(res.P[k], e)))
    return out


def linear_gaussian_model():
    """Return the linear-Gaussian process model on which the graphs must equal the EKF: stable
    body velocities with one coupling, two inputs, a fixed ``Q_rate_``."""
    A = np.zeros((6, 6))
    A[0, 3] = A[1, 4] = A[2, 5] = 1.0
    A[3:, 3:] = -np.diag([1.0, 4.0, 2.0])
    A[3, 5] = 0.3
    B = np.zeros((6, 2))
    B[3, 0], B[5, 1] = 1.0, 0.8
    model = ProcessModel(LinearDynamics(A, B))
    model.Q_rate_ = np.diag([1e-4, 1e-4, 1e-4, 1e-2, 1e-3, 1e-2])
    return model
