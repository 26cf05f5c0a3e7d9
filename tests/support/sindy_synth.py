"""Small synthetic driving data from a KNOWN sparse model, for the identification tests.

Independent of the project's simulator on purpose: the identification must recover terms and
coefficients that the test itself chose. The body dynamics and the pose kinematics (eq. 5.75
with body velocities) are integrated with a fine fixed-step RK4 (2 ms) and sampled at 50 Hz.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from groundfloor.types import BodyStates

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
