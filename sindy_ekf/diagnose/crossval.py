"""The fixed-model gain of an input-side family scored by leaving out one run at a time, over every run.

A family's gain used to be scored on the test runs alone, with its parameters from the train runs
(the additive families still are: scored run by run, a tilted floor's columns found small systematic
structure in effect-free campaigns whose lab model is imperfect, beyond its calibrated null).
A campaign with one or two test runs then judges every mechanism by those runs, whatever they hold
of their own: the real ``warthog-drive-cmd`` campaign's one test run answers its inputs 0.17 s
*earlier* than the model and a 0.15 s delay injected into every run moved that run's 5 s error by
2.7 % (the train runs' by 11 %), so the delay was never named (``docs/diagnosis.md``).

Here every run is held out once (train and test runs alike): the mechanism's parameter by the
profile of the other runs' residuals over its grid (refined between grid points by the parabola),
its linear coefficients and its nuisance (an input-side mechanism's gain nuisance, the floor
patch's uniform damping) fitted on the other runs, and the held-out run's weighted window residual
compared with that of the null fitted on the same other runs. The gain is ``1 - sum_r SSE_r / sum_r
SSE0_r``: every window of the campaign scored once, out of sample. The per-run normal equations
(:func:`sindy_ekf.diagnose.columns.design_for`) make each fold a solve, not a new design; a
mechanism with a geometry (the floor patch's centre and radius, the smooth field's frame) keeps the
one the train runs chose. The equation weights and an input-side family's recalibrated input gains
come from the train runs, as before. The model itself was identified on the train runs, so on a
held-out train run it has seen that run: a mechanism it absorbed gains less there, which the
re-identified scoring (:func:`sindy_ekf.diagnose.fitting.refit_score`, train -> test) is for.
"""

from __future__ import annotations

import numpy as np

from sindy_ekf.diagnose.columns import design_for, null_columns
from sindy_ekf.diagnose.data import Split
from sindy_ekf.diagnose.design import Design, concat_designs, normal_equations, solve_design
from sindy_ekf.diagnose.families import Family
from sindy_ekf.diagnose.grids import parabolic_argmin


def _held_out_sse(d: Design, beta: np.ndarray, r: int) -> np.ndarray:
    """Return the weighted residual sum of squares ``(C,)`` of run ``r`` at coefficients ``beta (C, m)``."""
    return (d.yy[:, r] - 2.0 * np.einsum("cm,cm->c", beta, d.b[:, r])
            + np.einsum("cm,cmn,cn->c", beta, d.G[:, r], beta))


def cross_validated_gain(family: Family, model, splits: list[tuple[Split, np.ndarray]], grid: np.ndarray,
                         theta: np.ndarray, weights: np.ndarray) -> tuple[float, list[float]]:
    """Return the family's gain with every run held out once (module docstring) and the gain per run.

    ``splits`` are ``(split, base prediction)`` pairs (the train runs, then the test runs), ``grid``
    the family's search grid and ``theta`` its parameters fitted on the train runs (kept for a
    mechanism whose parameters are a geometry, not one number). A run without windows gains ``nan``.
    """
    def design(thetas):
        return concat_designs([design_for(family, model, s, thetas, weights, bp) for s, bp in splits], axis=1)

    nulls = []
    for s, bp in splits:
        y0, X0 = null_columns(model, s, bp, family)
        nulls.append(normal_equations(y0[None], X0[None], weights, s.window_run, len(s.names)))
    d0 = concat_designs(nulls, axis=1)
    R = d0.yy.shape[1]
    others = [np.flatnonzero(np.arange(R) != r) for r in range(R)]
    if grid.shape[1] == 1 and len(grid) > 1:  # one parameter: its own profile per fold
        d_grid = design(grid)
        folds = np.array([parabolic_argmin(grid, solve_design(d_grid, keep)[1]) for keep in others])
        d_fold, which = design(folds), np.arange(R)
    else:
        d_fold, which = design(np.atleast_2d(np.asarray(theta, float))), np.zeros(R, int)
    sse, sse0 = np.zeros(R), np.zeros(R)
    for r, keep in enumerate(others):
        c = which[r]
        one = Design(d_fold.G[c:c + 1], d_fold.b[c:c + 1], d_fold.yy[c:c + 1])
        sse[r] = _held_out_sse(one, solve_design(one, keep)[0], r)[0]
        sse0[r] = _held_out_sse(d0, solve_design(d0, keep)[0], r)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        per_run = np.where(sse0 > 0, 1.0 - sse / sse0, np.nan)
    return float(1.0 - sse.sum() / sse0.sum()), per_run.tolist()
