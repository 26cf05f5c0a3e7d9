"""Which grid point the search selects: admissibility and the one-standard-error rule.

The rules of :func:`identification.sindy.search.search` over its ranked table (thesis section
7.3.3 for the grid, Hastie, Tibshirani and Friedman 7.10 for the rule), apart so that the search
itself stays one module.
"""

from __future__ import annotations

import numpy as np

def admissible(table: dict[str, np.ndarray]) -> np.ndarray:
    """Return, per row, whether the model is stable at rest and never diverged on a held-out window.

    Stable at rest: every eigenvalue of ``J_f_x(0, 0)`` of every fold's model has a real part
    <= :data:`identification.sindy.checks.STABILITY_TOL` (a robot left alone must come to rest, not run away). Diverged: a
    rollout went non-finite or beyond ``blowup_factor`` times the training velocities.
    """
    ok = np.asarray(table["stable_at_rest"], bool) & (np.asarray(table["diverged_frac"]) == 0)
    return ok & np.isfinite(np.asarray(table["pos_err_5s_m"], float))


def select_one_se(table: dict[str, np.ndarray]) -> int:
    """Return the row of the sparsest admissible model within one standard error of the best.

    The "one-standard-error rule" of cross-validated model selection (Breiman et al. 1984;
    Hastie, Tibshirani and Friedman, *Elements of Statistical Learning*, 7.10): the best
    admissible CV score ``e*`` is uncertain by its standard error over the folds ``se*``
    (std of the per-fold RMS 5 s errors / sqrt(n_folds)); every model scoring
    ``<= e* + se*`` is statistically as good, and the sparsest of them is taken (ties in
    complexity go to the lower error). Inadmissible rows (:func:`admissible`) are never
    selected unless no row is admissible, then the best row is returned. ``table`` is sorted
    by :func:`search` (admissible first, best first).
    """
    ok = admissible(table)
    if not ok.any():
        return 0
    err = np.asarray(table["pos_err_5s_m"], float)
    best = int(np.flatnonzero(ok)[np.argmin(err[ok])])
    se = float(table["pos_err_5s_se_m"][best])
    limit = err[best] + (se if np.isfinite(se) else 0.0)
    cand = np.flatnonzero(ok & (err <= limit))
    return int(cand[np.lexsort((err[cand], np.asarray(table["complexity"])[cand]))[0]])


def select_parsimonious(table: dict[str, np.ndarray], rel_tol: float = 0.05) -> int:
    """Return the row of the sparsest model whose CV 5 s position error is within ``rel_tol`` of the best.

    The earlier fixed-tolerance rule, kept for comparison (:func:`select_one_se` is the
    default). Only admissible rows (:func:`admissible`) count when there are any. Ties in
    complexity go to the lower error. ``table`` is sorted best first.
    """
    err = np.asarray(table["pos_err_5s_m"], float)
    okay = admissible(table)
    pool = okay if okay.any() else np.ones(len(err), bool)
    best = err[pool].min()
    ok = np.flatnonzero(pool & (err <= (1 + rel_tol) * best))
    return int(ok[np.lexsort((err[ok], np.asarray(table["complexity"])[ok]))[0]])
