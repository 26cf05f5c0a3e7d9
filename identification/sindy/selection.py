"""Which grid point the search selects and which candidate ``identify`` selects: admissibility
and the one-standard-error rule.

The rules of :func:`identification.sindy.search.search` over its ranked table (thesis section
7.3.3 for the grid, Hastie, Tibshirani and Friedman 7.10 for the rule), apart so that the search
itself stays one module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from groundfloor.errors import InputError


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


@dataclass(frozen=True)
class Candidate:
    """One candidate of the output-error stage with its cross-validated score."""

    label: str  # "lag" or "grid rank N"
    hyperparameters: dict | None  # the screening's grid point, None for the lag
    fold_rms_m: np.ndarray  # (folds,) RMS 5 s position error on each held-out fold
    fold_n: np.ndarray  # (folds,) windows per held-out fold
    fold_yaw_deg: np.ndarray  # (folds,) RMS 5 s heading error on each held-out fold
    complexity: float  # mean number of active terms over the folds
    passed: bool  # the models of most folds (more than half) passed the checks
    failed: tuple[str, ...] = ()

    @property
    def cv_pos_err_5s_m(self) -> float:
        """Return the RMS 5 s position error over all held-out windows."""
        n = self.fold_n.sum()
        return float(np.sqrt(np.sum(self.fold_n * self.fold_rms_m**2) / n)) if n else float("nan")

    @property
    def cv_yaw_err_5s_deg(self) -> float:
        """Return the RMS 5 s heading error over all held-out windows."""
        n = self.fold_n.sum()
        return float(np.sqrt(np.sum(self.fold_n * self.fold_yaw_deg**2) / n)) if n else float("nan")

    @property
    def cv_se_m(self) -> float:
        """Return the standard error of the CV error over the folds (std of the fold RMS / sqrt(folds))."""
        scored = self.fold_n > 0
        if scored.sum() < 2:
            return float("nan")
        with np.errstate(invalid="ignore"):  # a diverged fold (inf) makes it nan, which it is
            return float(np.std(self.fold_rms_m[scored], ddof=1) / np.sqrt(scored.sum()))

    def summary(self) -> dict:
        """Return the JSON-ready description."""
        return {"label": self.label, "hyperparameters": self.hyperparameters,
                "cv_pos_err_5s_m": self.cv_pos_err_5s_m, "cv_se_m": self.cv_se_m,
                "cv_yaw_err_5s_deg": self.cv_yaw_err_5s_deg,
                "fold_pos_err_5s_m": [float(v) for v in self.fold_rms_m], "complexity": self.complexity,
                "passed_checks": self.passed, "failed_checks": list(self.failed)}


def select_candidate(candidates: Sequence[Candidate]) -> int:
    """Return the index of the sparsest candidate that passed its checks and lies within one
    standard error of the best such candidate's CV error (the one-standard-error rule over folds)."""
    ok = [i for i, c in enumerate(candidates) if c.passed and np.isfinite(c.cv_pos_err_5s_m)]
    if not ok:
        why = "; ".join(f"{c.label}: " + (f"fails {', '.join(c.failed)}" if not c.passed else
                                          f"diverged in {int(np.sum(~np.isfinite(c.fold_rms_m)))} of "
                                          f"{len(c.fold_rms_m)} folds")
                        for c in candidates)
        raise InputError(f"identification: no candidate passed the well-posedness checks in most folds ({why})")
    best = min(ok, key=lambda i: candidates[i].cv_pos_err_5s_m)
    se = candidates[best].cv_se_m
    limit = candidates[best].cv_pos_err_5s_m + (se if np.isfinite(se) else 0.0)
    within = [i for i in ok if candidates[i].cv_pos_err_5s_m <= limit]
    return min(within, key=lambda i: (candidates[i].complexity, candidates[i].cv_pos_err_5s_m))
