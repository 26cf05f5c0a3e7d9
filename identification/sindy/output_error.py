"""Output-error (simulation-error) fitting of a motion model on multi-second windows.

The integral regression (eqs. 5.53 to 5.59) fits one-step-like velocity differences; a model is
scored on what it predicts seconds ahead. Output-error least squares fits the parameters to
that: every window of the train runs is integrated from its reference start state with the
model's dead-timed inputs (:func:`identification.sindy.evaluate.rollout`'s RK4), and the
residuals are the predicted minus the measured poses at every step (position in metres,
heading times :data:`HEADING_WEIGHT_M`), minimised by ``scipy.optimize.least_squares``.

The Jacobian is exact and cheap: the state sensitivities ``S = d x / d p`` are carried through
the same RK4 steps (the derivative of the discrete map, so it matches the residuals to round-off),
each stage adding ``J_f_x S + d f / d p``; a dead time ``d_i`` enters through
``d f / d d_i = -J_f_u[:, i] du_i/dt (t - d_i)`` (the windows' :class:`InputTrack` gives the
input's rate). One pass costs about one rollout with Jacobians, whatever the number of
parameters, where finite differences would cost one rollout per parameter.

Standard errors: the residuals of one window are strongly correlated (a prediction error
carries on), so the covariance is the cluster-robust sandwich with one cluster per window
(``A^-1 B A^-1``, ``A = J^T J``, ``B = sum_w J_w^T r_w r_w^T J_w``), over windows that do not
overlap. This is the least-squares adjustment of thesis 5.3.9 on the output error, corrected for
the correlation the thesis noted (its eq. 5.79 treats every row as independent).

:class:`ParametricModel` is what a model must say to be fitted: its dynamics for a parameter
vector and the derivative of its accelerations in the parameters. :class:`SindyStructure` is the
SINDy model's active terms; the lag baseline's is in :mod:`identification.sindy.baselines`.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, cholesky, qr
from scipy.optimize import least_squares

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from identification.sindy.evaluate import Windows
from identification.sindy.library import LIBRARY_STATE_NAMES, FeatureLibrary
from identification.sindy.model import SindyModel
from identification.sindy.sensitivity_rollout import sensitivity_rollout

log = logging.getLogger(__name__)

#: metres of position residual per radian of heading residual: a heading error turns into about
#: that much position error over the rest of a few-second window at about 1 m/s
HEADING_WEIGHT_M = 1.0
#: largest input dead time considered, s
MAX_DEAD_TIME_S = 1.0
#: largest first-order input lag considered, s (groundfloor.input_chain)
MAX_INPUT_LAG_S = 1.0
#: windows of the output-error fits (non-overlapping) and their integration step
OE_WINDOW_S = 3.0
OE_DT = 0.05
#: at most this many windows enter one fit (evenly spread; a 45-minute campaign has 900)
OE_MAX_WINDOWS = 200
#: smallest pivot of the Cholesky factor of :func:`compressed` relative to the largest (unit
#: columns: the sine of a column's angle to the others' span) before it takes the QR decomposition
MIN_CHOLESKY_PIVOT = 1e-5
#: residual of a window whose prediction left the finite numbers (a diverging candidate), m
DIVERGED_RESIDUAL_M = 100.0
#: a window whose residuals or sensitivities pass this has run away as surely as a non-finite one:
#: its squares would overflow the Gram matrix of the fit (float64 ends at 1.8e308)
RUNAWAY_MAGNITUDE = 1e100


class ParametricModel(ABC):
    """A motion model as a function of a parameter vector, for output-error fitting."""

    names: tuple[str, ...]  # one per parameter (dead times not included)
    lower: np.ndarray  # bounds of the parameters
    upper: np.ndarray

    @property
    def n_params(self) -> int:
        """Number of parameters (dead times not included)."""
        return len(self.names)

    @abstractmethod
    def build(self, theta: np.ndarray, dead_time_s, input_lag_s=(0.0, 0.0)) -> Dynamics:
        """Return the dynamics with parameters ``theta (p,)``, dead times ``(d1, d2)`` and input lags ``(T1, T2)``."""

    @abstractmethod
    def accel_param_jacobian(self, dynamics: Dynamics, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return ``d a / d theta`` ``(..., 3, p)`` of ``dynamics`` (built by :meth:`build`) at ``(x6, u)``."""

    def derivative_and_jacobians(self, dynamics: Dynamics, x6: np.ndarray, u: np.ndarray, t
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return the six-state derivative ``(W, 6)``, ``J_f_x (W, 6, 6)``, ``J_f_u (W, 6, 2)`` and
        ``d a / d theta (W, 3, p)`` (a model may compute them together, faster)."""
        f, J_x, J_u = dynamics.derivative_and_jacobians(x6, u, t)
        return f, J_x, J_u, self.accel_param_jacobian(dynamics, x6, u)


class SindyStructure(ParametricModel):
    """The active terms of a SINDy model as parameters (its coefficients; the structure fixed).

    The accelerations are linear in the coefficients, so ``d a_e / d xi_(e, j)`` is the feature
    ``theta_j`` at the state (evaluated on a library of the active features only). Terms in
    ``fixed`` (a ``(3, k)`` mask) keep the template's coefficients: a direction the data do not
    move has no gradient, and a Jacobian-scaled optimiser takes huge steps along it.
    """

    def __init__(self, model: SindyModel, fixed: np.ndarray | None = None):
        self.template = model
        free = model.coef != 0 if fixed is None else (model.coef != 0) & ~np.asarray(fixed, bool)
        eq, col = np.nonzero(free)
        self.eq, self.col = eq, col
        all_eq, all_col = np.nonzero(model.coef)
        self.names = tuple(f"{LIBRARY_STATE_NAMES[e]}: {model.library.feature_names[j]}" for e, j in zip(eq, col))
        cols = sorted(set(all_col.tolist()))
        self.sub = FeatureLibrary(name=f"{model.library.name}[active]",
                                  feature_names=tuple(model.library.feature_names[j] for j in cols))
        self.sub_col = np.array([cols.index(j) for j in col], dtype=int)
        self.all_eq, self.all_sub_col = all_eq, np.array([cols.index(j) for j in all_col], dtype=int)
        self.all_col = all_col
        self.sub_linear = model.linear_columns[cols]
        # the compiled rollout's view: each parameter's feature as atom-table columns (FeatureLibrary._index)
        self.factors = model.library._index[0][col]
        self.linear = model.linear_columns[col]
        self.bounds = model._clamp_bounds()
        self.lower = np.full(len(eq), -np.inf)
        self.upper = np.full(len(eq), np.inf)

    @property
    def theta0(self) -> np.ndarray:
        """Return the template model's active coefficients."""
        return self.template.coef[self.eq, self.col].copy()

    def build(self, theta, dead_time_s, input_lag_s=(0.0, 0.0)) -> SindyModel:
        coef = self.template.coef.copy()  # the fixed terms keep their values
        coef[self.eq, self.col] = theta
        return self.template.with_coefficients(coef, dead_time_s, input_lag_s)

    def accel_param_jacobian(self, dynamics, x6, u):
        return self.derivative_and_jacobians(dynamics, np.asarray(x6, float), np.asarray(u, float), 0.0)[3]

    def derivative_and_jacobians(self, dynamics, x6, u, t):
        """Return what :meth:`ParametricModel.derivative_and_jacobians` does, from the active
        features alone (one small library evaluation per stage: the fits' inner loop)."""
        z = np.concatenate([x6[..., 3:], u], axis=-1)
        theta, d_theta = self.sub.transform_with_jacobian(z)
        zc = z if self.bounds is None else np.concatenate([np.clip(z[..., :3], *self.bounds), z[..., 3:]], -1)
        if zc is not z and np.any(zc != z):  # frozen extrapolation outside the envelope (SindyModel.features)
            theta_c, d_theta_c = self.sub.transform_with_jacobian(zc)
            d_theta_c[..., :3, :] *= (zc[..., :3] == z[..., :3])[..., None]
            theta = np.where(self.sub_linear, theta, theta_c)
            d_theta = np.where(self.sub_linear, d_theta, d_theta_c)
        C = np.zeros((self.sub.n_features, 3))
        C[self.all_sub_col, self.all_eq] = dynamics.coef[self.all_eq, self.all_col]
        lead = z.shape[:-1]
        f = np.empty(lead + (6,))
        J_x = np.zeros(lead + (6, 6))
        J_u = np.zeros(lead + (6, 2))
        psi = x6[..., 2]
        c, s = np.cos(psi), np.sin(psi)
        vx, vy = x6[..., 3], x6[..., 4]
        f[..., 0], f[..., 1], f[..., 2] = c * vx - s * vy, s * vx + c * vy, x6[..., 5]
        f[..., 3:] = theta @ C
        J_x[..., 0, 2], J_x[..., 1, 2] = -f[..., 1], f[..., 0]  # eq. 5.75's Jacobian, as Dynamics'
        J_x[..., 0, 3], J_x[..., 0, 4], J_x[..., 1, 3], J_x[..., 1, 4], J_x[..., 2, 5] = c, -s, s, c, 1.0
        J_a_z = np.swapaxes(d_theta @ C, -1, -2)  # (..., 3, 5)
        J_x[..., 3:, 3:] = J_a_z[..., :3]
        J_u[..., 3:, :] = J_a_z[..., 3:]
        J_p = np.zeros(lead + (3, len(self.eq)))
        J_p[..., self.eq, np.arange(len(self.eq))] = theta[..., self.sub_col]
        return f, J_x, J_u, J_p


@dataclass(frozen=True)
class OutputErrorFit:
    """Parameters fitted by output error, with their cluster-robust covariance."""

    names: tuple[str, ...]  # parameters, then "d1", "d2" and "T1", "T2" when the dead times / lags were fitted
    theta: np.ndarray  # (p,) model parameters
    dead_time_s: tuple[float, float]
    cov: np.ndarray  # covariance of [theta, d1, d2, T1, T2] (whichever were fitted, in that order)
    rms_pos_m: float  # RMS position residual over all steps of all windows
    n_windows: int
    nfev: int
    success: bool
    message: str = ""
    input_lag_s: tuple[float, float] = (0.0, 0.0)

    @property
    def std(self) -> np.ndarray:
        """Return the standard deviations of all fitted parameters (dead times last when fitted)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    @property
    def t_stat(self) -> np.ndarray:
        """Return ``|theta| / std`` of the model parameters ``(p,)`` (inf where the std is 0)."""
        sd = self.std[: len(self.theta)]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(sd > 0, np.abs(self.theta) / sd, np.inf)


def lag_sensitivity(windows: Windows, delay_s, lag_s) -> np.ndarray:
    """Return ``d u_seen / d T_i`` ``(W, 2n - 1, 2)`` of the inputs a model sees (input ``i`` on
    its own lag ``T_i``), by central differences of the lagged tracks (forward at ``T_i = 0``)."""
    lag = np.asarray(lag_s, dtype=float)
    d = np.asarray(delay_s, dtype=float)
    if not windows.tracks:
        raise InputError("windows without input tracks cannot apply an input dead time or lag")
    out = np.empty(windows.u_half.shape)
    sides = []
    for i in range(2):
        eps = max(1e-3, 0.02 * lag[i])
        lo, hi = lag.copy(), lag.copy()
        lo[i], hi[i] = max(lag[i] - eps, 0.0), lag[i] + eps
        sides.append((lo, hi))
    # the lagged channels each run's differences take, and the inputs' own (Windows.inputs_for's,
    # asked for next), filtered side by side in one pass
    keys = [(i, side[i]) for i, pair in enumerate(sides) for side in pair if np.any(side > 0.0)]
    keys += [(0, lag[0]), (1, lag[1])] if np.any(lag > 0.0) else []
    for r, _, _ in windows.run_queries:
        windows.tracks[r].lag_channels(keys)
    for i, (lo, hi) in enumerate(sides):
        # Windows.inputs_for's values, in one pass over the runs (the fits' inner loop)
        for r, sel, tq in windows.run_queries:
            track = windows.tracks[r]
            out[sel, :, i] = (track.lagged_at(i, hi, tq, d) - track.lagged_at(i, lo, tq, d)) / (hi[i] - lo[i])
    return out


def rollout_with_sensitivities(dynamics: Dynamics, model: ParametricModel, windows: Windows,
                               fit_dead_time: bool = True, fit_input_lag: bool = False, compiled: bool = True
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Return predicted states ``(W, n, 6)`` and their sensitivities ``(W, n, 6, P)``.

    Classical RK4 with the inputs at the step's start, middle and end, exactly as
    :func:`identification.sindy.evaluate.rollout`; ``P`` is the number of model parameters plus
    the two dead times when ``fit_dead_time`` plus the two input lags when ``fit_input_lag``
    (``d f / d T_i = J_f_u[:, i] d u_i / d T_i``, :func:`lag_sensitivity`). A SINDy structure
    is integrated in one compiled pass when ``compiled``
    (:func:`identification.sindy.sensitivity_rollout.sensitivity_rollout`); otherwise, and for
    other models, by the numpy recursion below.
    """
    delay = np.asarray(dynamics.dead_time_s, dtype=float)
    lag = np.asarray(getattr(dynamics, "input_lag_s", (0.0, 0.0)), dtype=float)
    u_dlag = lag_sensitivity(windows, delay, lag) if fit_input_lag else None  # first: it filters the lags at once
    u_half = windows.inputs_for(delay, lag_s=lag)
    u_rate = windows.inputs_for(delay, rate=True, lag_s=lag) if fit_dead_time else None
    if compiled and isinstance(model, SindyStructure):
        return sensitivity_rollout(dynamics._active_terms(), model.eq, model.factors, model.linear, windows.x0,
                                   u_half, windows.t_rel[1] - windows.t_rel[0], len(windows.t_rel), u_rate, u_dlag)
    p = model.n_params
    n_d = 2 if fit_dead_time else 0
    n_par = p + n_d + (2 if fit_input_lag else 0)
    dt = windows.t_rel[1] - windows.t_rel[0]
    n = len(windows.t_rel)
    t0 = windows.t0_run if windows.t0_run is not None else np.zeros_like(windows.t0)
    s = windows.x0.copy()
    S = np.zeros(s.shape + (n_par,))
    out_s = np.empty((len(s), n, 6))
    out_S = np.empty((len(s), n, 6, n_par))
    out_s[:, 0], out_S[:, 0] = s, S

    def stage(x, Sx, j, t):
        u = u_half[:, j]
        f, J_x, J_u, J_p = model.derivative_and_jacobians(dynamics, x, u, t)
        dS = J_x @ Sx
        dS[:, 3:, :p] += J_p
        if fit_dead_time:
            dS[:, :, p:p + 2] -= J_u * u_rate[:, j][:, None, :]
        if fit_input_lag:
            dS[:, :, p + n_d:] += J_u * u_dlag[:, j][:, None, :]
        return f, dS

    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(n - 1):
            t = t0 + windows.t_rel[i]
            k1, K1 = stage(s, S, 2 * i, t)
            k2, K2 = stage(s + 0.5 * dt * k1, S + 0.5 * dt * K1, 2 * i + 1, t + 0.5 * dt)
            k3, K3 = stage(s + 0.5 * dt * k2, S + 0.5 * dt * K2, 2 * i + 1, t + 0.5 * dt)
            k4, K4 = stage(s + dt * k3, S + dt * K3, 2 * i + 2, t + dt)
            s = s + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            S = S + dt / 6.0 * (K1 + 2.0 * K2 + 2.0 * K3 + K4)
            out_s[:, i + 1], out_S[:, i + 1] = s, S
    return out_s, out_S


def pose_residuals(pred: np.ndarray, windows: Windows) -> np.ndarray:
    """Return ``(W, n - 1, 3)`` residuals ``[dx, dy, w dyaw]`` after the start (heading wrapped, weighted)."""
    d = pred[:, 1:, :3] - windows.pose_truth[:, 1:]
    d[..., 2] = ((d[..., 2] + np.pi) % (2 * np.pi) - np.pi) * HEADING_WEIGHT_M
    return d


def ran_away(r: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Return which windows of residuals ``r (W, n, 3)`` and sensitivities ``J (W, n, 3, P)`` ran
    away: a value non-finite or beyond :data:`RUNAWAY_MAGNITUDE` (the fit and the stepwise score
    test leave them out alike)."""
    with np.errstate(invalid="ignore"):  # nan compares False: not within the bound
        return ~((np.abs(r) <= RUNAWAY_MAGNITUDE).all(axis=(1, 2))
                 & (np.abs(J) <= RUNAWAY_MAGNITUDE).all(axis=(1, 2, 3)))


def compressed(r: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the residuals ``(n + 1,)`` and Jacobian ``(n + 1, n)`` of a least-squares problem
    equivalent to ``r (m,)``, ``J (m, n)`` at this point: ``[Q^T r, |r_perp|]`` and ``[R; 0]``
    for ``J = Q R``.

    Their squared norm is ``|r|^2``, ``J'^T J' = J^T J`` and ``J'^T r' = J^T r``, and the
    Jacobian of the last entry, ``|(I - Q Q^T) r|``, is zero where it is taken (``(I - Q Q^T) J = 0``),
    so a trust-region method takes the same steps and judges them by the same cost, on ``n + 1``
    rows: ``scipy.optimize.least_squares``' exact solver takes an SVD of the Jacobian at every
    step, a third of an output-error fit's time on 36,000 rows (measured on the default campaign).
    ``R`` comes from the Cholesky factor of the Gram matrix of ``[J r]`` with ``J``'s columns
    scaled to unit norm (about 20 times cheaper than the QR decomposition on such shapes), and
    from the QR decomposition when that matrix is not numerically positive definite.
    """
    n = J.shape[1]
    gram = J.T @ J
    norms = np.sqrt(np.clip(np.diag(gram), 0.0, None))
    live = np.flatnonzero(norms > 0)  # a column of zeros adds nothing to either side
    k = len(live)
    s = norms[live]
    G = np.empty((k + 1, k + 1))  # the Gram matrix of [J / norms, r], without forming that matrix
    G[:k, :k] = gram[np.ix_(live, live)] / np.outer(s, s)
    G[:k, k] = G[k, :k] = (J.T @ r)[live] / s
    G[k, k] = r @ r
    try:
        R = cholesky(G, lower=False, check_finite=False)
        d = np.abs(np.diag(R)[:k])
        if not np.all(np.isfinite(R)) or (k and d.min() < MIN_CHOLESKY_PIVOT * d.max()):
            raise LinAlgError("ill-conditioned Gram matrix")
    except LinAlgError:
        R = qr(np.concatenate([J[:, live] / s, r[:, None]], axis=1), mode="r", check_finite=False)[0]
        R = np.vstack([R, np.zeros((k + 1 - R.shape[0], k + 1))]) if R.shape[0] < k + 1 else R[: k + 1]
    r_c = np.zeros(n + 1)
    r_c[:k], r_c[n] = R[:k, k], abs(R[k, k])
    J_c = np.zeros((n + 1, n))
    J_c[:k, live] = R[:k, :k] * norms[live]
    return r_c, J_c


def fit_output_error(model: ParametricModel, theta0: np.ndarray, windows: Windows, dead_time0=(0.0, 0.0),
                     fit_dead_time: bool = True, max_nfev: int = 40, input_lag0=(0.0, 0.0),
                     fit_input_lag: bool = False, compiled: bool = True) -> OutputErrorFit:
    """Return the output-error least-squares fit of ``model``'s parameters (and dead times, and
    first-order input lags) on ``windows``.

    ``windows`` should not overlap (the covariance takes windows as independent clusters).
    Windows whose prediction diverges count :data:`DIVERGED_RESIDUAL_M` per residual with a zero
    Jacobian, so the optimiser steps back from parameters that make a window run away.
    ``compiled`` as in :func:`rollout_with_sensitivities`.
    """
    theta0 = np.asarray(theta0, dtype=float)
    p = len(theta0)
    n_d = 2 if fit_dead_time else 0
    parts0, lower, upper = [theta0], [model.lower], [model.upper]
    if fit_dead_time:
        parts0.append(np.clip(dead_time0, 0.0, MAX_DEAD_TIME_S))
        lower.append([0.0, 0.0])
        upper.append([MAX_DEAD_TIME_S] * 2)
    if fit_input_lag:
        parts0.append(np.clip(input_lag0, 0.0, MAX_INPUT_LAG_S))
        lower.append([0.0, 0.0])
        upper.append([MAX_INPUT_LAG_S] * 2)
    lower, upper = np.concatenate(lower), np.concatenate(upper)
    x0 = np.clip(np.concatenate(parts0), lower, upper)
    fixed_d = tuple(float(d) for d in dead_time0)
    fixed_lag = tuple(float(v) for v in input_lag0)

    def chain(x):
        """Return the dead times and input lags of the parameter vector ``x``."""
        d = tuple(x[p:p + 2]) if fit_dead_time else fixed_d
        lag = tuple(x[p + n_d:p + n_d + 2]) if fit_input_lag else fixed_lag
        return d, lag

    cache: dict = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            dyn = model.build(x[:p], *chain(x))
            pred, sens = rollout_with_sensitivities(dyn, model, windows, fit_dead_time, fit_input_lag, compiled)
            r = pose_residuals(pred, windows)
            J = sens[:, 1:, :3, :].copy()
            J[..., 2, :] *= HEADING_WEIGHT_M
            bad = ran_away(r, J)
            r[bad] = DIVERGED_RESIDUAL_M
            J[bad] = 0.0
            r, J = r.reshape(-1), J.reshape(-1, J.shape[-1])
            cache[key] = (r, J, bad) + compressed(r, J)
        return cache[key]

    # the optimiser sees the (n + 1)-row problem of compressed(): the same cost, gradient and
    # Gauss-Newton matrix at every point, without an SVD of the tall Jacobian per step
    # (a parameter the windows barely move, a dead time of an input that hardly changes, has a huge
    # x_scale="jac" scale: the bounded trust-region step's quadratic for the reflected step then
    # overflows inside scipy; that only decides how far a reflected step may go, and the step taken
    # is judged by the cost like every other: a warning on the user's terminal and nothing else)
    with np.errstate(over="ignore"):
        sol = least_squares(lambda x: evaluate(x)[3], x0, jac=lambda x: evaluate(x)[4], bounds=(lower, upper),
                            method="trf", x_scale="jac", max_nfev=max_nfev, xtol=1e-8, ftol=1e-6)
    r, J, bad = evaluate(sol.x)[:3]
    n_w = windows.n_windows
    per = J.shape[0] // n_w
    Jw = J.reshape(n_w, per, -1)
    rw = r.reshape(n_w, per)
    A = J.T @ J
    g = np.einsum("wkp,wk->wp", Jw, rw)
    B = g.T @ g * (n_w / max(n_w - J.shape[1], 1))  # small-sample correction of the cluster sandwich
    A_inv = np.linalg.pinv(A)
    cov = A_inv @ B @ A_inv
    pos = r.reshape(n_w, per // 3, 3)[..., :2] if per % 3 == 0 else None
    rms = float(np.sqrt(np.mean(np.sum(pos**2, axis=-1)))) if pos is not None else float("nan")
    d, lag = (tuple(float(v) for v in part) for part in chain(sol.x))
    names = tuple(model.names) + (("d1", "d2") if fit_dead_time else ()) + (("T1", "T2") if fit_input_lag else ())
    if bad.any():
        log.info("output-error fit: %d of %d windows diverge at the solution", int(bad.sum()), n_w)
    return OutputErrorFit(names=names, theta=sol.x[:p].copy(), dead_time_s=d, cov=cov, rms_pos_m=rms,
                          n_windows=n_w, nfev=int(sol.nfev), success=bool(sol.success) and not bad.any(),
                          message=str(sol.message), input_lag_s=lag)
