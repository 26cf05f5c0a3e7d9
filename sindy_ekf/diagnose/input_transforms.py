"""The input-side mechanisms' transforms: what the motors see of the recorded inputs.

Each function returns the motor inputs ``(C, N, 2)`` for ``C`` candidate parameters at once
(vectorised over candidates and samples); :class:`sindy_ekf.diagnose.families.Family` dispatches
to them (:meth:`~sindy_ekf.diagnose.families.Family.motor_inputs`). The delay, the lag and the
deadbands take one parameter per candidate for both inputs ``(C,)``, or one per input ``(C, 2)``
(the per-input mechanisms of :mod:`sindy_ekf.diagnose.per_input`).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def _clip(u: np.ndarray) -> np.ndarray:
    """Return ``u`` within the joystick's range [-1, 1]."""
    return np.clip(u, -1.0, 1.0)


def per_input(values) -> np.ndarray:
    """Return candidate parameters as ``(C, 2)``: ``(C,)`` holds one value for both inputs."""
    v = np.asarray(values, float)
    return np.repeat(np.atleast_1d(v)[:, None], 2, axis=1) if v.ndim <= 1 else v.reshape(len(v), 2)


def inputs_delayed(t_run: np.ndarray, u: np.ndarray, slices, delay_s: np.ndarray) -> np.ndarray:
    """Return inputs ``(C, N, 2)`` delayed by each ``delay_s`` (C,) or (C, 2): ``u_m(t) = u(t - d)`` per run.

    Linear interpolation between samples, the first sample held before a run's start.
    """
    d = per_input(delay_s)
    out = np.empty((len(d),) + u.shape)
    for sl in slices:  # a handful of runs; vectorised over candidates and samples
        t = t_run[sl]
        for j in range(2):
            tq = (t[None, :] - d[:, j:j + 1]).ravel()
            out[:, sl, j] = np.interp(tq, t, u[sl, j]).reshape(len(d), -1)
    return out


def inputs_deadband(u: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """Return ``sign(u) max(|u| - v, 0) / (1 - v)`` per threshold ``v`` (C,) or (C, 2), shape ``(C, N, 2)``."""
    v = per_input(threshold)[:, None, :]
    return _clip(np.sign(u) * np.maximum(np.abs(u) - v, 0.0) / (1.0 - v))


def inputs_smooth_deadband(u: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """Return a deadband with a smooth onset per threshold ``v`` (C,) or (C, 2), shape ``(C, N, 2)``.

    ``sign(u) q(|u|) / (1 - v)`` with ``q(a) = a^2 / (4 v)`` below ``2 v`` and ``a - v`` above: the
    motors start at any input, quadratically (friction overcome gradually), and far from zero the
    response is the hard deadband's; ``q`` and its slope are continuous at ``2 v`` (for ``v <= 0.5``).
    """
    v = per_input(threshold)[:, None, :]
    a = np.abs(u)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(a < 2.0 * v, a * a / (4.0 * np.where(v > 0, v, 1.0)), a - v)
    return _clip(np.sign(u) * q / (1.0 - v))


def inputs_battery(u: np.ndarray, t_run: np.ndarray, decay_per_10min: np.ndarray) -> np.ndarray:
    """Return ``u (1 - r t / 600 s)`` per decay ``r`` (C,) with ``t`` since the run start, ``(C, N, 2)``."""
    r = np.atleast_1d(np.asarray(decay_per_10min, float))[:, None]
    return _clip(u[None] * np.maximum(1.0 - r * t_run[None, :] / 600.0, 0.0)[..., None])


def inputs_coupling(u: np.ndarray, coupling: np.ndarray) -> np.ndarray:
    """Return throttle-to-turn coupled inputs ``[u1, u2 + c u1]`` per coupling ``c`` (C,), ``(C, N, 2)``."""
    c = np.atleast_1d(np.asarray(coupling, float))[:, None]
    out = np.repeat(u[None], len(c), axis=0)
    out[..., 1] = u[None, :, 1] + c * u[None, :, 0]
    return _clip(out)


def inputs_steering_offset(u: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Return inputs with the steering offset by ``o`` (C,): ``[u1, u2 + o]``, ``(C, N, 2)``."""
    o = np.atleast_1d(np.asarray(offset, float))[:, None]
    out = np.repeat(u[None], len(o), axis=0)
    out[..., 1] = u[None, :, 1] + o
    return _clip(out)


def inputs_lagged(t_run: np.ndarray, u: np.ndarray, slices, lag_s: np.ndarray) -> np.ndarray:
    """Return inputs through a first-order actuator lag ``T u_m' = u - u_m`` per ``T`` (C,) or (C, 2),
    ``(C, N, 2)``.

    Exact for inputs linear between samples (the first-order hold's discretisation); each run
    starts at rest on its first input; ``T = 0`` passes the inputs through.
    """
    T = per_input(lag_s)
    out = np.repeat(u[None], len(T), axis=0).astype(float)
    live = (T > 0).any(axis=1)
    if not live.any():
        return out
    Tl = T[live][:, None, :]  # (C, 1, 2); a zero lag on one input passes it through (a = 0)
    for sl in slices:
        t, uu = t_run[sl], u[sl]
        h = np.diff(t)[None, :, None]  # (1, N-1, 1)
        with np.errstate(divide="ignore"):
            a = np.exp(-h / Tl)  # (C, N-1, 2)
        slope = np.divide(np.diff(uu, axis=0)[None], h, out=np.zeros((1,) + uu[1:].shape), where=h > 0)
        # over a step of length h with u(s) = u0 + slope s: y1 = u1 - slope T - (u0 - slope T - y0) exp(-h/T)
        c = uu[1:][None] - slope * Tl - (uu[:-1][None] - slope * Tl) * a  # (C, N-1, 2)
        ys = np.empty((len(Tl), len(t), 2))
        ys[:, 0] = uu[0]
        hv = h[0, :, 0]
        edges = np.concatenate([[0], np.flatnonzero(np.abs(np.diff(hv)) > 1e-9 * hv[1:]) + 1, [len(hv)]])
        if len(t) > 1 and len(edges) < len(t) / 20:  # stretches of even sampling: a linear filter each
            y = ys[:, 0].copy()
            for s0, e0 in zip(edges[:-1], edges[1:]):
                for i in range(len(Tl)):
                    if Tl[i, 0, 0] == Tl[i, 0, 1]:  # one lag for both inputs: one filter over both
                        ai = a[i, s0, 0]
                        ys[i, s0 + 1:e0 + 1] = lfilter([1.0], [1.0, -ai], c[i, s0:e0], axis=0,
                                                       zi=ai * y[i][None])[0]
                        continue
                    for j in range(2):
                        ai = a[i, s0, j]
                        ys[i, s0 + 1:e0 + 1, j] = lfilter([1.0], [1.0, -ai], c[i, s0:e0, j], zi=[ai * y[i, j]])[0]
                y = ys[:, e0].copy()
            out[live, sl] = ys
            continue
        y = ys[:, 0].copy()
        for k in range(len(t) - 1):  # the recursion itself, vectorised over candidates
            y = c[:, k] + a[:, k] * y
            ys[:, k + 1] = y
        out[live, sl] = ys
    return out


def inputs_imbalance(u: np.ndarray, imbalance: np.ndarray) -> np.ndarray:
    """Return track-imbalance inputs ``[u1 + a/2 u2, u2 + a/2 u1]`` per imbalance ``a`` (C,), ``(C, N, 2)``."""
    h = np.atleast_1d(np.asarray(imbalance, float))[:, None, None] / 2.0
    return _clip(u[None] + h * u[None, :, ::-1])
