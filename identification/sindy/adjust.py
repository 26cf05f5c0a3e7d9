"""Least-squares adjustment of the active SINDy coefficients (thesis 5.3.9 and 7.9).

Functional model eq. 5.79: only the state differences are observations,
``Delta x_i + v_i = Theta'_active xi_i``, one Gauss-Markov model per equation (the equations do
not share parameters, so the joint covariance is block-diagonal, as the thesis found). The
adjustment gives the coefficients, their covariance ``sigma0^2 (A^T A)^-1``, the correlation
matrix (fig. 7.12) and its strongest entries (table 7.7).

Overlapping integration windows make the observations correlated, so ``sigma0`` and the
standard deviations are optimistic; the correlations, which are what the thesis discusses,
depend only on ``A`` and are unaffected.

The thesis's proposed cure (section 7.9), targeted subsampling of low-acceleration data, is
:func:`subsample_low_acceleration`; :func:`subsampling_effect` measures what it does to the
correlations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundfloor.errors import InputError
from identification.sindy.library import LIBRARY_STATE_NAMES
from identification.sindy.model import SindyModel
from identification.sindy.regression import IntegralProblem, condition_from_singular_values


@dataclass(frozen=True)
class Adjustment:
    """Adjusted active coefficients with covariance and correlation (eq. 5.79)."""

    terms: tuple[tuple[str, str], ...]  # (equation, feature name) per parameter
    coef: np.ndarray  # (p,)
    cov: np.ndarray  # (p, p), block-diagonal by equation
    corr: np.ndarray  # (p, p)
    sigma0: dict  # equation -> a-posteriori std of unit weight (m/s or rad/s)
    condition_number: dict  # equation -> cond(A) of its active columns
    n_obs: int

    @property
    def coef_std(self) -> np.ndarray:
        """Standard deviations of the coefficients ``(p,)``."""
        return np.sqrt(np.diag(self.cov))

    def strongest_correlations(self, n: int = 15) -> list[tuple[float, str, str]]:
        """Return the ``n`` largest ``|correlation|`` pairs as ``(rho, term A, term B)`` (table 7.7)."""
        iu, ju = np.triu_indices(len(self.coef), k=1)
        rho = self.corr[iu, ju]
        order = np.argsort(-np.abs(rho), kind="stable")[:n]
        return [(float(rho[o]), f"{self.terms[iu[o]][0]}: {self.terms[iu[o]][1]}",
                 f"{self.terms[ju[o]][0]}: {self.terms[ju[o]][1]}") for o in order if rho[o] != 0]

    def max_abs_correlation(self) -> float:
        """Return the largest off-diagonal ``|correlation|``."""
        c = np.abs(self.corr - np.diag(np.diag(self.corr)))
        return float(c.max()) if c.size else 0.0


def adjust_coefficients(model: SindyModel, problem: IntegralProblem, rows: np.ndarray | None = None) -> Adjustment:
    """Return the least-squares adjustment of ``model``'s active terms on ``problem`` (eq. 5.79).

    Parameters
    ----------
    model : SindyModel
        Gives the active terms (non-zero coefficients) per equation.
    problem : IntegralProblem
        Integral regression of the same library (``theta_int``, ``delta_x``).
    rows : ndarray of bool or int, optional
        Windows to use (e.g. from :func:`subsample_low_acceleration`); all by default.

    Raises
    ------
    InputError
        If the libraries differ, no term is active, or an equation has no redundancy.
    """
    if problem.library.feature_names != model.library.feature_names:
        raise InputError(f"adjustment: model library {model.library.name!r} differs from the problem's "
                         f"{problem.library.name!r}")
    theta = problem.theta_int if rows is None else problem.theta_int[rows]
    dx = problem.delta_x if rows is None else problem.delta_x[rows]
    terms, coefs, blocks, sigma0, cond = [], [], [], {}, {}
    for i, eq in enumerate(LIBRARY_STATE_NAMES):
        active = np.flatnonzero(model.coef[i])
        if not len(active):
            continue
        a = theta[:, active]
        if len(a) <= len(active):
            raise InputError(f"adjustment: equation {eq}: {len(a)} windows for {len(active)} active terms")
        # least squares on A's SVD rather than inverting A^T A: A is badly conditioned (the thesis's
        # finding); one SVD gives the solution (lstsq's, its default cutoff), (A^T A)^-1 and the condition
        us, sv, vt = np.linalg.svd(a, full_matrices=False)
        kept = sv > np.finfo(float).eps * max(a.shape) * sv[0]
        xi = vt[kept].T @ ((us[:, kept].T @ dx[:, i]) / sv[kept])
        v = a @ xi - dx[:, i]
        s0 = float(np.sqrt(v @ v / (len(a) - len(active))))
        n_inv = (vt.T / sv**2) @ vt  # stable where the normal matrix is not
        terms += [(eq, model.library.feature_names[j]) for j in active]
        coefs.append(xi)
        blocks.append(s0**2 * n_inv)
        sigma0[eq] = s0
        cond[eq] = condition_from_singular_values(sv)
    if not terms:
        raise InputError("adjustment: the model has no active terms")
    p = len(terms)
    cov = np.zeros((p, p))
    k = 0
    for b in blocks:
        cov[k:k + len(b), k:k + len(b)] = b
        k += len(b)
    d = np.sqrt(np.diag(cov))
    corr = cov / np.outer(d, d)
    return Adjustment(terms=tuple(terms), coef=np.concatenate(coefs), cov=cov, corr=corr, sigma0=sigma0,
                      condition_number=cond, n_obs=len(theta))


def nonoverlapping_rows(problem: IntegralProblem) -> np.ndarray:
    """Return a boolean mask of windows that do not overlap: per run, each starts a window length
    ``tau`` after the last kept one. Their residuals are (nearly) independent, so the adjustment's
    standard errors on them are not optimistic (overlapping windows share most of their samples)."""
    keep = np.zeros(problem.n_windows, bool)
    for r in np.unique(problem.run_index):
        idx = np.flatnonzero(problem.run_index == r)
        next_t = -np.inf
        for i in idx[np.argsort(problem.t_start[idx], kind="stable")]:
            if problem.t_start[i] >= next_t - 1e-9:
                keep[i] = True
                next_t = problem.t_start[i] + problem.tau
    return keep


def prune_insignificant(model: SindyModel, problem: IntegralProblem, protected: np.ndarray, min_t: float = 2.0,
                        rows: np.ndarray | None = None, fixed: np.ndarray | None = None
                        ) -> tuple[SindyModel, Adjustment]:
    """Return ``model`` with its non-significant terms dropped one by one, and the last adjustment.

    Backward elimination on the adjustment of eq. 5.79 over non-overlapping windows
    (:func:`nonoverlapping_rows`, within ``rows`` when given): while some term that is not
    ``protected`` (a ``(3, k)`` mask) has ``|coefficient| / std < min_t``, the weakest one is
    dropped and the rest readjusted (one at a time: collinear terms, the thesis's finding, can
    each look insignificant while together they are not). The returned coefficients are the
    adjustment's; terms in ``fixed`` (a ``(3, k)`` mask) are neither adjusted nor dropped.
    """
    keep = nonoverlapping_rows(problem) if rows is None else nonoverlapping_rows(problem) & rows
    fixed = np.zeros(model.coef.shape, bool) if fixed is None else np.asarray(fixed, bool)
    held = np.where(fixed, model.coef, 0.0)
    while True:
        free_model = model.with_coefficients(np.where(fixed, 0.0, model.coef))
        adj = adjust_coefficients(free_model, problem, rows=keep)
        t = np.abs(adj.coef) / np.where(adj.coef_std > 0, adj.coef_std, np.inf)
        eq, col = np.nonzero(free_model.coef)  # the adjustment's parameter order
        free = ~protected[eq, col]
        coef = held.copy()
        coef[eq, col] = adj.coef
        if not free.any() or t[free].min() >= min_t:
            return model.with_coefficients(coef), adj
        k = np.flatnonzero(free)[np.argmin(t[free])]
        coef[eq[k], col[k]] = 0.0
        model = model.with_coefficients(coef)


def subsample_low_acceleration(problem: IntegralProblem, keep_fraction: float = 0.2, quantile: float = 0.5,
                               seed: int = 0) -> np.ndarray:
    """Return a boolean mask of windows: all high-acceleration windows, a random few low ones.

    The mean acceleration of a window is ``Delta x / tau``; each component is scaled by its
    standard deviation over all windows and the norm taken. Windows below the ``quantile`` of
    that norm (steady driving or standing still, where ``vx`` tracks ``u1`` and ``omega``
    tracks ``u2`` and the columns become collinear) are kept with probability
    ``keep_fraction`` (section 7.9's proposal).
    """
    if not 0 < keep_fraction <= 1 or not 0 < quantile < 1:
        raise InputError(f"subsampling: keep_fraction={keep_fraction} must be in (0, 1], quantile={quantile} in (0, 1)")
    acc = problem.delta_x / problem.tau
    acc_norm = np.linalg.norm(acc / np.maximum(acc.std(axis=0), 1e-12), axis=1)
    low = acc_norm < np.quantile(acc_norm, quantile)
    rng = np.random.default_rng(seed)
    return ~low | (rng.random(len(low)) < keep_fraction)


def subsampling_effect(model: SindyModel, problem: IntegralProblem, keep_fraction: float = 0.2,
                       quantile: float = 0.5, seed: int = 0) -> dict:
    """Return the correlations before and after low-acceleration subsampling (section 7.9)."""
    before = adjust_coefficients(model, problem)
    mask = subsample_low_acceleration(problem, keep_fraction, quantile, seed)
    after = adjust_coefficients(model, problem, rows=mask)

    def stats(adj: Adjustment) -> dict:
        off = np.abs(adj.corr[np.triu_indices(len(adj.coef), 1)])
        off = off[off > 0]
        return {"max_abs_corr": float(off.max()) if off.size else 0.0,
                "mean_abs_corr": float(off.mean()) if off.size else 0.0,
                "n_above_0.9": int(np.sum(off > 0.9)), "condition_number": adj.condition_number,
                "n_windows": adj.n_obs}

    return {"before": stats(before), "after": stats(after), "kept_fraction": float(mask.mean())}
