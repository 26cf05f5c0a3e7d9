"""A family's columns on the windows of the integral regression, its nulls and its per-run normal equations.

The window targets after the model's fixed part and the mechanism's columns (an input-side
mechanism's motor inputs through the model, with its gain nuisance; an additive mechanism's
integrated columns, the floor patch with its uniform nuisance), the nulls they are scored against,
and the weighted normal equations of every candidate per run (:func:`design_for`), on which
:mod:`sindy_ekf.diagnose.fitting` fits the families and :mod:`sindy_ekf.diagnose.crossval` scores
them run by run.
"""

from __future__ import annotations

import numpy as np

from sindy_ekf.diagnose.data import Split
from sindy_ekf.diagnose.design import (
    ActiveTerms,
    Design,
    chunks,
    concat_designs,
    model_and_gain_columns,
    normal_equations,
    null_prediction,
    solve_design,
)
from sindy_ekf.diagnose.families import Family


def residual_and_columns(family: Family, model, split: Split, theta: np.ndarray,
                         base_pred: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return window targets ``y (C, p, 3)`` after the fixed part and columns ``X (C, p, 3, m + n)``:
    the mechanism's ``m`` columns, then its ``n`` nuisance columns (2 for an input-side mechanism: its
    gain nuisance; 2 for the floor patch: its uniform nuisance; 0 for the other additive ones).

    An input-side mechanism gets two more columns, its nuisance: the model's response to a change of
    its input gains (linearised at the given gains, the derivative by ``log g_i``), fitted with the
    mechanism. What a constant gain per input explains is credited to no mechanism, and a gain-shaped
    mechanism (a decay, a deadband) is fitted around the gains it would otherwise have to mimic
    (:func:`sindy_ekf.diagnose.design.gain_recalibrated` is the null's nonlinear counterpart). An additive mechanism acts where
    the robot is or how it heads and cannot mimic a gain; it gets no gain nuisance: given one, a floor patch
    bought a better fit of the gains on the train runs by absorbing the runs that disagree and credited
    that to itself (measured: 26 % on the clean real cmd test run, which never enters the patch; the
    extension changed its 5 s error by 1e-12). The floor patch gets its own uniform nuisance instead
    (:func:`uniform_nuisance`): a patch grown over the whole driven area is a damping wrong everywhere,
    which a battery sag or a soft deadband also looks like (issue 15's forms suite: a patch of radius
    4 m won over both, 0/3 and 1/3 named).
    """
    theta = np.atleast_2d(theta)
    C, p, m = len(theta), split.n_windows, family.n_columns
    dv = split.delta_v
    act = ActiveTerms(model)
    if family.kind == "input":
        y, X = np.empty((C, p, 3)), np.empty((C, p, 3, 2))
        k = act.library.n_features
        for sl in chunks(C, len(split.t_run) * k * 3):
            u_m = family.motor_inputs(split.t_run, split.u, split.runs_slices(), theta[sl])
            pred, X[sl] = model_and_gain_columns(act, split, u_m)
            y[sl] = dv - pred
        return y, X
    base_pred = null_prediction(model, split) if base_pred is None else base_pred
    y = np.broadcast_to(dv - base_pred, (C, p, 3))
    nuisance = uniform_nuisance(family, split)
    X = np.zeros((C, p, 3, m + nuisance.shape[-1]))  # the pairs a mechanism leaves empty stay zero
    X[..., m:] = nuisance
    x6 = split.x6
    for sl in chunks(C, len(split.t_run) * 3 * m):
        idx = patch_support(family, split.pose_local, theta[sl])
        if idx is None:
            cols = family.columns(x6, split.u, split.t_run, theta[sl])
        else:  # the patches of this chunk are zero beyond their box: columns there alone
            cols = family.columns(x6[idx], split.u[idx], split.t_run[idx], theta[sl])
        # only the (equation, column) pairs the mechanism fills are integrated (the floor patch fills 2
        # of 6); the others stay zero, as their integrals were
        filled = np.any(cols != 0, axis=(0, 1))
        X[sl, ..., :m][:, :, filled] = (split.integrate(cols[:, :, filled]) if idx is None
                                       else split.integrate_sparse(cols[:, :, filled], idx))
    return y, X


#: beyond this distance outside its radius a floor patch is exactly zero in double precision: its edge's
#: tanh is -1 to the last bit from 19.1 edge widths h on (:data:`PATCH_EDGE_M` / (2 ln 9) = 0.046 m), and
#: 1 m is 22 of them (tests/sindy_ekf/diagnose/test_kernels.py checks it)
PATCH_ZERO_M = 1.0


def patch_support(family: Family, pose: np.ndarray, theta: np.ndarray) -> np.ndarray | None:
    """Return the samples (sorted indices into ``pose (N, 3)``) where any floor patch of ``theta (C, 3)`` may
    be non-zero: inside the box of their centres widened by the largest radius and :data:`PATCH_ZERO_M`.
    None for every other mechanism (its columns are non-zero anywhere), and where the box holds most samples.

    On an outdoor campaign the patch grid (a centre every 0.4 m over the driven area) has tens of
    thousands of candidates, each non-zero on a small part of the track: the real wheels campaign's
    33,000 patches made two thirds of its diagnosis.
    """
    if family.name != "position_dependence" or family.mechanism == "smooth_field" or not len(theta):
        return None
    reach = float(np.max(theta[:, 2])) + PATCH_ZERO_M
    lo, hi = theta[:, :2].min(axis=0) - reach, theta[:, :2].max(axis=0) + reach
    inside = np.all((pose[:, :2] >= lo) & (pose[:, :2] <= hi), axis=1)
    return np.flatnonzero(inside) if inside.mean() < 0.5 else None


def uniform_nuisance(family: Family, split: Split) -> np.ndarray:
    """Return the window integrals ``(p, 3, n)`` of an additive family's uniform nuisance
    (:meth:`Family.uniform_columns`), fitted beside the mechanism and in its null."""
    cols = family.uniform_columns(split.x6)
    n = cols.shape[-1]
    return split.integrate(cols.reshape(len(cols), 3 * n)).reshape(-1, 3, n) if n else np.zeros((split.n_windows, 3, 0))


def null_columns(model, split: Split, base_pred: np.ndarray | None = None,
                 family: Family | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return the null of ``family``'s fixed-model scoring as ``y (p, 3)``, ``X (p, 3, n)``: the given
    model with its gain nuisance (``n = 2``) for an input-side mechanism (also when ``family`` is
    None), with its uniform nuisance for an additive one (:func:`uniform_nuisance`, ``n = 0`` for most):
    :func:`residual_and_columns` fits the same nuisance beside the mechanism."""
    base_pred = null_prediction(model, split) if base_pred is None else base_pred
    y = split.delta_v - base_pred
    if family is not None and family.kind != "input":
        return y, uniform_nuisance(family, split)
    return y, model_and_gain_columns(ActiveTerms(model), split, split.u[None])[1][0]


def null_fit(model, split: Split, weights: np.ndarray, base_pred: np.ndarray | None = None,
             family: Family | None = None):
    """Return ``(nuisance coefficients, weighted SSE)`` of the null of ``family`` fitted on ``split``."""
    y, X = null_columns(model, split, base_pred, family)
    beta, sse = solve_design(normal_equations(y[None], X[None], weights, split.window_run, len(split.names)))
    return beta[0], float(sse[0])


def null_residual(model, split: Split, beta0: np.ndarray, base_pred: np.ndarray | None = None,
                  family: Family | None = None) -> np.ndarray:
    """Return the window residual ``(p, 3)`` on ``split`` of the null of ``family`` with nuisance
    coefficients ``beta0``."""
    y, X = null_columns(model, split, base_pred, family)
    return y - np.einsum("pem,m->pe", X, beta0)


def design_for(family: Family, model, split: Split, grid: np.ndarray, weights: np.ndarray,
               base_pred: np.ndarray | None = None) -> Design:
    """Return the per-run normal equations of all candidates ``grid``, built in memory-bounded chunks."""
    parts = []
    per = split.n_windows * 3 * (family.n_columns + 2)
    for sl in chunks(len(grid), per):
        y, X = residual_and_columns(family, model, split, grid[sl], base_pred)
        parts.append(normal_equations(y, X, weights, split.window_run, len(split.names)))
    return concat_designs(parts)
