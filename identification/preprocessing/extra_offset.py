"""The extra offset of the late tracker by minimising the baseline spread (eqs. 5.13 to 5.22).

The AT960 measured on the falling trigger edge (thesis 4.2.2), about a duty cycle after the
time its clock model gives. Interpolating its positions at shifted times and minimising the
spread of the prism-to-prism distance finds that offset (5.13 to 5.18); a quadratic through ten
samples of the spread gives its vertex (5.19, 5.20) and, by error propagation, its standard
deviation (5.21, 5.22). Also here: the interpolation of tracker positions at arbitrary times
and the turning-hub design of eq. 5.25 used to estimate the offset jointly with the hub terms.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline, PPoly

from groundfloor.errors import InputError

log = logging.getLogger(__name__)

MAX_INTERP_GAP_S = 0.05  # interpolate across one missing sample at most, never across a dropout
FIT_STEP_S = 2e-5  # spacing of the ten spread samples of the quadratic (eq. 5.19)
JACKKNIFE_BLOCKS = 10
HUB_DELAYS_S = np.arange(0.0, 0.2001, 0.01)  # trial delays of the hubs behind their commands  # time blocks for the jackknife standard deviation of the extra offset


@dataclass(frozen=True)
class OffsetEstimate:
    """The AT960's extra offset per run (eqs. 5.13 to 5.22), sign of eq. 5.24."""

    dt: float  # s, added to the AT960's clock-model times (eq. 5.24)
    dt_std: float  # s, by error propagation (eqs. 5.21, 5.22)
    dt_std_jackknife: float  # s, jackknife over JACKKNIFE_BLOCKS time blocks of the run
    coeffs: np.ndarray  # (3,) [a, b, c] of eq. 5.19
    cov: np.ndarray  # (3, 3) covariance of the coefficients
    dt_grid: np.ndarray  # offsets of the fine grid around the minimum, s
    spread_grid: np.ndarray  # baseline spread s_r at those offsets (eq. 5.16), m
    dt_fit: np.ndarray  # the ten samples of the quadratic fit (eq. 5.19)
    spread_fit: np.ndarray
    hub_terms: bool  # spread taken after removing the eq. 5.25 hub terms (joint estimate)
    hub_delay_s: float  # delay of the hubs behind their commands used for the hub terms
    dt_without_hub: float  # the thesis's estimate: spread of the raw baseline length, s


def track_interpolator(s_samples: np.ndarray, xyz: np.ndarray, max_gap_s: float = MAX_INTERP_GAP_S,
                       method: str = "cubic") -> Callable[[np.ndarray], np.ndarray]:
    """Return ``f(s_query) -> (..., 3)`` interpolating a tracker's positions, NaN across gaps.

    The thesis (5.2.2) interpolated linearly. Its error is ``a * t1 * t2 / 2`` for an
    acceleration ``a`` between samples ``t1`` before and ``t2`` after the query: some 20 um at
    the AT960's 1.3 ms offset and up to ~0.5 mm across a lost pulse (40 ms) when the prism
    swings round a turn. ``"cubic"`` (default) uses a not-a-knot cubic spline per stretch of
    samples without a gap over ``max_gap_s`` (exact for cubic motion); ``"linear"`` is the
    thesis's. Queries outside the samples or in a gap give NaN.
    """
    s_samples = np.asarray(s_samples, float)
    xyz = np.asarray(xyz, float)
    cut = np.flatnonzero(np.diff(s_samples) > max_gap_s) + 1
    knots, coefs = [], []
    for seg in np.split(np.arange(s_samples.size), cut):  # one spline per stretch, not per sample
        if seg.size < 2:
            continue
        x, y = s_samples[seg], xyz[seg]
        if method == "cubic" and seg.size >= 4:
            c = CubicSpline(x, y, bc_type="not-a-knot").c
        else:  # linear, or too few samples for a cubic: as the thesis did
            c = np.zeros((4, seg.size - 1, 3))
            c[2], c[3] = np.diff(y, axis=0) / np.diff(x)[:, None], y[:-1]
        if knots:  # the gap since the previous stretch: NaN polynomial
            coefs.append(np.full((4, 1, 3), np.nan))
        knots.append(x)
        coefs.append(c)
    if not knots:
        return lambda q: np.full(np.shape(q) + (3,), np.nan)
    pp = PPoly(np.concatenate(coefs, axis=1), np.concatenate(knots), extrapolate=False)
    return lambda q: pp(np.asarray(q, float))


def interpolate_at(s_query: np.ndarray, s_samples: np.ndarray, xyz: np.ndarray,
                   max_gap_s: float = MAX_INTERP_GAP_S, method: str = "cubic") -> np.ndarray:
    """Return positions interpolated at ``s_query`` (any shape, + (3,)), NaN where the samples
    around it are more than ``max_gap_s`` apart or outside them (see :func:`track_interpolator`)."""
    return track_interpolator(s_samples, xyz, max_gap_s, method)(s_query)


def hub_design(t_query: np.ndarray, t_cmd: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Return the (n, 5) design of eq. 5.25 in linear form at the query times, NaN rows before
    the first command: ``[1, cos phi_f, sin phi_f, cos phi_r, sin phi_r]``.

    The hub set points are commands, constant until the next one: a zero-order hold.
    """
    az = azimuth_at(t_query, t_cmd, azimuth)
    return np.column_stack([np.ones(len(az)), np.cos(az[:, 0]), np.sin(az[:, 0]),
                            np.cos(az[:, 1]), np.sin(az[:, 1])])


def azimuth_at(t_query: np.ndarray, t_cmd: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Return the (n, 2) commanded azimuths held since the last command before each query time
    (NaN before the first one)."""
    if len(t_cmd) == 0:
        return np.full((len(t_query), 2), np.nan)
    i = np.searchsorted(t_cmd, t_query, side="right") - 1
    az = np.unwrap(np.asarray(azimuth, float), axis=0)[np.clip(i, 0, None)]
    az[i < 0] = np.nan
    return az


def _baseline_residuals(dt: np.ndarray, s: np.ndarray, p_ref: np.ndarray, late_at,
                        A_hub: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Return the (G, M) baseline lengths about their fit for each offset in ``dt``, and the
    number of fitted parameters (eqs. 5.15, 5.17).

    Without ``A_hub`` the fit is the mean (eq. 5.17); with it (the eq. 5.25 design at the
    trigger times) the least-squares hub terms are removed at each trial offset. Only the
    triggers where every offset has both prisms count, so that all offsets see the same set.
    """
    p_late = late_at(s[None, :] - np.asarray(dt)[:, None])
    length = np.linalg.norm(p_ref[None] - p_late, axis=-1)
    ok = np.isfinite(length).all(axis=0)
    if A_hub is None:
        L = length[:, ok]
        return L - L.mean(axis=1, keepdims=True), 1
    ok &= np.isfinite(A_hub).all(axis=1)
    # orthonormal basis of the hub terms (SVD: rank-revealing if an azimuth barely moves)
    U, sv, _ = np.linalg.svd(A_hub[ok], full_matrices=False)
    U = U[:, sv > sv[0] * 1e-8]
    L = length[:, ok]
    return L - (L @ U) @ U.T, U.shape[1]


def _spread(dt: np.ndarray, s: np.ndarray, p_ref: np.ndarray, late_at,
            A_hub: np.ndarray | None = None) -> np.ndarray:
    """Return the baseline spread s_r(dt) for each offset in ``dt`` (eq. 5.16, as a standard
    deviation), after the hub terms when ``A_hub`` is given."""
    res, n_par = _baseline_residuals(dt, s, p_ref, late_at, A_hub)
    return np.sqrt((res**2).sum(axis=1) / (res.shape[1] - n_par))


def fit_extra_offset(s: np.ndarray, p_ref: np.ndarray, s_late: np.ndarray, xyz_late: np.ndarray,
                     search_s: float = 0.01, run: str = "?",
                     hub: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                     max_gap_s: float = MAX_INTERP_GAP_S) -> OffsetEstimate:
    """Return the extra offset of one tracker's times that minimises the baseline spread.

    Implements eqs. 5.13 to 5.22: ``s_r`` is sampled over ``[-search_s, search_s]`` (coarse,
    then finer around the minimum), a quadratic (5.19) is fitted to ten samples around the
    minimum, its vertex is the offset (5.20) and its standard deviation follows by error
    propagation of the coefficients' covariance (5.21, 5.22). The sign is that of eq. 5.24:
    the shifted tracker's positions at trigger time ``t`` are its samples at ``t - dt`` on its
    clock model; ``p_ref`` are the other tracker's positions at the trigger times ``s``.

    Beyond the thesis: with ``hub = (t_trigger, t_command, azimuth)`` (the trigger times and
    the hub set points, on one clock) the spread is measured after the turning-hub terms of
    eq. 5.25 are removed at every trial offset, i.e. offset and hub eccentricity are estimated
    jointly. The eccentricity seen along the baseline follows the hub azimuths, which follow
    the robot's motion; left in, it correlates with the speed and pulls the thesis's estimate
    by tens of microseconds (``dt_without_hub`` keeps that one). The hubs follow their commands
    late (thesis 5.2.3: transmission, PD controller); that delay is estimated first
    (:func:`fit_hub_delay`) at the thesis's offset.
    """
    late_at = track_interpolator(s_late, xyz_late, max_gap_s)
    est = _fit_offset(s, p_ref, late_at, search_s, run, None)
    if hub is None or len(hub[1]) == 0:
        return est
    joint, delay = est, 0.0
    for _ in range(2):  # delay at the current offset, then the offset with that delay
        delay = fit_hub_delay(s, p_ref, late_at, joint.dt, *hub)
        A_hub = hub_design(hub[0] - delay, hub[1], hub[2])
        if not np.isfinite(A_hub).all(axis=1).any():
            return est
        joint = _fit_offset(s, p_ref, late_at, search_s, run, A_hub)
    return replace(joint, dt_without_hub=est.dt, hub_delay_s=delay)


def fit_hub_delay(s: np.ndarray, p_ref: np.ndarray, late_at, dt: float, t_query: np.ndarray,
                  t_cmd: np.ndarray, azimuth: np.ndarray,
                  delays_s: np.ndarray = HUB_DELAYS_S) -> float:
    """Return the delay (s) of the hubs behind their commands that best explains the baseline.

    At the extra offset ``dt``, the baseline spread left by the eq. 5.25 hub terms is computed
    with the azimuth commands delayed by each of ``delays_s`` (a zero-order hold, shifted);
    the minimum is refined by a parabola through it and its neighbours.
    """
    # one evaluation per trial delay (about twenty), not per sample; every 2nd trigger suffices
    sub = np.s_[::2]
    spread = np.array([_spread(np.array([dt]), s[sub], p_ref[sub], late_at,
                               hub_design(t_query[sub] - d, t_cmd, azimuth))[0] for d in delays_s])
    i = int(np.argmin(spread))
    if 0 < i < len(delays_s) - 1:
        y0, y1, y2 = spread[i - 1:i + 2]
        den = y0 - 2 * y1 + y2
        if den > 0:
            return float(delays_s[i] + 0.5 * (y0 - y2) / den * (delays_s[1] - delays_s[0]))
    return float(delays_s[i])


def _fit_offset(s, p_ref, late_at, search_s, run, A_hub) -> OffsetEstimate:
    """Grid, quadratic and vertex of :func:`fit_extra_offset` for one spread definition."""
    if np.sum(np.isfinite(p_ref[:, 0])) < 50:
        raise InputError(f"run {run}: fewer than 50 trigger times with both prisms seen; "
                         "cannot estimate the AT960 offset")
    coarse = np.arange(-search_s, search_s + 1e-12, 2.5e-4)
    # the coarse grid only brackets the minimum: every 4th trigger is plenty for that
    sub = np.s_[::4]
    spread_c = _spread(coarse, s[sub], p_ref[sub], late_at, None if A_hub is None else A_hub[sub])
    best = coarse[np.argmin(spread_c)]
    fine = best + np.arange(-3e-4, 3e-4 + 1e-12, 2e-5)
    spread_f = _spread(fine, s, p_ref, late_at, A_hub)
    dt = fine[np.argmin(spread_f)]
    # The spread is a hyperbola, sqrt(noise^2 + (g dt)^2), not a parabola: ten samples placed
    # off-centre pull the vertex of eq. 5.19 by a fraction of their step, so they are centred
    # on the vertex and fitted again.
    for _ in range(2):
        dt_fit = dt + FIT_STEP_S * (np.arange(10) - 4.5)
        res_fit, n_par = _baseline_residuals(dt_fit, s, p_ref, late_at, A_hub)
        spread_fit = np.sqrt((res_fit**2).sum(axis=1) / (res_fit.shape[1] - n_par))
        x0 = dt_fit.mean()  # centre for conditioning; the vertex is shifted back below
        A = np.column_stack([(dt_fit - x0) ** 2, dt_fit - x0, np.ones(10)])
        coef, *_ = np.linalg.lstsq(A, spread_fit, rcond=None)
        a, b, _ = coef
        dt = x0 - b / (2 * a) if a > 0 else np.inf  # eq. 5.20
        if not dt_fit[0] - 1e-4 <= dt <= dt_fit[-1] + 1e-4:
            raise InputError(f"run {run}: baseline spread has no minimum near "
                             f"{best * 1e3:.3f} ms; cannot estimate the AT960 offset")
    res = spread_fit - A @ coef
    cov = (res @ res / (10 - 3)) * np.linalg.inv(A.T @ A)
    F = np.array([b / (2 * a**2), -1 / (2 * a), 0.0])  # eq. 5.22
    # Jackknife over time blocks: the same estimate leaving out one tenth of the run at a time.
    # Eq. 5.21 only sees how well ten spread samples lie on a parabola (the thesis, 7.3.2:
    # "not reflective of the overall time synchronisation quality"); this sees the data.
    k = JACKKNIFE_BLOCKS
    starts = np.linspace(0, res_fit.shape[1], k + 1).astype(int)[:-1]
    ssr_block = np.add.reduceat(res_fit**2, starts, axis=1)  # (10, k)
    n_block = np.diff(np.append(starts, res_fit.shape[1]))
    ssr_loo = ssr_block.sum(axis=1, keepdims=True) - ssr_block
    spread_loo = np.sqrt(ssr_loo / (res_fit.shape[1] - n_block - n_par))
    coef_loo, *_ = np.linalg.lstsq(A, spread_loo, rcond=None)
    dt_loo = x0 - coef_loo[1] / (2 * coef_loo[0])
    dt_jack = float(np.sqrt((k - 1) / k * np.sum((dt_loo - dt_loo.mean()) ** 2)))
    return OffsetEstimate(dt=float(dt), dt_std=float(np.sqrt(F @ cov @ F)), coeffs=coef, cov=cov,
                          dt_std_jackknife=dt_jack,
                          dt_grid=fine, spread_grid=spread_f,
                          dt_fit=dt_fit, spread_fit=spread_fit, hub_terms=A_hub is not None,
                          hub_delay_s=0.0,
                          dt_without_hub=float(dt))
