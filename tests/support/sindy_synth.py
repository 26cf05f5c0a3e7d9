"""Small synthetic driving data from a KNOWN sparse model, for the identification tests.

Independent of the project's simulator on purpose: the identification must recover terms and
coefficients that the test itself chose. The body dynamics and the pose kinematics (eq. 5.75
with body velocities) are integrated with a fine fixed-step RK4 (2 ms) and sampled at 50 Hz.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from groundfloor.types import BodyStates, InputSeries, PoseTrack, TrajectoryRun

# A sparse model in the spirit of the thesis's eqs. 7.4 to 7.9 (friction, throttle, turning).
SPARSE_TERMS = {
    "vx": {"vx": -5.0, "u1": 4.5, "vx omega^2": -2.0},
    "vy": {"vy": -4.0, "vx omega": 1.5},
    "omega": {"omega": -6.0, "u2": 7.0, "omega^3": -1.5},
}


def sparse_f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Return body accelerations of :data:`SPARSE_TERMS` (written out by hand, not via the library)."""
    vx, vy, om = x[..., 0], x[..., 1], x[..., 2]
    u1, u2 = u[..., 0], u[..., 1]
    return np.stack([-5.0 * vx + 4.5 * u1 - 2.0 * vx * om**2,
                     -4.0 * vy + 1.5 * vx * om,
                     -6.0 * om + 7.0 * u2 - 1.5 * om**3], axis=-1)


def smooth_inputs(duration_s: float, rng: np.random.Generator, knot_s: float = 1.2):
    """Return a function t -> u (n, 2): random knots in [-1, 1] every ``knot_s``, PCHIP between."""
    t_knots = np.arange(0.0, duration_s + 2 * knot_s, knot_s)
    u_knots = np.clip(rng.normal(0.0, 0.6, size=(len(t_knots), 2)), -1, 1)
    u_knots[rng.random(len(t_knots)) < 0.15] = 0.0  # pauses, as a human driver makes
    return PchipInterpolator(t_knots, u_knots, axis=0)


def simulate_states(duration_s: float, seeds, f=sparse_f, noise_std: float = 0.002,
                    rate_hz: float = 50.0, dt: float = 0.004) -> list[BodyStates]:
    """Return one 50 Hz BodyStates per seed (small velocity noise) of ``f`` under smooth random inputs.

    All runs are integrated together (RK4, fixed step ``dt``, vectorised over runs).
    """
    seeds = [seeds] if np.isscalar(seeds) else list(seeds)
    rngs = [np.random.default_rng(seed) for seed in seeds]
    n = int(round(duration_s / dt))
    t = np.arange(n + 1) * dt
    u_fun = [smooth_inputs(duration_s, rng) for rng in rngs]
    u_all = np.stack([uf(t) for uf in u_fun], axis=1)  # (n+1, runs, 2)
    u_half = np.stack([uf(t[:-1] + dt / 2) for uf in u_fun], axis=1)

    def g(s, u):
        c, sn = np.cos(s[:, 2]), np.sin(s[:, 2])
        kin = np.stack([s[:, 3] * c - s[:, 4] * sn, s[:, 3] * sn + s[:, 4] * c, s[:, 5]], axis=-1)
        return np.concatenate([kin, f(s[:, 3:], u)], axis=-1)

    s = np.zeros((n + 1, len(seeds), 6))
    s[0, :, 3] = 0.2
    for i in range(n):  # time loop only; vectorised over runs
        k1 = g(s[i], u_all[i])
        k2 = g(s[i] + dt / 2 * k1, u_half[i])
        k3 = g(s[i] + dt / 2 * k2, u_half[i])
        k4 = g(s[i] + dt * k3, u_all[i + 1])
        s[i + 1] = s[i] + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = int(round(1 / (rate_hz * dt)))
    idx = np.arange(0, n + 1, step)
    out = []
    for r, rng in enumerate(rngs):
        v = s[idx, r, 3:] + rng.normal(0.0, noise_std, size=(len(idx), 3))
        out.append(BodyStates(t=t[idx] + 1000.0, vx=v[:, 0], vy=v[:, 1], omega=v[:, 2], u1=u_all[idx, r, 0],
                              u2=u_all[idx, r, 1], x=s[idx, r, 0], y=s[idx, r, 1], yaw=s[idx, r, 2]))
    return out


def lag_f(k_v: float = 1.8, tau_v: float = 0.3, k_w: float = 1.2, tau_w: float = 0.2):
    """Return the body accelerations of a first-order lag per axis (``vy`` decaying with ``tau_v``)."""
    def f(x, u):
        return np.stack([(k_v * u[..., 0] - x[..., 0]) / tau_v, -x[..., 1] / tau_v,
                         (k_w * u[..., 1] - x[..., 2]) / tau_w], axis=-1)
    return f


def simulate_trajectory_runs(duration_s: float, seeds, f=sparse_f, dead_time_s=(0.0, 0.0),
                             pose_std_m: float = 1e-4, yaw_std_rad: float = 1e-4, rate_hz: float = 50.0,
                             msg_hz: float = 20.0, dt: float = 0.005, inputs=None,
                             input_lag_s=(0.0, 0.0)) -> list[TrajectoryRun]:
    """Return one TrajectoryRun per seed of ``f`` driven by recorded command messages seen late.

    The inputs are messages at ``msg_hz`` sampled from smooth random inputs (or ``inputs``, a
    function ``(t, rng) -> (n, 2)``); the system holds each message (zero-order hold) and sees it
    ``dead_time_s`` late, so the recording is exact and only the dead time separates it from what
    the system saw (keep the dead times multiples of ``dt`` so that the switches fall on steps).
    With ``input_lag_s`` ``(T1, T2)`` it sees them through first-order lags, integrated as two
    more states of the same RK4 (``T w' = u - w``, at rest on the first message): a motor lag
    written here independently of ``groundfloor.input_chain``.
    Poses at ``rate_hz`` with white noise of the given sigmas (and those sigmas in the pose
    track); fixed-step RK4 at ``dt``, all runs at once.
    """
    seeds = [seeds] if np.isscalar(seeds) else list(seeds)
    rngs = [np.random.default_rng(seed) for seed in seeds]
    t_msg = np.arange(0.0, duration_s + 1.0, 1.0 / msg_hz)
    u_msg = np.stack([smooth_inputs(duration_s, rng)(t_msg) if inputs is None else inputs(t_msg, rng)
                      for rng in rngs], axis=1)  # (messages, runs, 2)
    d = np.asarray(dead_time_s, float)
    n = int(round(duration_s / dt))
    t = np.arange(n + 1) * dt

    def u_at(tt):
        k = np.clip(np.searchsorted(t_msg, tt[:, None] - d[None, :] + 1e-9, side="right") - 1, 0, len(t_msg) - 1)
        return np.stack([u_msg[k[:, 0], :, 0], u_msg[k[:, 1], :, 1]], axis=-1)  # (times, runs, 2)

    u0, uh = u_at(t), u_at(t[:-1] + dt / 2)

    lag = np.asarray(input_lag_s, float)
    lagged = lag > 0

    def g(s, u):
        # s: (runs, 8) = six states and the two lagged inputs (an input without lag is seen as held)
        w = np.where(lagged, s[:, 6:], u)
        c, sn = np.cos(s[:, 2]), np.sin(s[:, 2])
        kin = np.stack([s[:, 3] * c - s[:, 4] * sn, s[:, 3] * sn + s[:, 4] * c, s[:, 5]], axis=-1)
        dw = np.where(lagged, (u - s[:, 6:]) / np.where(lagged, lag, 1.0), 0.0)
        return np.concatenate([kin, f(s[:, 3:6], w), dw], axis=-1)

    s = np.zeros((n + 1, len(seeds), 8))
    s[0, :, 6:] = u0[0]
    for i in range(n):
        k1 = g(s[i], u0[i])
        k2 = g(s[i] + dt / 2 * k1, uh[i])
        k3 = g(s[i] + dt / 2 * k2, uh[i])
        k4 = g(s[i] + dt * k3, u0[i + 1])
        s[i + 1] = s[i] + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    idx = np.arange(0, n + 1, int(round(1 / (rate_hz * dt))))
    m = len(idx)
    keep = t_msg <= duration_s
    runs = []
    for r, (seed, rng) in enumerate(zip(seeds, rngs)):
        noise = rng.normal(size=(m, 3)) * [pose_std_m, pose_std_m, yaw_std_rad]
        nan = np.full(m, np.nan)
        t0 = 1000.0 * (r + 1)
        poses = PoseTrack(t=t[idx] + t0, x=s[idx, r, 0] + noise[:, 0], y=s[idx, r, 1] + noise[:, 1], z=nan,
                          pitch=nan, yaw=s[idx, r, 2] + noise[:, 2], x_std=np.full(m, pose_std_m),
                          y_std=np.full(m, pose_std_m), z_std=nan, pitch_std=nan, yaw_std=np.full(m, yaw_std_rad))
        runs.append(TrajectoryRun(name=f"run_{seed}", split="train", poses=poses,
                                  inputs=InputSeries(t=t_msg[keep] + t0, u1=u_msg[keep, r, 0], u2=u_msg[keep, r, 1])))
    return runs
