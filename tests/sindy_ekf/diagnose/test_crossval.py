"""The fixed-model gain with every run held out once, against a second, brute-force computation.

The package scores each fold from per-run normal equations (``crossval.cross_validated_gain``). The
reference here refits every fold from scratch: the held-out run's windows and the other runs'
windows stacked, weighted and solved by ``numpy.linalg.lstsq`` (no normal equations, no per-run
sums), the mechanism's parameter profiled over its grid on the other runs' residuals, the null
fitted the same way, and the held-out run's residual summed by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from simulation.effects import parse_effect
from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose.columns import null_columns, residual_and_columns
from sindy_ekf.diagnose.crossval import cross_validated_gain
from sindy_ekf.diagnose.data import model_split
from sindy_ekf.diagnose.design import equation_weights, gain_recalibrated, null_prediction
from sindy_ekf.diagnose.families import FAMILY_SPECS
from sindy_ekf.diagnose.grids import parabolic_argmin
from tests.support.diagnose_synth import fit_reference_model


def _lstsq_sse(y: np.ndarray, X: np.ndarray, w: np.ndarray, fit: np.ndarray, score: np.ndarray) -> float:
    """Return the weighted SSE on windows ``score`` of the weighted least-squares fit on windows ``fit``."""
    sw = np.sqrt(w)
    if X.shape[-1]:
        A = (X[fit] * sw[None, :, None]).reshape(-1, X.shape[-1])
        beta = np.linalg.lstsq(A, (y[fit] * sw).reshape(-1), rcond=None)[0]
        r = y[score] - X[score] @ beta
    else:
        r = y[score]
    return float(np.sum(r * r * w))


def _reference(family, model, splits, grid, theta, w) -> float:
    """Return the cross-validated gain by refitting every fold from the stacked windows."""
    ys, Xs, y0s, X0s, runs = [], [], [], [], []
    offset = 0
    for split, bp in splits:
        thetas = grid if grid.shape[1] == 1 and len(grid) > 1 else np.atleast_2d(theta)
        y, X = residual_and_columns(family, model, split, thetas, bp)  # (C, p, 3), (C, p, 3, m)
        y0, X0 = null_columns(model, split, bp, family)
        ys.append(y), Xs.append(X), y0s.append(y0), X0s.append(X0)
        runs.append(split.window_run + offset)
        offset += len(split.names)
    y, X = np.concatenate(ys, axis=1), np.concatenate(Xs, axis=1)
    y0, X0 = np.concatenate(y0s), np.concatenate(X0s)
    run = np.concatenate(runs)
    num = den = 0.0
    for r in range(offset):
        fit, score = run != r, run == r
        c = 0
        if len(y) > 1:  # the parameter by its profile over the grid on the other runs
            sse = np.array([_lstsq_sse(y[k], X[k], w, fit, fit) for k in range(len(y))])
            th = parabolic_argmin(grid, sse)
            splits_y = [residual_and_columns(family, model, s, th[None], bp) for s, bp in splits]
            yk = np.concatenate([a[0][0] for a in splits_y])
            Xk = np.concatenate([a[1][0] for a in splits_y])
        else:
            yk, Xk = y[c], X[c]
        num += _lstsq_sse(yk, Xk, w, fit, score)
        den += _lstsq_sse(y0, X0, w, fit, score)
    return 1.0 - num / den


@pytest.fixture(scope="module")
def campaign():
    model = fit_reference_model(n_runs=3, run_s=30.0)
    train, test, a, b = simulate_states_campaign(5, parse_effect("deadband=0.12"), n_train=3, n_test=2, run_s=30.0,
                                                 rate_hz=25.0)
    tr, te = model_split(model, train, a, 2.0), model_split(model, test, b, 2.0)
    return model, tr, te


@pytest.mark.parametrize("name", ["deadband", "heading_dependence"])
def test_cross_validated_gain_equals_refitting_every_fold(campaign, name):
    """An input-side family (its threshold profiled per fold, with its gain nuisance, against the
    recalibrated model) and an additive one (no parameter), both against the stacked refits."""
    model, tr, te = campaign
    family = FAMILY_SPECS[name]
    w = equation_weights(model, tr)
    scored = gain_recalibrated(model, tr, w)[0] if family.kind == "input" else model
    splits = [(tr, null_prediction(scored, tr)), (te, null_prediction(scored, te))]
    grid = family.grid(tr)
    theta = grid[len(grid) // 2]
    gain, per_run = cross_validated_gain(family, scored, splits, grid, theta, w)
    # to the whisper of ridge solve_design adds (1e-9 of the trace), which lstsq does not
    assert gain == pytest.approx(_reference(family, scored, splits, grid, theta, w), rel=1e-4, abs=1e-9)
    assert len(per_run) == len(tr.names) + len(te.names)
    if name == "deadband":
        assert gain > 0.2  # the hidden deadband is found in every fold
