"""Integral SINDy with control: the regression matrix of eqs. 5.53 to 5.59 and its sparse fit.

pysindy 2.1 has no integral (weak) SINDy with control for ODEs, so the integral regression
matrix is built here and plain arrays go to ``pysindy.optimizers.STLSQ``:

- features ``Theta(x(t), u(t))`` at every sample, integrated with the trapezoidal rule as a
  running integral per run (``scipy.integrate.cumulative_trapezoid``), so that every window
  ``[t_j, t_j + tau]`` is one subtraction: ``Theta'_j = C(t_end) - C(t_j)`` (eq. 5.56);
- targets ``Delta x_j = x(t_end) - x(t_j)`` (eq. 5.55);
- every sample starts a window; windows that would cross a run's end or a gap in the data
  longer than ``max_gap_s`` (:data:`MAX_WINDOW_STEP_S`) are dropped, so poses further apart than
  that in every run leave no window: :func:`check_pose_spacing` says so before the work starts.

The ridge problems of STLSQ only see ``Theta'`` through its Gram matrix, so a thin QR
factorisation ``Theta' = Q R`` turns the (windows x features) problem into the equivalent
(features x features) one ``R Xi = Q^T Delta X`` (same objective up to a constant, same
thresholding): STLSQ gives the same coefficients for a fraction of the cost (tested), which is
what makes the full hyperparameter search affordable. Per-run factors stack, so
cross-validation folds are assembled from them without touching the windows again.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.integrate import cumulative_trapezoid
from threadpoolctl import threadpool_limits

from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.library import (
    LIBRARY_INPUT_NAMES,
    LIBRARY_STATE_NAMES,
    FeatureLibrary,
    make_library,
)
from identification.sindy.model import SindyModel, envelope_from_data

log = logging.getLogger(__name__)

COND_WARN = 1e8  # above this the integral regression is reported as ill-conditioned


class IllConditionedWarning(UserWarning):
    """The integral regression matrix is badly conditioned; the message gives its condition number."""


@dataclass(frozen=True)
class IntegralProblem:
    """The integral regression ``Delta X = Theta' Xi`` of eq. 5.57, with per-run compressions.

    Attributes
    ----------
    theta_int : ndarray (p, k)
        Integrated features ``Theta'`` (eq. 5.56), one row per window.
    delta_x : ndarray (p, 3)
        State differences ``Delta X`` (eq. 5.55).
    run_index : ndarray (p,)
        Index into ``run_names`` of the run each window belongs to.
    r_factors, qt_targets : list of ndarray
        Per run, the triangular factor ``R_r`` (k', k) and ``Q_r^T Delta X_r`` (k', 3).
    """

    theta_int: np.ndarray
    delta_x: np.ndarray
    run_index: np.ndarray
    t_start: np.ndarray
    run_names: tuple[str, ...]
    library: FeatureLibrary
    tau: float
    r_factors: tuple[np.ndarray, ...]
    qt_targets: tuple[np.ndarray, ...]

    @property
    def n_windows(self) -> int:
        """Number of integration windows."""
        return len(self.delta_x)

    def compressed(self, runs: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(R, c)`` with ``||R xi - c||`` equal to the residual over ``runs`` up to a constant."""
        runs = range(len(self.run_names)) if runs is None else runs
        r = np.vstack([self.r_factors[i] for i in runs])
        c = np.vstack([self.qt_targets[i] for i in runs])
        return r, c


#: an integral window never spans a step between samples longer than this, s (the trapezoid of a
#: longer one is no integral of the motion: a turn of a skid-steered robot settles within it)
MAX_WINDOW_STEP_S = 0.2


def check_pose_spacing(times: Sequence[np.ndarray], names: Sequence[str], what: str,
                       max_step_s: float = MAX_WINDOW_STEP_S) -> None:
    """Raise a one-line InputError when the sample times ``times`` (one array per run) are more
    than ``max_step_s`` apart (median over all runs): poses so sparse (GNSS at 2 Hz, say) that
    almost every integral window would cross a step longer than its integral allows, and nothing
    would be fitted."""
    steps = np.concatenate([np.diff(np.asarray(t, dtype=float)) for t in times] or [np.empty(0)])
    median = float(np.median(steps)) if steps.size else float("nan")
    if median > max_step_s:
        raise InputError(f"{what} {', '.join(names)}: poses {1e3 * median:.0f} ms apart (median): the integral "
                         f"windows never cross a step longer than {1e3 * max_step_s:.0f} ms; give poses at "
                         f"{1 / max_step_s:.0f} Hz or more")


def check_states(states: Sequence[BodyStates], names: Sequence[str], allow_constant: Sequence[str] = ()) -> None:
    """Raise InputError if a run has missing values or the inputs cannot be identified.

    Constant (or all-missing) inputs over all runs make the input terms unidentifiable, unless
    named in ``allow_constant`` (the identification leaves their terms out).
    """
    if not states:
        raise InputError("identification: no training runs")
    for st, name in zip(states, names):
        for col in ("t",) + LIBRARY_STATE_NAMES + LIBRARY_INPUT_NAMES:
            v = np.asarray(getattr(st, col), dtype=float)
            if len(v) != len(st.t):
                raise InputError(f"run {name}: column {col} has {len(v)} values for {len(st.t)} times")
            if not np.all(np.isfinite(v)):
                raise InputError(f"run {name}: column {col} has {np.count_nonzero(~np.isfinite(v))} missing "
                                 "or non-finite values")
        if len(st.t) > 1 and np.any(np.diff(st.t) <= 0):
            raise InputError(f"run {name}: times are not strictly increasing")
    for col in (c for c in LIBRARY_INPUT_NAMES if c not in allow_constant):
        u = np.concatenate([np.asarray(getattr(st, col), dtype=float) for st in states])
        if np.ptp(u) < 1e-6:
            raise InputError(f"input {col}: constant ({u[0]:.3g}) over all training runs "
                             f"({', '.join(names)}): its terms cannot be identified")


def integral_problem(states: Sequence[BodyStates], library: FeatureLibrary | str = "poly3", tau: float = 3.0,
                     names: Sequence[str] | None = None, max_gap_s: float = MAX_WINDOW_STEP_S,
                     allow_constant: Sequence[str] = ()) -> IntegralProblem:
    """Return the integral regression problem of eqs. 5.55 to 5.57 over several runs.

    Parameters
    ----------
    states : sequence of BodyStates
        Body-frame states and inputs per run (the runs are never joined by a window).
    library : FeatureLibrary or str
        Candidate functions.
    tau : float
        Integration window length, s.
    names : sequence of str, optional
        Run names for messages.
    max_gap_s : float
        Windows containing a time step longer than this are dropped.
    allow_constant : sequence of str
        Inputs that may be constant (their terms are left out by the caller).

    Raises
    ------
    InputError
        Missing values, constant inputs, or fewer windows than features.
    """
    library = make_library(library) if isinstance(library, str) else library
    names = tuple(names) if names is not None else tuple(f"#{i}" for i in range(len(states)))
    check_states(states, names, allow_constant)
    if not tau > 0:
        raise InputError(f"tau={tau}: the integration window length must be positive")
    thetas, dxs, runs, t0s, rs, cs = [], [], [], [], [], []
    for i, st in enumerate(states):
        t = np.asarray(st.t, dtype=float) - st.t[0]
        x = st.state
        theta = library.transform(np.column_stack([x, st.inputs]))
        c_int = cumulative_trapezoid(theta, t, axis=0, initial=0.0)
        end = np.searchsorted(t, t + tau * (1 - 1e-9))
        big_gap = np.concatenate([[0], np.cumsum(np.diff(t) > max_gap_s)])
        ok = np.flatnonzero(end < len(t))
        ok = ok[big_gap[end[ok]] == big_gap[ok]]
        th = c_int[end[ok]] - c_int[ok]
        dx = x[end[ok]] - x[ok]
        thetas.append(th)
        dxs.append(dx)
        runs.append(np.full(len(ok), i))
        t0s.append(st.t[ok])
        if len(ok):
            with threadpool_limits(limits=1, user_api="blas"):  # tall-skinny QR: threads only contend
                q, r = np.linalg.qr(th, mode="reduced")
            rs.append(r)
            cs.append(q.T @ dx)
        else:
            rs.append(np.zeros((0, library.n_features)))
            cs.append(np.zeros((0, 3)))
    theta_int = np.vstack(thetas)
    if len(theta_int) < library.n_features:
        raise InputError(f"tau={tau:g} s: only {len(theta_int)} integration windows in runs "
                         f"{', '.join(names)} for {library.n_features} features of library {library.name!r}")
    return IntegralProblem(theta_int=theta_int, delta_x=np.vstack(dxs), run_index=np.concatenate(runs),
                           t_start=np.concatenate(t0s), run_names=names, library=library, tau=float(tau),
                           r_factors=tuple(rs), qt_targets=tuple(cs))


def condition_number(r: np.ndarray) -> float:
    """Return the 2-norm condition number of a regression matrix (or of its R factor)."""
    return condition_from_singular_values(np.linalg.svd(r, compute_uv=False))


def condition_from_singular_values(s: np.ndarray) -> float:
    """Return the 2-norm condition number from a matrix's singular values ``s`` (descending)."""
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def check_conditioning(r: np.ndarray, what: str) -> float:
    """Return the condition number of ``r``; warn with it when above :data:`COND_WARN`."""
    cond = condition_number(r)
    if cond > COND_WARN:
        msg = f"{what}: ill-conditioned integral regression, condition number {cond:.3g}"
        log.warning(msg)
        warnings.warn(msg, IllConditionedWarning, stacklevel=2)
    return cond


def fit_stlsq(theta: np.ndarray, target: np.ndarray, threshold: float, alpha: float,
              max_iter: int = 20, normalize: bool = False) -> np.ndarray:
    """Return STLSQ coefficients ``(n_targets, k)`` of ``target ~ theta @ coef.T`` (eqs. 5.58, 5.59).

    A thin wrapper on ``pysindy.optimizers.STLSQ``: pysindy's warnings about thresholds that
    remove every term are silenced (they are expected during a grid search).

    With ``normalize`` the regression is solved on unit-norm columns of ``theta`` and a
    unit-norm target per equation, so ``threshold`` and ``alpha`` are dimensionless:
    a term is dropped when ``|xi_ej| ||theta_j|| / ||target_e|| < threshold``, i.e. when at
    its typical size it carries less than that fraction of its equation's signal, whatever
    the units, the window length ``tau`` or the number of windows (pysindy's own
    ``normalize_columns`` scales the columns only, so one threshold would still compare a
    lateral-velocity equation with a forward one). Both norms are unchanged by the QR
    compression of :class:`IntegralProblem` (``||R e_j|| = ||Theta' e_j||``, ``Q^T Delta X``
    is the projection of the targets), so the compressed and the full problem still agree.
    """
    from pysindy.optimizers import (
        STLSQ,  # local: pysindy loads scikit-learn (about 2 s); only fitting needs it
    )

    theta = np.asarray(theta, dtype=float)
    target = np.asarray(target, dtype=float)
    if normalize:
        col = np.linalg.norm(theta, axis=0)
        col = np.where(col > 0, col, 1.0)
        tgt = np.linalg.norm(target, axis=0)
        tgt = np.where(tgt > 0, tgt, 1.0)
        theta, target = theta / col, target / tgt
    opt = STLSQ(threshold=threshold, alpha=alpha, max_iter=max_iter)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(theta, target)
    coef = np.asarray(opt.coef_, dtype=float).reshape(target.shape[1], theta.shape[1])
    return coef * tgt[:, None] / col[None, :] if normalize else coef


def fit_sindy(states: Sequence[BodyStates], library: FeatureLibrary | str = "poly3", tau: float = 3.0,
              alpha: float = 10.0, threshold: float = 0.25, smoothing: float | None = None,
              names: Sequence[str] | None = None, problem: IntegralProblem | None = None,
              normalize: bool = False) -> SindyModel:
    """Return the SINDy model fitted on all windows of ``states`` (eqs. 5.53 to 5.59).

    ``problem`` may pass a precomputed :func:`integral_problem` of the same states. The model's
    ``training`` records the condition number, the number of windows and the runs.
    ``normalize`` makes ``threshold`` and ``alpha`` dimensionless (see :func:`fit_stlsq`).
    """
    problem = problem or integral_problem(states, library, tau, names)
    r, c = problem.compressed()
    cond = check_conditioning(r, f"runs {', '.join(problem.run_names)}, tau={problem.tau:g} s")
    coef = fit_stlsq(r, c, threshold=threshold, alpha=alpha, normalize=normalize)
    x = np.vstack([st.state for st in states])
    u = np.vstack([st.inputs for st in states])
    return SindyModel(
        library=problem.library, coef=coef,
        hyperparameters={"s": smoothing, "tau": problem.tau, "alpha": float(alpha), "T": float(threshold),
                         "normalize": bool(normalize)},
        envelope=envelope_from_data(x, u),
        training={"condition_number": cond, "n_windows": problem.n_windows, "runs": list(problem.run_names)},
    )
