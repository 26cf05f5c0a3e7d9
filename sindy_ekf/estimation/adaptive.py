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

import numba
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


@numba.njit(cache=True)
def _scale_kernel(y, S_state, R, newest, n, threshold, grid):
    """Return lambda over the ``n`` disjoint pairs ending at ring index ``newest`` (compiled: the
    filter asks at every fix, where the numpy version cost a third of the filter's time)."""
    size = y.shape[0]
    d = np.empty((n, 2))
    Sp = np.empty((n, 2, 2))
    Rp = np.empty((n, 2, 2))
    for p in range(n):
        a = (newest - 2 * p) % size  # the later fix of the pair
        b = (newest - 2 * p - 1) % size
        for i in range(2):
            d[p, i] = (y[a, i] - y[b, i]) / math.sqrt(2.0)
            for j in range(2):
                Sp[p, i, j] = 0.5 * (S_state[a, i, j] + S_state[b, i, j])
                Rp[p, i, j] = 0.5 * (R[a, i, j] + R[b, i, j])
    q = np.empty(n)
    for g in range(grid.size):
        lam = grid[g]
        for p in range(n):
            s00 = Sp[p, 0, 0] + lam * Rp[p, 0, 0]
            s01 = Sp[p, 0, 1] + lam * Rp[p, 0, 1]
            s10 = Sp[p, 1, 0] + lam * Rp[p, 1, 0]
            s11 = Sp[p, 1, 1] + lam * Rp[p, 1, 1]
            q[p] = (s11 * d[p, 0] ** 2 - (s01 + s10) * d[p, 0] * d[p, 1] + s00 * d[p, 1] ** 2) / (
                s00 * s11 - s01 * s10)
        stat = np.median(q) / _MEDIAN_CHI2_2
        if g == 0 and stat <= threshold:
            return 1.0
        if stat <= 1.0:
            return lam
    return grid[-1]


class NoiseScaler:
    """The variance factor of one run's stated GNSS covariance, from its recent innovations."""

    def __init__(self, n_pairs: int = N_PAIRS):
        self.n_pairs = n_pairs
        size = 2 * n_pairs  # ring buffers of the latest fixes
        self._y, self._S, self._R = np.empty((size, 2)), np.empty((size, 2, 2)), np.empty((size, 2, 2))
        self._count = 0

    def add(self, y: np.ndarray, S_state: np.ndarray, R: np.ndarray) -> None:
        """Record one fix's innovation ``y (2,)``, ``H P H^T (2, 2)`` and stated ``R (2, 2)``."""
        if math.isfinite(y.sum() + S_state.sum()):
            i = self._count % len(self._y)
            self._y[i], self._S[i], self._R[i] = y, S_state, R
            self._count += 1

    def scale(self) -> float:
        """Return ``lambda`` for the next fix (module docstring); 1 until :data:`MIN_PAIRS` pairs
        are in, then over the pairs there are (at most ``n_pairs``) with their own threshold."""
        n = min(self._count // 2, self.n_pairs)
        if n < MIN_PAIRS:
            return 1.0
        threshold = _THRESHOLDS.get(n) or median_threshold(n)
        return float(_scale_kernel(self._y, self._S, self._R, (self._count - 1) % len(self._y), n,
                                   threshold, _GRID))
