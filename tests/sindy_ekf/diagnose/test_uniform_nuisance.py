"""A floor patch is credited only for what varies over the lab (issue 15): a damping that is wrong
everywhere is the uniform nuisance's, not a position dependence.

Reference: a model identified on an effect-free simulated campaign, then its ``vx`` and ``omega``
damping made 15 % stronger by hand. The window residual of the wrong model is the identified
model's plus ``0.15 c ∫ vx`` (and the same for ``omega``), so the nuisance must recover
``-0.15 c`` per equation, and a patch fitted beside it buys nothing beyond what a chance
patch buys on effect-free data.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from identification.sindy.model import SindyModel
from identification.sindy.regression import fit_sindy
from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose.data import model_split
from sindy_ekf.diagnose.design import equation_weights, null_prediction
from sindy_ekf.diagnose.extend import ExtendedModel
from sindy_ekf.diagnose.families import FAMILY_SPECS, model_coefficient
from sindy_ekf.diagnose.columns import null_columns, null_fit, residual_and_columns
from sindy_ekf.diagnose.fitting import score_family
from sindy_ekf.diagnose.rank import THRESHOLDS

STRONGER = 0.15


@pytest.fixture(scope="module")
def wrongly_damped():
    """Return ``(identified model, model with damping made stronger, train split, test split)``."""
    train, test, a, b = simulate_states_campaign(271828, None, run_s=45.0, rate_hz=25.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = fit_sindy(train, "poly3", tau=2.0, alpha=1.0, threshold=0.2, names=a)
    coef = np.array(model.coef, float)
    names = list(model.library.feature_names)
    for e, term in ((0, "vx"), (2, "omega")):
        assert coef[e, names.index(term)] < 0  # a damping, identified
        coef[e, names.index(term)] *= 1.0 + STRONGER
    wrong = SindyModel(library=model.library, coef=coef, hyperparameters=dict(model.hyperparameters))
    tr = model_split(wrong, train, a, 2.0, what="train runs")
    te = model_split(wrong, test, b, 2.0, what="test runs")
    return model, wrong, tr, te


def test_uniform_nuisance_recovers_a_damping_wrong_everywhere(wrongly_damped):
    model, wrong, tr, _ = wrongly_damped
    family = FAMILY_SPECS["position_dependence"]
    beta0, _ = null_fit(wrong, tr, equation_weights(wrong, tr), null_prediction(wrong, tr), family)
    # by hand: the wrong model over-damps by STRONGER c, the nuisance adds it back (c < 0: beta0 > 0)
    expected = [-STRONGER * model_coefficient(model, "vx", "vx"), -STRONGER * model_coefficient(model, "omega", "omega")]
    np.testing.assert_allclose(beta0, expected, rtol=0.1)


def test_patch_is_not_credited_with_a_damping_wrong_everywhere(wrongly_damped):
    _, wrong, tr, te = wrongly_damped
    score = score_family("position_dependence", wrong, tr, te, uncertainty=False, refit=False)
    assert score.gain < THRESHOLDS["fixed"]["position_dependence"]


def test_the_nuisance_beside_the_patch_is_the_null_s_and_a_patch_over_everything_is_the_nuisance(wrongly_damped):
    _, wrong, tr, _ = wrongly_damped
    family = FAMILY_SPECS["position_dependence"]
    m = family.n_columns
    base = null_prediction(wrong, tr)
    x, y = tr.x6[:, 0], tr.x6[:, 1]
    centre = [0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())]
    far = np.array([[centre[0], centre[1], 1e3]])  # a disc of 1 km: s = 1 wherever the robot drove
    target, X = residual_and_columns(family, wrong, tr, far, base)
    y0, X0 = null_columns(wrong, tr, base, family)
    assert X.shape[-1] == m + 2 and X0.shape[-1] == 2
    np.testing.assert_array_equal(X[0, ..., m:], X0)  # the same nuisance in the null and beside the patch
    np.testing.assert_allclose(target[0], y0)
    # the patch switched on everywhere spans exactly the nuisance's columns: nothing left to credit to it
    patch = X[0, ..., :m].reshape(-1, m)
    nuisance = X0.reshape(-1, 2)
    coef, *_ = np.linalg.lstsq(nuisance, patch, rcond=None)
    np.testing.assert_allclose(nuisance @ coef, patch, atol=1e-9 * np.abs(patch).max())


def test_the_patch_extension_carries_the_uniform_damping_it_was_scored_with(wrongly_damped):
    """The extension of a patch scored beside its nuisance puts the damping back where the wrong model
    lost it: by hand, the extended model's accelerations are the wrong model's plus the patch's columns
    plus ``-STRONGER c vx`` (vx equation) and ``-STRONGER c omega`` (omega equation)."""
    model, wrong, tr, te = wrongly_damped
    score = score_family("position_dependence", wrong, tr, te, uncertainty=False, refit=False)
    assert score.uniform.shape == (2,)
    ext = ExtendedModel.added(wrong, "position_dependence", score.theta, score.beta, dict(score.estimate),
                              score.uniform)
    expected = [-STRONGER * model_coefficient(model, "vx", "vx"), -STRONGER * model_coefficient(model, "omega", "omega")]
    np.testing.assert_allclose(score.uniform, expected, rtol=0.1)
    x6, u = tr.x6[::50], tr.u[::50]
    patch = FAMILY_SPECS["position_dependence"].columns(x6, u, np.zeros(len(x6)), score.theta[None])[0] @ score.beta
    by_hand = wrong.f(x6[:, 3:], u) + patch
    by_hand[:, 0] += score.uniform[0] * x6[:, 3]
    by_hand[:, 2] += score.uniform[1] * x6[:, 5]
    np.testing.assert_allclose(ext.accel(x6, u), by_hand, rtol=1e-9, atol=1e-12)
    assert ext.estimate["uniform_damping"] == {"vx": score.uniform[0], "omega": score.uniform[1]}
