"""Measurement-noise adaptation from the innovations: a stated GNSS covariance too small is inflated.

Covariance matching (Mehra 1972, "Approaches to adaptive filtering", sec. III; Myers and Tapley
1976): over a consistent filter the innovation ``y`` of a fix has covariance ``S = H P H^T + R``,
so ``y^T S^-1 y`` is chi-square with 2 degrees of freedom. A receiver that states ``R`` ten times
too small makes that ratio about ten times too large at every fix. :class:`NoiseScaler` estimates
one variance factor ``lambda >= 1`` of the stated ``R`` from the recent innovations and the
filter applies ``lambda R``.

What is matched is the scatter of the innovations, not their size: the statistic is built from
differences of consecutive innovations, ``d = (y_i - y_{i-1}) / sqrt 2`` (von Neumann's mean
square successive difference, 1941, used here as a variance estimator insensitive to a slowly
varying mean), on disjoint pairs so that the differences are independent. A step of all fixes
(multipath burst, position jump) or a slow drift of a lost filter moves the innovations' mean
and touches at most one difference; white noise larger than stated scales them all. Steps and
drifts are left to the gate and to the monitor's step test (:mod:`sindy_ekf.benchmark.health`).

Robust and bounded: the statistic is the median over :data:`N_PAIRS` differences of
``d^T Sbar(lambda)^-1 d`` over the median of chi2(2), ``2 ln 2``, so that an outlier or one step
moves it by one rank. ``lambda`` stays 1 unless that statistic at ``lambda = 1`` exceeds the
``1 - FALSE_ALARM`` quantile of the sample median of ``N_PAIRS`` independent chi2(2) variables
(:func:`median_threshold`, exact from the order statistic's beta law): correctly stated fixes
are left untouched but for that false-alarm rate. Above it, ``lambda`` is the smallest value on a
log grid in ``[1, SCALE_MAX]`` that brings the statistic down to 1.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
from scipy.stats import beta

N_PAIRS = 15  # disjoint pairs of consecutive fixes: 30 fixes, 6 s of 5 Hz GNSS
MIN_PAIRS = 5  # from the start of a run, with the threshold of that many pairs
FALSE_ALARM = 1e-3  # per fix, of a correctly stated R
SCALE_MAX = 100.0  # at most 10 x the stated standard deviation
_MEDIAN_CHI2_2 = 2.0 * math.log(2.0)
_GRID = np.geomspace(1.0, SCALE_MAX, 81)


def median_threshold(n: int = N_PAIRS, false_alarm: float = FALSE_ALARM) -> float:
    """Return the ``1 - false_alarm`` quantile of the median of ``n`` chi2(2) samples over ``2 ln 2``.

    The median of an odd ``n`` is the order statistic ``k = (n + 1) / 2``, whose value of the
    chi2(2) distribution function ``1 - exp(-x / 2)`` follows ``Beta(k, n - k + 1)``.
    """
    k = (n + 1) // 2
    b = float(beta.ppf(1.0 - false_alarm, k, n - k + 1))
    return -2.0 * math.log1p(-b) / _MEDIAN_CHI2_2


THRESHOLD = median_threshold()
_THRESHOLDS = {n: median_threshold(n) for n in range(MIN_PAIRS, N_PAIRS + 1)}


def scatter_statistic(d: np.ndarray, S_state: np.ndarray, R: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Return, per scale ``lambda``, the median of ``d^T (S_state + lambda R)^-1 d`` over ``2 ln 2``.

    ``d (n, 2)`` differences, ``S_state, R (n, 2, 2)`` their state and stated measurement parts,
    ``scales (L,)``; the 2 x 2 inverses in closed form, all scales at once.
    """
    S = S_state[None] + scales[:, None, None, None] * R[None]  # (L, n, 2, 2)
    a, b, c, e = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    q = (e * d[:, 0] ** 2 - (b + c) * d[:, 0] * d[:, 1] + a * d[:, 1] ** 2) / (a * e - b * c)
    return np.median(q, axis=-1) / _MEDIAN_CHI2_2


class NoiseScaler:
    """The variance factor of one run's stated GNSS covariance, from its recent innovations."""

    def __init__(self, n_pairs: int = N_PAIRS):
        self.n_pairs = n_pairs
        self._fixes: deque = deque(maxlen=2 * n_pairs)  # (y, S_state, R) of the latest fixes

    def add(self, y: np.ndarray, S_state: np.ndarray, R: np.ndarray) -> None:
        """Record one fix's innovation ``y (2,)``, ``H P H^T (2, 2)`` and stated ``R (2, 2)``."""
        if np.all(np.isfinite(y)) and np.all(np.isfinite(S_state)):
            self._fixes.append((y, S_state, R))

    def scale(self) -> float:
        """Return ``lambda`` for the next fix (module docstring); 1 until :data:`MIN_PAIRS` pairs
        are in, then over the pairs there are (at most ``n_pairs``) with their own threshold."""
        n = len(self._fixes) // 2
        if n < MIN_PAIRS:
            return 1.0
        latest = list(self._fixes)[len(self._fixes) - 2 * n:]
        y, S_state, R = (np.array(v) for v in zip(*latest))
        d = (y[1::2] - y[0::2]) / math.sqrt(2.0)  # disjoint pairs: independent differences
        S_pair = 0.5 * (S_state[1::2] + S_state[0::2])
        R_pair = 0.5 * (R[1::2] + R[0::2])
        threshold = _THRESHOLDS.get(n) or median_threshold(n)
        if scatter_statistic(d, S_pair, R_pair, _GRID[:1])[0] <= threshold:
            return 1.0
        stat = scatter_statistic(d, S_pair, R_pair, _GRID)
        below = np.flatnonzero(stat <= 1.0)
        return float(_GRID[below[0]]) if below.size else SCALE_MAX
