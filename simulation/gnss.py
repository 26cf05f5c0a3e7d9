"""Degraded GNSS positions generated from ground-truth poses (laser tracker or simulator).

The thesis's outlook (chapter 7) proposes "simulating GNSS data based on the laser tracker
measurements with different measurement frequencies and precision levels"; this module does it.
An antenna at a lever arm ``lever_arm_body`` on the robot is moved with the true pose; each
profile samples it at its own epochs (exact multiples of its period on the campaign's time
base), adds white noise, for ``standalone`` a slowly wandering first-order Gauss-Markov bias, and
multipath outliers, and delivers each fix ``latency_s`` (plus an exponential jitter) after its
time of validity. Scheduled outages remove every fix whose time of validity falls inside them.
All of it in the local metric frame of the poses, seeded through ``np.random.default_rng``.

The series is a :class:`groundfloor.gnss.GnssSeries`, the type the estimators consume;
``flags`` carries what the generator did (``FLAG_OUTLIER``) for scoring only.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from groundfloor.errors import InputError
from groundfloor.gnss import FLAG_OUTLIER, GnssSeries

log = logging.getLogger(__name__)

OUTAGE_DURATIONS_S = (5.0, 10.0, 30.0, 60.0)


@dataclass(frozen=True)
class GnssProfile:
    """Error budget of one receiver class (all standard deviations per axis, metres)."""

    name: str
    rate_hz: float
    std_m: float  # white horizontal noise per axis
    std_up_m: float  # white vertical noise
    latency_s: float  # mean delay from time of validity to arrival
    latency_jitter_s: float  # mean of the exponential extra delay
    bias_std_m: float = 0.0  # stationary std of the Gauss-Markov bias per axis
    bias_tau_s: float = 300.0  # its correlation time
    outlier_prob: float = 0.0  # probability that a fix is hit by multipath
    outlier_m: tuple[float, float] = (0.0, 0.0)  # range of the multipath offset, metres

    @property
    def reported_std_m(self) -> float:
        """Horizontal std the receiver reports per axis: white noise and bias together."""
        return float(np.hypot(self.std_m, self.bias_std_m))


PROFILES: dict[str, GnssProfile] = {
    "rtk": GnssProfile("rtk", 10.0, 0.02, 0.04, 0.05, 0.01, outlier_prob=0.002, outlier_m=(0.2, 0.5)),
    "dgnss": GnssProfile("dgnss", 5.0, 0.3, 0.6, 0.1, 0.02, outlier_prob=0.01, outlier_m=(2.0, 5.0)),
    "standalone": GnssProfile("standalone", 1.0, 1.0, 2.5, 0.2, 0.05, bias_std_m=1.1,
                              bias_tau_s=300.0, outlier_prob=0.02, outlier_m=(5.0, 15.0)),
}


def schedule_outages(t_start: float, t_end: float, durations=OUTAGE_DURATIONS_S,
                     warmup_s: float = 30.0, recovery_s: float = 30.0) -> np.ndarray:
    """Return outage intervals ``(m, 2)``: the durations in turn, each after ``recovery_s`` of GNSS.

    The first outage begins ``warmup_s`` after ``t_start`` so that every estimator has converged;
    the cycle of durations repeats while a whole outage still fits before ``t_end``.
    """
    out = []
    t = t_start + warmup_s
    i = 0
    while durations:
        d = durations[i % len(durations)]
        if t + d > t_end:
            break
        out.append((t, t + d))
        t += d + recovery_s
        i += 1
    return np.array(out, dtype=float).reshape(-1, 2)


def simulate_gnss(t: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray,
                  profile: str | GnssProfile = "dgnss", seed: int = 0, z: np.ndarray | None = None,
                  lever_arm_body=(-0.2, 0.1, 0.5), outages: np.ndarray | None = None) -> GnssSeries:
    """Return a degraded GNSS series of the antenna on a robot following the given poses.

    Parameters
    ----------
    t, x, y, yaw : (n,) arrays
        Ground-truth poses in the local frame (yaw wrapped or unwrapped), strictly increasing t.
    profile : name in :data:`PROFILES` or a :class:`GnssProfile`.
    seed : seed of ``np.random.default_rng``.
    z : optional (n,) height of the body origin (NaN or None: 0).
    lever_arm_body : antenna position in the body frame, m.
    outages : (m, 2) intervals without GNSS; default :func:`schedule_outages` over the run.
    """
    if isinstance(profile, str):
        if profile not in PROFILES:
            raise InputError(f"GNSS profile {profile!r} unknown (choose from {', '.join(PROFILES)})")
        profile = PROFILES[profile]
    t = np.asarray(t, dtype=float)
    if t.size < 2 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
        raise InputError("poses t: need at least two strictly increasing finite stamps for GNSS")
    rng = np.random.default_rng(seed)
    lever = np.asarray(lever_arm_body, dtype=float)
    if outages is None:
        outages = schedule_outages(t[0], t[-1])
    period = 1.0 / profile.rate_hz
    t_valid = np.arange(np.ceil(t[0] / period), np.floor(t[-1] / period) + 1) * period
    t_valid = t_valid[(t_valid >= t[0]) & (t_valid <= t[-1])]
    yaw_v = np.interp(t_valid, t, np.unwrap(yaw))
    c, s = np.cos(yaw_v), np.sin(yaw_v)
    z = np.zeros_like(t) if z is None else np.nan_to_num(np.asarray(z, dtype=float))
    p = np.column_stack([np.interp(t_valid, t, x) + c * lever[0] - s * lever[1],
                         np.interp(t_valid, t, y) + s * lever[0] + c * lever[1],
                         np.interp(t_valid, t, z) + lever[2]])
    n = len(t_valid)
    white_std = np.array([profile.std_m, profile.std_m, profile.std_up_m])
    p += rng.standard_normal((n, 3)) * white_std
    if profile.bias_std_m > 0:
        # exact discretisation of a first-order Gauss-Markov process, started stationary
        phi = np.exp(-period / profile.bias_tau_s)
        drive = rng.standard_normal((n, 3)) * profile.bias_std_m * np.sqrt(1.0 - phi ** 2)
        drive[0] = rng.standard_normal(3) * profile.bias_std_m
        p += lfilter([1.0], [1.0, -phi], drive, axis=0)
    flags = np.zeros(n, dtype=np.uint8)
    hit = rng.random(n) < profile.outlier_prob
    if hit.any():
        ang = rng.uniform(0, 2 * np.pi, hit.sum())
        mag = rng.uniform(*profile.outlier_m, hit.sum())
        p[hit, 0] += mag * np.cos(ang)
        p[hit, 1] += mag * np.sin(ang)
        flags[hit] |= FLAG_OUTLIER
    t_arrival = t_valid + profile.latency_s + rng.exponential(profile.latency_jitter_s, n)
    keep = ~np.any((t_valid[:, None] >= outages[:, 0]) & (t_valid[:, None] < outages[:, 1]), axis=1)
    rep_std = np.array([profile.reported_std_m, profile.reported_std_m,
                        np.hypot(profile.std_up_m, profile.bias_std_m)])
    return GnssSeries(profile.name, t_valid[keep], t_arrival[keep], p[keep],
                      np.tile(rep_std, (keep.sum(), 1)), flags[keep], lever, outages)
