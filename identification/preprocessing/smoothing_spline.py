"""The weighted cubic smoothing spline of eq. 5.68 (thesis 5.3.5), by Reinsch's algorithm.

The smoothing factor ``s``
--------------------------
``s`` keeps the meaning of eq. 5.68: the spline ``f`` is the smoothest (least ``int f''^2``)
cubic spline whose *mean* squared normalised residual does not exceed ``s``::

    (1/N) sum_i ((y_i - f(t_i)) / sigma_i)^2 <= s

with ``sigma_i`` the pose standard deviation (``x_std``, ``y_std``, ``yaw_std``), so one ``s``
serves metres and radians alike. ``s = 0`` interpolates; ``s = 1`` lets the spline deviate
from the poses by their own noise (Reinsch's classic choice); larger values smooth more. In
scipy's terms this is ``UnivariateSpline(t, y, w=1/sigma, s=N*s)``, but FITPACK's knot
placement takes minutes for 30 000 poses at small ``s``, so the spline here is Reinsch's
(1967) smoothing spline: a natural cubic spline with a knot at every pose, the penalty weight
found by a root search so that the constraint holds with equality. It is the spline
``scipy.interpolate.make_smoothing_spline`` computes for a given penalty, at O(N) cost per
trial penalty (one banded Cholesky factorisation; Newton's method with the analytic slope of
the residual needs two to six). With tracker-derived a priori sigmas (about 10 um, 0.001
deg), the thesis's values 0.0005 to 0.01 (table 5.1, applied there to a posteriori sigmas
inflated by the hub eccentricity) are close to interpolation; ``s = 1`` is the noise-matched
choice, and larger values also remove real high-frequency motion (simulated campaigns,
``bench/results/poses.md``: vy RMS against truth 0.6 mm/s at s <= 0.01, 0.3 mm/s at s = 1,
while vx grows from 1.1 to 2.4 mm/s at s = 10). When a pose track has no sigmas the noise
level of each component is estimated from the data (robust spread of fourth differences), so
``s`` keeps its meaning.

The smoothing spline is natural (zero curvature at both ends of a segment), so over roughly
one smoothing length at each end the derivative is pulled towards the straight-line slope
(synthetic test, s = 10: velocity RMS 3e-4 m/s with the ends, 5e-6 m/s without). By default
(``pad_ends=True``) each segment is therefore refitted, with the penalty found on the data,
after continuing both ends by a weighted quadratic over three kernel widths of the spline:
the zero-curvature conditions then fall outside the data (same test: 3e-5 m/s with the ends).

:func:`smoothing_spline` fits one component; :mod:`identification.preprocessing.states` turns
the splines of x, y and yaw into body-frame states.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.linalg import cho_solve_banded, cholesky_banded, solveh_banded

from groundfloor.errors import InputError

#: search range of the normalised penalty exponent (log10)
_LOG_LAMBDA_RANGE = (-12.0, 14.0)


class _Reinsch:
    """Cubic smoothing spline values for any penalty, by Reinsch's algorithm.

    Minimises ``sum (y - g)^2 / var + lam * int g''^2``: with ``Q`` the second-divided-
    difference matrix and ``R`` the tridiagonal spline matrix, the interior second derivatives
    solve ``(R + lam Q^T D Q) gamma = Q^T y`` (``D = diag(var)``, a pentadiagonal SPD system,
    O(n) per penalty) and ``g = y - lam D Q gamma``. The bands of ``R`` and ``Q^T D Q`` are
    built once and reused across the penalties a root search tries.
    """

    def __init__(self, t: np.ndarray, y: np.ndarray, var: np.ndarray):
        h = np.diff(t)
        self.inv_h = 1.0 / h
        a = self.inv_h[:-1]  # column j of Q has a_j, b_j, c_j in rows j-1, j, j+1 (j interior)
        c = self.inv_h[1:]
        b = -(a + c)
        d = var
        m = t.size - 2
        self.R = np.zeros((3, m))  # upper banded storage for solveh_banded
        self.R[1, 1:] = h[1:-1] / 6.0
        self.R[2] = (h[:-1] + h[1:]) / 3.0
        self.T = np.zeros((3, m))
        self.T[0, 2:] = d[2:-2] * c[:-2] * a[2:]
        self.T[1, 1:] = d[1:-2] * b[:-1] * a[1:] + d[2:-1] * c[:-1] * b[1:]
        self.T[2] = d[:-2] * a**2 + d[1:-1] * b**2 + d[2:] * c**2
        self.rhs = np.diff(np.diff(y) * self.inv_h)
        self.y, self.var = y, var

    def log_lambda_guess(self, s: float) -> float:
        """Return log10 of the penalty at which ``mean(((y - g) / sigma)^2) = s`` for small penalties.

        For small ``lam``, ``y - g ~= lam D Q R^-1 Q^T y``: the residual grows linearly in
        ``lam``, so one tridiagonal solve gives the asymptote.
        """
        gamma0 = solveh_banded(self.R[1:], self.rhs, check_finite=False)
        slope = np.diff(np.concatenate([[0.0], gamma0, [0.0]])) * self.inv_h
        Q_gamma = np.diff(np.concatenate([[0.0], slope, [0.0]]))
        F1 = np.mean(self.var * Q_gamma**2)
        return 0.5 * float(np.log10(s / max(F1, 1e-300)))

    def _Q(self, gamma: np.ndarray) -> np.ndarray:
        """Return ``Q gamma`` (second divided differences, transposed) for interior ``gamma``."""
        slope = np.diff(np.concatenate([[0.0], gamma, [0.0]])) * self.inv_h
        return np.diff(np.concatenate([[0.0], slope, [0.0]]))

    def _T_matvec(self, v: np.ndarray) -> np.ndarray:
        """Return ``Q^T D Q v`` from the upper banded storage of the symmetric matrix."""
        T = self.T
        out = T[2] * v
        out[1:] += T[1, 1:] * v[:-1]
        out[:-1] += T[1, 1:] * v[1:]
        out[2:] += T[0, 2:] * v[:-2]
        out[:-2] += T[0, 2:] * v[2:]
        return out

    def values(self, lam: float) -> np.ndarray:
        """Return the smoothing spline's values at the knots for penalty ``lam``."""
        if lam == 0.0:
            return self.y.copy()
        gamma = solveh_banded(self.R + lam * self.T, self.rhs, check_finite=False)
        return self.y - lam * self.var * self._Q(gamma)

    def chi2_and_slope(self, lam: float) -> tuple[float, float]:
        """Return ``F = mean(((y - g) / sigma)^2)`` and ``d ln F / d ln lam`` at penalty ``lam``.

        ``y - g = lam D Q gamma`` and ``d gamma / d lam = -(R + lam T)^-1 T gamma``: one
        banded Cholesky factor serves both solves.
        """
        factor = cholesky_banded(self.R + lam * self.T, check_finite=False)
        gamma = cho_solve_banded((factor, False), self.rhs, check_finite=False)
        q = self._Q(gamma)
        dq = self._Q(-cho_solve_banded((factor, False), self._T_matvec(gamma), check_finite=False))
        vq2 = np.mean(self.var * q * q)
        F = lam**2 * vq2
        dF = 2.0 * lam * vq2 + 2.0 * lam**2 * np.mean(self.var * q * dq)
        return float(F), float(lam * dF / max(F, 1e-300))


def _solve_log_lambda(problem: "_Reinsch", s: float, tol: float = 5e-3, max_iter: int = 40) -> float | None:
    """Return ``u = log10 lam`` at which ``mean(((y - g) / sigma)^2) = s``, or None if none.

    Newton's method on ``f(u) = ln F - ln s`` with the analytic slope of
    :meth:`_Reinsch.chi2_and_slope`, started from the small-penalty asymptote and kept inside
    the bracket found so far (bisection when a step leaves it): typically three to five banded
    factorisations. ``tol`` is on ``ln F``: 0.5 % in the residual of eq. 5.68.
    """
    lo, hi = _LOG_LAMBDA_RANGE
    a, b = lo, hi  # f(a) < 0 < f(b) once evaluated; the ends are only assumed so
    u = float(np.clip(problem.log_lambda_guess(s), lo, hi))
    for _ in range(max_iter):
        F, dlnF = problem.chi2_and_slope(10.0**u)
        f = np.log(max(F, 1e-300)) - np.log(s)
        if abs(f) < tol:
            return u
        if f < 0:
            a = u
        else:
            b = u
        if b - a < 1e-6:
            return u
        slope = np.log(10.0) * dlnF
        u_new = u - f / slope if slope > 1e-9 else np.nan
        if not a < u_new < b:  # Newton left the bracket: bisect it, or step out by 4 decades
            if f < 0 and b >= hi:
                if u >= hi:
                    return None  # even the largest penalty leaves the residual below s
                u_new = min(u + 4.0, hi)
            elif f > 0 and a <= lo:
                if u <= lo:
                    return lo  # the smallest penalty already reaches s: interpolation
                u_new = max(u - 4.0, lo)
            else:
                u_new = 0.5 * (a + b)
        u = u_new
    return u


def smoothing_spline(t, y, y_std, s: float, pad_ends: bool = False) -> tuple[CubicSpline, float]:
    """Return the weighted cubic smoothing spline of eq. 5.68 and its penalty weight.

    Parameters
    ----------
    t : (n,) strictly increasing times, s.
    y : (n,) values.
    y_std : (n,) standard deviations of ``y`` (positive).
    s : mean squared normalised residual allowed (eq. 5.68); 0 interpolates.
    pad_ends : after the penalty is found on the data, refit with each end continued by
        three equivalent kernel widths of the spline (``lam^(1/4)`` in samples) of values
        from a weighted quadratic fitted to the last three widths of samples, so that the natural (zero-curvature)
        end conditions fall outside the data instead of bending the derivative at its ends.
        Off, the spline is exactly ``scipy.interpolate.make_smoothing_spline``'s.

    Returns
    -------
    spline : scipy.interpolate.CubicSpline
        Natural cubic spline through the smoothed values (the smoothing spline itself); call
        ``spline(t, 1)`` for the analytic derivative. Its argument is ``t`` as given.
    lam : float
        Penalty weight on ``int f''^2`` in the units of ``t`` and ``y`` (0 when interpolating,
        ``inf`` when ``s`` exceeds the residual of the weighted straight line, which is then
        returned).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    var = np.asarray(y_std, dtype=float) ** 2
    if s < 0 or not np.isfinite(s):
        raise InputError(f"smoothing: must be a finite value >= 0, got {s!r}")
    t0 = t[0]
    tau = t - t0
    if s == 0.0 or t.size < 4:
        return CubicSpline(t, y, bc_type="natural"), 0.0
    # normalise time by the median step and values by the median sigma: penalty near 1
    h_ref = float(np.median(np.diff(tau)))
    std_ref = float(np.sqrt(np.median(var)))
    tau_n, y_n, var_n = tau / h_ref, (y - y[0]) / std_ref, var / std_ref**2

    problem = _Reinsch(tau_n, y_n, var_n)
    w = 1.0 / var_n
    A = np.column_stack([np.ones_like(tau_n), tau_n])
    coef = np.linalg.lstsq(A * np.sqrt(w)[:, None], y_n * np.sqrt(w), rcond=None)[0]
    chi2_line = np.mean((y_n - A @ coef) ** 2 * w)
    if chi2_line <= s:
        g_n, lam = A @ coef, np.inf
    else:
        log_lam = _solve_log_lambda(problem, s)
        if log_lam is None:
            g_n, lam = A @ coef, np.inf
        else:
            lam_n = 10.0**log_lam
            lam = lam_n * h_ref**3 / std_ref**2
            if pad_ends:
                tau_p, g_p = _padded_fit(tau_n, y_n, var_n, lam_n)
                return CubicSpline(t0 + tau_p * h_ref, y[0] + g_p * std_ref, bc_type="natural"), lam
            g_n = problem.values(lam_n)
    return CubicSpline(t, y[0] + g_n * std_ref, bc_type="natural"), lam


def _padded_fit(tau: np.ndarray, y: np.ndarray, var: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Return knots and smoothed values of the fit with quadratically continued ends.

    Normalised units (unit median step, unit median variance): the equivalent kernel of a
    cubic smoothing spline is about ``lam^(1/4)`` steps wide; each end is continued by three
    widths, from a weighted quadratic through the last three widths of data (the best of the
    combinations of one to three widths tried on the synthetic trajectories of the tests).
    """
    n = tau.size
    width = lam**0.25
    k = int(min(max(np.ceil(3.0 * width), 3), n // 2))
    m = int(min(max(np.ceil(3.0 * width), 8), n))
    pads_t, pads_y = [], []
    for sl, steps in ((slice(0, m), -np.arange(k, 0, -1)), (slice(n - m, n), np.arange(1, k + 1))):
        t_end = tau[0] if steps[0] < 0 else tau[-1]
        coef = np.polyfit(tau[sl] - t_end, y[sl], 2, w=1.0 / np.sqrt(var[sl]))
        pads_t.append(t_end + steps.astype(float))
        pads_y.append(np.polyval(coef, steps.astype(float)))
    tau_p = np.concatenate([pads_t[0], tau, pads_t[1]])
    y_p = np.concatenate([pads_y[0], y, pads_y[1]])
    var_p = np.concatenate([np.ones(k), var, np.ones(k)])
    return tau_p, _Reinsch(tau_p, y_p, var_p).values(lam)


def noise_std_from_data(y) -> float:
    """Return a robust noise standard deviation of a smooth series from its fourth differences.

    For white noise of standard deviation ``sigma`` the fourth difference has standard
    deviation ``sqrt(70) sigma``; a smooth trajectory at 50 Hz contributes far less. The
    spread is the scaled median absolute deviation, so the few jumps at gaps do not count.
    """
    y = np.asarray(y, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 6:
        return float("nan")
    d4 = np.diff(y, 4)
    mad = 1.4826 * np.median(np.abs(d4 - np.median(d4)))
    return float(max(mad / np.sqrt(70.0), 1e-12 * (np.ptp(y) + 1.0)))
