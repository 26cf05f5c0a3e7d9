"""Step versus drift: whether a NIS alarm is a step of the GNSS fixes or a lost filter.

:func:`fixes_stepped` weighs the innovations of an alarm between levels of the fixes with steps
between them and a smooth drift of the filter (Basseville and Nikiforov 1993, ch. 2 and 4); the
monitor of :mod:`sindy_ekf.benchmark.health` resets the filter only when the fixes did not step.
docs/robustness.md, section 2, says why each rule is there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from sindy_ekf.estimation.ekf import GATE_PROB

STEP_FALSE_ALARM = 1e-3  # of the step model's residual test
_OUTLIER_NIS = float(chi2.ppf(0.999, 2))  # a fix this far from its neighbours' median is an outlier
_GATE_NIS = float(chi2.ppf(GATE_PROB, 2))  # a level of the fixes inside the filter's gate agrees with it


def _segment_rss(w: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return ``rss[a, b]``, the weighted residual sum of squares of ``y[a:b]`` about its weighted
    mean (``w (n,)`` weights, ``y (n, 2)``), for all ``0 <= a <= b <= n`` (0 where empty)."""
    c_w = np.concatenate([[0.0], np.cumsum(w)])
    c_wy = np.concatenate([np.zeros((1, 2)), np.cumsum(w[:, None] * y, axis=0)])
    c_wyy = np.concatenate([[0.0], np.cumsum(w * np.sum(y * y, axis=1))])
    sw = c_w[None, :] - c_w[:, None]
    swy = c_wy[None, :, :] - c_wy[:, None, :]
    swyy = c_wyy[None, :] - c_wyy[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        rss = swyy - np.sum(swy * swy, axis=-1) / sw
    return np.where(sw > 0, rss, 0.0)


MAX_LEVELS = 8  # levels of the fixes told apart in one test window: up to 7 steps in 8 s
MIN_LEVEL_FIXES = 2  # a level held by one fix is an outlier, not a level
# outliers are isolated by definition: a consistent series leaves about 1 in 1000 fixes beyond the
# 0.999 quantile, a series scattering three times its stated std leaves half of them
MAX_OUTLIER_SHARE = 0.2


def _partitions(rss: np.ndarray, max_levels: int, min_len: int = MIN_LEVEL_FIXES) -> tuple[np.ndarray, np.ndarray]:
    """Return the least residual sum of ``y[:n]`` in ``k`` levels for ``k = 0..max_levels`` and the
    split points (optimal partitioning by dynamic programming, Jackson et al. 2005).

    ``rss`` is :func:`_segment_rss`'s ``(n + 1, n + 1)`` table. ``cost[k]`` is the least sum over
    partitions of all fixes into ``k`` levels of at least ``min_len`` fixes (inf where none),
    ``arg[k, b]`` the start of the last level of the best partition of ``y[:b]``.
    """
    n = rss.shape[0] - 1
    a, b = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    seg = np.where(b - a >= min_len, rss, np.inf)
    cost = np.full((max_levels + 1, n + 1), np.inf)
    cost[0, 0] = 0.0
    arg = np.zeros((max_levels + 1, n + 1), int)
    for k in range(1, max_levels + 1):
        total = cost[k - 1][:, None] + seg
        arg[k] = np.argmin(total, axis=0)
        cost[k] = total[arg[k], np.arange(n + 1)]
    return cost, arg


def _drift_rss(w: np.ndarray, y: np.ndarray, t: np.ndarray) -> float:
    """Return the weighted residual sum of ``y (n, 2)`` about a quadratic in ``t`` per coordinate."""
    tau = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
    A = np.column_stack([np.ones_like(tau), tau, tau ** 2]) * np.sqrt(w)[:, None]
    yw = y * np.sqrt(w)[:, None]
    coef = np.linalg.lstsq(A, yw, rcond=None)[0]
    return float(np.sum((yw - A @ coef) ** 2))


NEIGHBOURS = 5  # fixes of the running median an outlier is measured from (itself among them)


def _local_median(y: np.ndarray, width: int = NEIGHBOURS) -> np.ndarray:
    """Return per row of ``y (n, 2)`` the median of the ``width`` consecutive rows centred on it,
    the window shifted inward at the ends (not padded with the end row: a padded end row would be
    most of its own window, so an outlier at the window's edge would be its own median)."""
    n = len(y)
    width = min(width, n)
    lo = np.clip(np.arange(n) - width // 2, 0, n - width)
    return np.median(y[lo[:, None] + np.arange(width)], axis=1)


def fixes_stepped(innovation: np.ndarray, innovation_cov: np.ndarray, t: np.ndarray | None = None,
                  need_step: bool = False, false_alarm: float = STEP_FALSE_ALARM) -> bool:
    """Return whether the innovations ``(n, 2)`` are a piecewise-constant offset plus noise.

    Two hypotheses about an alarm (Basseville and Nikiforov 1993, ch. 2 and 4), weights
    ``2 / trace S`` per fix, isolated outliers (farther than the chi2(2) 0.999 quantile from the
    running median of five fixes, :func:`_local_median`) left out first:

    - **the fixes stepped**: the innovations are levels with steps between them (the fewest
      levels, at most :data:`MAX_LEVELS`, whose optimal partition passes the ``1 - false_alarm``
      quantile of chi-square with ``2 n - 2 k`` degrees of freedom); overlapping multipath bursts
      give several levels in a few seconds;
    - **the filter drifts**: the innovations follow a smooth curve, a quadratic in time per
      coordinate (a lost filter's position error grows with its velocity and heading error).

    The fixes stepped when the levels pass their test and explain the window better than the
    drift by the Bayesian information criterion (each level's mean and each step time against
    the quadratic's six coefficients): a staircase can follow a drift, but only with more levels
    than the curve has coefficients. With ``need_step`` (the first alarm of an episode) a step
    must lie inside the window, and one level must agree with the filter (its mean inside the
    gate): a constant offset there, or fixes that never agreed, is a filter off before it.
    ``t`` are the fixes' times (default: evenly spaced).
    """
    y = np.asarray(innovation, float)
    S = np.asarray(innovation_cov, float)
    t = np.arange(len(y), dtype=float) if t is None else np.asarray(t, float)
    ok = np.all(np.isfinite(y), axis=1) & np.all(np.isfinite(S), axis=(1, 2)) & np.isfinite(t)
    y, S, t = y[ok], S[ok], t[ok]
    n = len(y)
    if n < 8:
        return False
    var = 0.5 * (S[:, 0, 0] + S[:, 1, 1])
    keep = np.sum((y - _local_median(y)) ** 2, axis=1) / var <= _OUTLIER_NIS
    if np.sum(~keep) > MAX_OUTLIER_SHARE * n:  # not isolated outliers: the fixes scatter beyond their covariance
        return False
    y, var, t = y[keep], var[keep], t[keep]
    n = len(y)
    if n < 8:
        return False
    w = 1.0 / var
    cost, arg = _partitions(_segment_rss(w, y), min(MAX_LEVELS, n // MIN_LEVEL_FIXES))
    levels = np.arange(cost.shape[0])
    passes = np.isfinite(cost[:, n]) & (levels >= 1) & (
        cost[:, n] <= chi2.ppf(1.0 - false_alarm, np.maximum(2 * n - 2 * levels, 1)))
    if not passes.any():
        return False
    k = int(np.flatnonzero(passes)[0])  # the fewest levels that explain the window
    if need_step:
        if k < 2:
            return False
        starts, end = [], n  # the levels' starts, back along the best partition
        for kk in range(k, 0, -1):
            end = int(arg[kk, end])
            starts.insert(0, end)
        sw = np.add.reduceat(w, starts)
        means = np.add.reduceat(w[:, None] * y, starts, axis=0) / sw[:, None]
        mean_w = sw / np.diff([*starts, n])
        if not np.any(np.sum(means ** 2, axis=1) * mean_w <= _GATE_NIS):
            return False  # no level of the fixes agreed with the filter: it did not follow them either
    log_n = math.log(n)
    bic_steps = float(cost[k, n]) + (3 * k - 1) * log_n
    bic_drift = _drift_rss(w, y, t) + 6 * log_n
    return bic_steps < bic_drift
