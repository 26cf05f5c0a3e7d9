"""The GNSS measurement type the estimators consume, and its checks.

A :class:`GnssSeries` is what a receiver delivers: antenna positions in the local frame with
their reported standard deviations, each with its time of validity and its time of arrival at
the estimator. The simulator (:mod:`simulation.gnss`) writes them from ground-truth poses; a
recorded receiver is read into the same type. ``flags`` carries what a generator did
(:data:`FLAG_OUTLIER`) for scoring only: an estimator must not read it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from groundfloor.errors import InputError

log = logging.getLogger(__name__)

FLAG_OUTLIER = 1


@dataclass(frozen=True)
class GnssSeries:
    """Antenna positions as a receiver delivers them, in the local frame."""

    profile: str
    t_valid: np.ndarray  # (n,) time of validity of each fix, s (campaign time base)
    t_arrival: np.ndarray  # (n,) when the fix reached the estimator, s
    p_local: np.ndarray  # (n, 3) antenna position, m
    std: np.ndarray  # (n, 3) reported standard deviation per axis, m
    flags: np.ndarray  # (n,) uint8, generator truth (FLAG_OUTLIER); not for estimators
    lever_arm_body: np.ndarray  # (3,) antenna in the body frame, m
    outages: np.ndarray  # (m, 2) [start, end] of scheduled outages, s



def check_gnss(series: GnssSeries, source: str = "GNSS") -> tuple[GnssSeries, dict[str, int]]:
    """Return ``series`` cleaned for an estimator and the counts of what was repaired.

    Fixes with a NaN or non-positive std are dropped (counted and logged); gaps longer than
    three nominal periods outside the scheduled outages are counted and logged (an estimator
    simply dead-reckons through them). Duplicate or decreasing times of validity, or arrival
    before validity, are errors: which fix to believe cannot be decided here.
    """
    t = np.asarray(series.t_valid, dtype=float)
    repairs = {"nan_fixes_dropped": 0, "unscheduled_gaps": 0}
    if t.ndim != 1 or series.p_local.shape[0] != t.size or series.std.shape[0] != t.size:
        raise InputError(f"{source}: t_valid, p_local and std differ in length")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{source}: t_valid holds NaN/inf at index {int(np.argmin(np.isfinite(t)))}")
    dt = np.diff(t)
    if np.any(dt == 0):
        i = int(np.argmax(dt == 0))
        raise InputError(f"{source}: duplicate GNSS time of validity {t[i]:.3f} s (index {i})")
    if np.any(dt < 0):
        i = int(np.argmax(dt < 0))
        raise InputError(f"{source}: GNSS times of validity decrease at index {i + 1} ({t[i + 1]:.3f} s)")
    if np.any(series.t_arrival < t):
        i = int(np.argmax(series.t_arrival < t))
        raise InputError(f"{source}: GNSS fix {i} arrives before its time of validity")
    bad = ~np.all(np.isfinite(series.p_local[:, :2]), axis=1) | ~np.all(series.std[:, :2] > 0, axis=1)
    bad |= ~np.all(np.isfinite(series.std[:, :2]), axis=1)
    if bad.any():
        repairs["nan_fixes_dropped"] = int(bad.sum())
        log.warning("%s: dropped %d GNSS fixes with NaN position or invalid std", source, bad.sum())
        keep = ~bad
        series = replace(series, t_valid=t[keep], t_arrival=series.t_arrival[keep],
                         p_local=series.p_local[keep], std=series.std[keep], flags=series.flags[keep])
        t = series.t_valid
    if t.size > 2:
        period = float(np.median(np.diff(t)))
        gap_start = t[:-1][np.diff(t) > 3.0 * period]
        in_outage = np.any((gap_start[:, None] >= series.outages[:, 0] - 3.0 * period)
                           & (gap_start[:, None] < series.outages[:, 1]), axis=1) \
            if series.outages.size else np.zeros(gap_start.size, bool)
        repairs["unscheduled_gaps"] = int((~in_outage).sum())
        if repairs["unscheduled_gaps"]:
            log.warning("%s: %d GNSS gaps longer than 3 periods outside scheduled outages "
                        "(dead reckoning through them)", source, repairs["unscheduled_gaps"])
    return series, repairs
