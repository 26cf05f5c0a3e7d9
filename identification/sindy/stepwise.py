"""Term selection by output error: forward-backward stepwise search on the multi-second windows.

The integral regression picks terms by how well they fit velocity differences over ``T``; a model
is scored on what it predicts seconds ahead. On simulator variants the two disagree: the
regression's structure, its coefficients refined by output error, stays at about twice the true
dynamics' 5 s error *on the train windows themselves* (variant 10: 10.8 mm against 4.8 mm), while
the true structure, started 30 % off and refined the same way, reaches the true dynamics' error
(variant 4: 3.7 mm against 3.9 mm). Output error fits coefficients well; the regression's choice
of terms is what costs. So the terms are chosen on the output error too:

1. **Forward**: at the current fit, every term the structure may take (``allowed``) is scored by
   how much it would lower the output-error cost on its own, to first order (the squared
   projection of the residuals on its sensitivity column, made orthogonal to the active terms'
   columns: a Gauss-Newton score test). The best :data:`N_ADD` of each equation are added (per
   equation: the equation with the largest misfit would otherwise take every slot with near-copies
   of its missing term) and the whole structure, dead times and input lags included, is refitted
   by output error.
2. **Backward**: the term with the smallest cluster-robust t statistic
   (:func:`identification.sindy.output_error.fit_output_error`'s covariance, one cluster per
   window) below :data:`~identification.sindy.checks.MIN_T_STAT` is dropped, until every term is
   significant; the protected terms (the first-order lag's core) are never dropped. After each
   drop the pruned structure is refitted (at most :data:`PRUNE_NFEV` evaluations), started from
   the estimate restricted to the dropped term being zero (:func:`wald_drop`, the minimum-distance
   restriction on the fit's estimate and covariance; the refit's for a model linear in its
   parameters only when the covariance is a multiple of ``(J^T J)^-1``),
   so the refit starts next to its optimum. Eliminating every insignificant term on the first
   fit's covariance with one refit at the end was tried (2026-11-25): 5 times faster on the
   default campaign, but on simulator variant 10 it dropped terms that a refit would have kept
   (t statistics of correlated terms change once one of them goes, and the cluster-robust
   covariance is not the refit's): the search's CV error went 7.0 -> 18.2 mm and the selected
   model from 1.42x to 3.05x the true dynamics' test error. Exact linear algebra for the
   restrictions (per-window Gram matrices and scores, the sandwich rebuilt after each drop; commit
   336e506, reverted) fixed variant 10 in one pass but lost variants 4 and 7, and only starting
   each refit there changed nothing measurable but the search path (``docs/identification.md``).
3. Repeated until a round leaves the structure as it was or returns to a structure an earlier round
   ended on (on the default campaign rounds 2 to 4 added and dropped the same few terms in turn),
   at most :data:`MAX_ROUNDS` rounds.

The forward score is a first-order guess; the backward t test on the refitted structure is what
keeps a term. The search runs on the train windows it is given; cross-validation
(:mod:`identification.sindy.identify`) judges it beside the other candidates, refitted per fold.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from identification.sindy.checks import MIN_T_STAT
from identification.sindy.evaluate import Windows
from identification.sindy.model import SindyModel
from identification.sindy.output_error import (
    HEADING_WEIGHT_M,
    OutputErrorFit,
    SindyStructure,
    fit_output_error,
    pose_residuals,
    ran_away,
    rollout_with_sensitivities,
)

log = logging.getLogger(__name__)

#: ``output_error`` of an ``identify`` candidate whose terms this search chooses
STEPWISE = "stepwise"
#: terms added per equation and forward step (the best scores)
N_ADD = 2
#: forward-backward rounds at most (on simulator variants the structure settles in 2 to 4)
MAX_ROUNDS = 4
#: least-squares evaluations of the refit after a backward elimination (it starts at the restricted estimate)
PRUNE_NFEV = 20
#: the coefficient a candidate term is given to make it a parameter of the score's rollout
_SEED = 1e-12


@dataclass(frozen=True)
class StepwiseFit:
    """The structure found by :func:`stepwise_output_error` with its last output-error fit."""

    model: SindyModel
    fit: OutputErrorFit
    rounds: int
    history: tuple[tuple[int, float], ...]  # (active terms, output-error RMS position residual) per round

    @property
    def names(self) -> tuple[str, ...]:
        """Return the free terms, ``"eq: feature"``."""
        return self.fit.names[:len(self.fit.theta)]

    @property
    def t_stat(self) -> np.ndarray:
        """Return the cluster-robust |t| of each free term."""
        return self.fit.t_stat


def _fit(model: SindyModel, windows: Windows, fixed: np.ndarray,
         max_nfev: int) -> tuple[SindyModel, OutputErrorFit, SindyStructure]:
    """Return ``model`` refitted by output error (terms, dead times, input lags), its fit and its structure."""
    spec = SindyStructure(model, fixed)
    fit = fit_output_error(spec, spec.theta0, windows, model.dead_time_s, True, max_nfev=max_nfev,
                           input_lag0=model.input_lag_s, fit_input_lag=True)
    return spec.build(fit.theta, fit.dead_time_s, fit.input_lag_s), fit, spec


def term_scores(model: SindyModel, windows: Windows, fixed: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """Return the first-order decrease of the output-error cost from adding each term, ``(3, k)``.

    Zero for the active terms and for those not ``allowed``. The residuals are taken at
    ``model`` (which should be fitted), the sensitivity of each candidate term made orthogonal
    to the active terms' before its squared projection is taken.
    """
    candidates = allowed & (model.coef == 0) & ~fixed
    scores = np.zeros(model.coef.shape)
    if not candidates.any():
        return scores
    probe = model.with_coefficients(np.where(candidates, _SEED, model.coef), model.dead_time_s, model.input_lag_s)
    spec = SindyStructure(probe, fixed)
    dyn = spec.build(spec.theta0, probe.dead_time_s, probe.input_lag_s)
    pred, sens = rollout_with_sensitivities(dyn, spec, windows, False, False)
    r = pose_residuals(pred, windows)
    J = sens[:, 1:, :3, :].copy()
    J[..., 2, :] *= HEADING_WEIGHT_M
    # a window whose prediction ran away (its squares overflow) says nothing of a term's first-order
    # gain: an overflowed score (inf) would be taken first, a nan one take a slot of the best two
    ok = ~ran_away(r, J)
    r, J = r[ok].reshape(-1), J[ok].reshape(-1, J.shape[-1])
    new = candidates[spec.eq, spec.col]
    if (~new).any():
        q, _ = np.linalg.qr(J[:, ~new])
        Jn = J[:, new] - q @ (q.T @ J[:, new])
    else:
        Jn = J[:, new]
    scores[spec.eq[new], spec.col[new]] = (Jn.T @ r) ** 2 / np.maximum(np.sum(Jn**2, axis=0), 1e-300)
    return scores


def wald_drop(fit: OutputErrorFit, droppable: np.ndarray, min_t: float = MIN_T_STAT,
              max_drops: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return the parameters after backward elimination on ``fit``'s estimate and covariance, and the mask of dropped ones.

    The parameter vector is ``[theta, dead times, input lags]`` (whichever were fitted,
    ``fit.cov``'s order); only model parameters where ``droppable`` (``(p,)``) may go. While the
    smallest ``|theta_k| / std_k`` of the droppable terms left is below ``min_t``, that term is
    restricted to zero: ``x <- x - S[:, k] x_k / S_kk`` and ``S <- S - S[:, k] S[k, :] / S_kk``
    (the estimate closest to ``x`` in ``S``'s metric with ``x_k = 0``, and its covariance; for a
    model linear in ``x`` it is the refit without the term when ``S`` is a multiple of ``(J^T J)^-1``,
    not for the cluster sandwich). At most ``max_drops`` terms go (all
    that qualify when None).
    """
    p = len(fit.theta)
    x = np.concatenate([fit.theta, fit.dead_time_s if "d1" in fit.names else [],
                        fit.input_lag_s if "T1" in fit.names else []]).astype(float)
    S = np.array(fit.cov, dtype=float)
    alive = np.asarray(droppable, bool).copy()
    dropped = np.zeros(p, bool)
    while alive.any() and (max_drops is None or dropped.sum() < max_drops):
        sd = np.sqrt(np.clip(np.diag(S)[:p], 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(sd > 0, np.abs(x[:p]) / sd, np.inf)
        t = np.where(alive, t, np.inf)
        k = int(np.argmin(t))
        if not t[k] < min_t:
            break
        x = x - S[:, k] * (x[k] / S[k, k])
        S = S - np.outer(S[:, k], S[k, :]) / S[k, k]
        alive[k], dropped[k] = False, True
        x[np.flatnonzero(dropped)] = 0.0  # exactly (the updates leave rounding there)
        S[k, :], S[:, k] = 0.0, 0.0
    return x[:p], dropped


def stepwise_output_error(model: SindyModel, windows: Windows, allowed: np.ndarray, protected: np.ndarray,
                          fixed: np.ndarray | None = None, n_add: int = N_ADD, max_rounds: int = MAX_ROUNDS,
                          max_nfev: int = 40) -> StepwiseFit:
    """Return the structure of the module docstring's search from ``model`` (its terms, coefficients,
    dead times and input lags the start) on ``windows``.

    ``allowed`` (3, k): terms that may be added; ``protected`` (3, k): terms never dropped;
    ``fixed`` (3, k): terms no fit moves (an unexcited state's damping). Windows should not overlap
    (the t statistics take them as independent clusters).
    """
    fixed = np.zeros(model.coef.shape, bool) if fixed is None else np.asarray(fixed, bool)
    current, fit, spec = _fit(model, windows, fixed, max_nfev)
    history = [(current.complexity, fit.rms_pos_m)]
    seen = {(current.coef != 0).tobytes()}
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        before = current.coef != 0
        scores = term_scores(current, windows, fixed, allowed)
        best = np.argsort(scores, axis=1)[:, ::-1][:, :n_add]  # (3, n_add) per equation
        eq = np.broadcast_to(np.arange(3)[:, None], best.shape)
        take = np.take_along_axis(scores, best, axis=1) > 0.0
        coef = current.coef.copy()
        coef[eq[take], best[take]] = _SEED
        current, fit, spec = _fit(current.with_coefficients(coef, current.dead_time_s, current.input_lag_s),
                                  windows, fixed, max_nfev)
        while True:
            theta, dropped = wald_drop(fit, ~protected[spec.eq, spec.col], max_drops=1)
            if not dropped.any():
                break
            coef = current.coef.copy()
            coef[spec.eq, spec.col] = np.where(dropped, 0.0, theta)
            current, fit, spec = _fit(current.with_coefficients(coef, current.dead_time_s, current.input_lag_s),
                                      windows, fixed, PRUNE_NFEV)
        history.append((current.complexity, fit.rms_pos_m))
        log.debug("stepwise output error, round %d: %d terms, RMS %.4f m", rounds, current.complexity, fit.rms_pos_m)
        structure = (current.coef != 0).tobytes()
        if np.array_equal(before, current.coef != 0) or structure in seen:
            break
        seen.add(structure)
    return StepwiseFit(current, fit, rounds, tuple(history))
