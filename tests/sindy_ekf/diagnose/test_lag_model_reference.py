"""The input_delay family against a lag-with-dead-time model, with an independent reference.

The data come from ``tests.support.sindy_synth`` (its own RK4 with the motor lag as two more
states, command messages held and seen late), not from the diagnosis's input chain. The model is
exact: the same first-order lags per axis, the same dead time and input lag, so the family must
find nothing on the clean runs and exactly the extra dead time when one is added to the data.
A model that waits too long already (dead time 0.3 s, the data none) must not be explained by
still more delay through a re-identification that runs away at rest: that refit (self-damping
+1.8 1/s at 0.6 s extra) won 41 % of the window residual on the clean real Warthog runs while
``~`` on a Python bool (-2, truthy) admitted every refit.
"""

from __future__ import annotations

import numpy as np
import pytest

from identification.sindy.checks import STABILITY_TOL, max_re_eig_at_rest
from identification.sindy.data import states_of_runs
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel
from sindy_ekf.diagnose.data import model_split
from sindy_ekf.diagnose.families import MECHANISMS
from sindy_ekf.diagnose.fitting import equation_weights, null_prediction, refit_grid
from sindy_ekf.diagnose.scoring import score_mechanisms
from tests.support.sindy_synth import lag_f, simulate_trajectory_runs

DEAD_S, LAG_S = 0.1, 0.15  # the system's (and the exact model's) dead time and input lag
POSE_STD = 0.002  # m and rad: enough noise that a relative gain means something


def exact_model(dead_s: float) -> SindyModel:
    """Return ``lag_f()`` as a poly1 SINDy model seeing its inputs ``dead_s`` late through LAG_S lags."""
    lib = make_library("poly1")
    coef = np.zeros((3, lib.n_features))
    for e, term, value in ((0, "vx", -1 / 0.3), (0, "u1", 1.8 / 0.3), (1, "vy", -1 / 0.3),
                           (2, "omega", -1 / 0.2), (2, "u2", 1.2 / 0.2)):
        coef[e, lib.feature_names.index(term)] = value
    return SindyModel(lib, coef, hyperparameters={"tau": 1.0}, dead_time_s=(dead_s, dead_s),
                      input_lag_s=(LAG_S, LAG_S))


def splits(model, data_dead_s: float):
    runs = simulate_trajectory_runs(40.0, [1, 2, 3, 4], f=lag_f(), dead_time_s=(data_dead_s, data_dead_s),
                                    input_lag_s=(LAG_S, LAG_S), pose_std_m=POSE_STD, yaw_std_rad=POSE_STD)
    states, names, _ = states_of_runs(runs, 0.0)
    return model_split(model, states[:3], names[:3], 1.0), model_split(model, states[3:], names[3:], 1.0)


def delay_score(model, data_dead_s: float):
    tr, te = splits(model, data_dead_s)
    weights = equation_weights(model, tr)
    base = {"train": null_prediction(model, tr), "test": null_prediction(model, te)}
    return score_mechanisms("input_delay", model, tr, te, weights, base, uncertainty=False), (tr, weights)


def test_exact_lag_model_leaves_no_delay():
    score, _ = delay_score(exact_model(DEAD_S), DEAD_S)
    assert score.gain < 0.01  # under the smallest threshold (rank.MIN_THRESHOLD)
    assert next(iter(score.estimate.values())) == pytest.approx(0.0, abs=0.01)


def test_extra_dead_time_is_found_on_top_of_the_models_chain():
    score, _ = delay_score(exact_model(DEAD_S), DEAD_S + 0.15)
    assert score.gain > 0.3
    assert next(iter(score.estimate.values())) == pytest.approx(0.15, abs=0.01)


def test_a_refit_that_runs_away_at_rest_is_not_admitted():
    model = exact_model(0.3)  # waits 0.3 s for inputs the data respond to at once
    score, (tr, weights) = delay_score(model, 0.0)
    assert score.gain <= 0.0 and next(iter(score.estimate.values())) == 0.0
    spec = MECHANISMS["input_delay"][0]
    grid = spec.grid(tr)
    _, sols, sse, ok = refit_grid(spec, model, tr, weights, grid)
    assert ok.dtype == bool
    coefs = np.zeros((len(sols),) + model.coef.shape)
    rows, cols = np.nonzero(model.coef)
    coefs[:, rows, cols] = sols[:, :len(rows)]
    runs_away = max_re_eig_at_rest(model.library, coefs) > STABILITY_TOL
    assert runs_away.any()  # the regression would explain the late model by positive self-damping
    assert np.all(np.isinf(sse[runs_away])) and np.all(~ok[runs_away])
