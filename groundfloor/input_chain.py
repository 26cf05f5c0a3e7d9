"""What a model's motors see of the recorded inputs: a dead time, then a first-order lag, per input.

A :class:`~groundfloor.dynamics.Dynamics` may see its inputs late and smoothed: input ``i`` is
recorded as ``u_i(t)``; the model sees ``w_i(t)`` with

.. math::  T_i \\dot w_i(t) = u_i(t - d_i) - w_i(t),

a dead time ``d_i`` (:attr:`Dynamics.dead_time_s`) followed by a first-order lag of time constant
``T_i`` (:attr:`Dynamics.input_lag_s`; ``T_i = 0`` is no lag, ``w_i = u_i(t - d_i)``). That is a
motor's (or a velocity controller's) response to its command, which no function of the body
velocities can express: a model with a dead time alone sees a step of the command all at once,
a motor with a 0.2 s lag does not (the simulator's variants, ``simulation.actuator``, have one).
The lag's state starts at rest on the first input (``w(t_0) = u(t_0 - d)``).

Both are linear and time-invariant, so they commute: the lag is applied to the inputs on a
uniform grid (:func:`first_order_lag`, exact for inputs linear between the grid points), and the
dead time is a shift of the lagged signal. Everything that drives a model (the multi-step
evaluation's input tracks, the filters, the integral regression, the diagnosis) calls
:func:`chain_inputs` or :func:`first_order_lag`, so the chain is written once.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: step of the uniform grid the lag is computed on, s (at most; the samples' own when finer)
LAG_GRID_S = 0.01
#: the same for held command messages (a switch falls between grid points: at most this late)
HELD_LAG_GRID_S = 0.001


def sees_recorded_inputs(dynamics) -> bool:
    """Return whether ``dynamics`` sees the recorded inputs as they are (no dead time, no input lag)."""
    return not np.any(getattr(dynamics, "dead_time_s", 0.0)) and not np.any(getattr(dynamics, "input_lag_s", 0.0))


def first_order_lag(u: np.ndarray, step_s: float, lag_s, hold: str = "linear") -> np.ndarray:
    """Return the first-order lag ``T w' = u - w`` of ``u (n, 2)`` sampled every ``step_s``.

    Exact over one step with ``a = exp(-h / T)``: for an input linear between the samples
    (``hold="linear"``, first-order hold) ``w_{k+1} = a w_k + (1 - c) u_{k+1} + (c - a) u_k`` with
    ``c = T (1 - a) / h``; for an input held from each sample to the next (``hold="zoh"``,
    command messages) ``w_{k+1} = a w_k + (1 - a) u_k``. The lag starts at rest on the first
    sample. ``lag_s`` is ``(2,)``; an input with ``T_i = 0`` is returned unchanged.
    """
    u = np.asarray(u, dtype=float)
    out = u.copy()
    lags = np.asarray(lag_s, dtype=float).reshape(-1)[:2]
    out[:, :len(lags)] = first_order_lags(u.T, step_s, range(len(lags)), lags, hold).T
    return out


def first_order_lags(u: np.ndarray, step_s: float, rows, lags_s, hold: str = "linear") -> np.ndarray:
    """Return ``(k, n)``: row ``u[rows[j]]`` of the inputs ``u (c, n)`` through a first-order lag
    of time constant ``lags_s[j]`` (:func:`first_order_lag`'s recursion), for each ``j``, in one
    compiled pass; a row with ``lags_s[j] <= 0`` is its input unchanged.

    The recursion's steps each wait on the one before (a multiply-add's latency per sample); run
    side by side, independent recursions fill that wait: an output-error fit asks for a lag of both
    inputs and the two either side of each (the lag sensitivities) at every step, six recursions in
    the time of two, to the same bits. Compiled: the fits ask for a few hundred lags of every
    segment's inputs, where a filter call's overhead outweighed the filtering.
    """
    u = np.ascontiguousarray(u, dtype=float)
    rows = np.asarray(rows, dtype=np.intp)
    lags = np.asarray(lags_s, dtype=float)
    on = np.flatnonzero(lags > 0.0)
    T = lags[on]
    a = np.exp(-step_s / T)
    c = T * (1.0 - a) / step_s if hold == "linear" else np.ones_like(T)
    out = u[rows].copy()  # the unlagged rows as they are
    if len(on):
        out[on] = _lag_recursions(u, rows[on], a, 1.0 - c, c - a)
    return out


@njit(cache=True)
def _lag_recursions(u: np.ndarray, rows: np.ndarray, a: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Return ``w (k, n)``: ``w_j0 = u_(r_j, 0)``, ``w_(j, k+1) = a_j w_jk + b0_j u_(r_j, k+1) + b1_j u_(r_j, k)``.

    Four recursions at a time, each carried in a scalar (a register: four cost what one does); a
    group short of four repeats its last recursion.
    """
    k, n = rows.shape[0], u.shape[1]
    w = np.empty((k, n))
    for g in range(0, k, 4):
        j0, j1, j2, j3 = g, min(g + 1, k - 1), min(g + 2, k - 1), min(g + 3, k - 1)
        u0, u1, u2, u3 = u[rows[j0]], u[rows[j1]], u[rows[j2]], u[rows[j3]]
        w0, w1, w2, w3 = w[j0], w[j1], w[j2], w[j3]
        a0, a1, a2, a3 = a[j0], a[j1], a[j2], a[j3]
        p0, p1, p2, p3 = b0[j0], b0[j1], b0[j2], b0[j3]
        q0, q1, q2, q3 = b1[j0], b1[j1], b1[j2], b1[j3]
        c0, c1, c2, c3 = u0[0], u1[0], u2[0], u3[0]
        w0[0], w1[0], w2[0], w3[0] = c0, c1, c2, c3
        for t in range(n - 1):
            c0 = a0 * c0 + p0 * u0[t + 1] + q0 * u0[t]
            c1 = a1 * c1 + p1 * u1[t + 1] + q1 * u1[t]
            c2 = a2 * c2 + p2 * u2[t + 1] + q2 * u2[t]
            c3 = a3 * c3 + p3 * u3[t + 1] + q3 * u3[t]
            w0[t + 1], w1[t + 1], w2[t + 1], w3[t + 1] = c0, c1, c2, c3
    return w


def lag_grid(t: np.ndarray, step_s: float = LAG_GRID_S) -> np.ndarray:
    """Return the uniform grid over ``[t[0], t[-1]]`` the lag is computed on (step at most ``step_s``)."""
    t = np.asarray(t, dtype=float)
    n = max(int(np.ceil((t[-1] - t[0]) / step_s)), 1)
    return np.linspace(t[0], t[-1], n + 1)


def chain_inputs(t_query: np.ndarray, t: np.ndarray, u: np.ndarray, dead_time_s=(0.0, 0.0),
                 input_lag_s=(0.0, 0.0)) -> np.ndarray:
    """Return what a model sees at ``t_query`` of inputs ``u (m, 2)`` sampled at ``t (m,)``, ``(..., 2)``.

    The samples are joined by straight lines (inputs sampled at the pose times), lagged by
    ``input_lag_s`` on a uniform grid (:func:`first_order_lag`) and delayed by ``dead_time_s``;
    before the first sample the first value holds, after the last the last.
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    tq = np.asarray(t_query, dtype=float)
    d = np.asarray(dead_time_s, dtype=float)
    lag = np.asarray(input_lag_s, dtype=float)
    if np.any(lag > 0.0) and len(t) > 1:
        grid = lag_grid(t)
        w = first_order_lag(np.column_stack([np.interp(grid, t, u[:, i]) for i in range(2)]),
                            float(grid[1] - grid[0]), lag)
        t, u = grid, w
    return np.stack([np.interp(tq - d[i], t, u[:, i]) for i in range(2)], axis=-1)
