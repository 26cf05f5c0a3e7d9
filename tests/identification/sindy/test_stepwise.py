"""The stepwise output-error search against a known sparse model (tests/support/sindy_synth.py):
from a wrong structure it must find the missing terms and drop the spurious ones."""

from __future__ import annotations

import numpy as np
import pytest

from identification.sindy.checks import lag_core
from identification.sindy.evaluate import evaluate_model
from identification.sindy.candidate_fit import refine
from identification.sindy.identify import _stepwise_spec
from identification.sindy.model import SindyModel, envelope_from_data, model_from_terms
from identification.sindy.reference import reference
from identification.sindy.selection import Candidate
from identification.sindy.output_error import OutputErrorFit
from identification.sindy.stepwise import MAX_ROUNDS, STEPWISE, stepwise_output_error, term_scores, wald_drop
from tests.support.runaway import spoilt_rollout
from tests.support.sindy_synth import SPARSE_TERMS, simulate_trajectory_runs, sparse_f

MISSING = {"vx": "vx omega^2", "omega": "omega^3"}
SPURIOUS = {"vy": {"u1": 0.3}, "vx": {"omega": 0.4}}


@pytest.fixture(scope="module")
def runs():
    """Three 40 s runs of the known sparse model."""
    return simulate_trajectory_runs(40.0, [11, 12, 13], f=sparse_f)


def _wrong_start(runs) -> tuple[SindyModel, SindyModel, object]:
    """Return the truth (poly3) and a start without two of its terms and with two spurious ones."""
    truth = model_from_terms(SPARSE_TERMS, "poly3")
    terms = {e: {k: v for k, v in t.items() if k != MISSING.get(e)} for e, t in SPARSE_TERMS.items()}
    for e, extra in SPURIOUS.items():
        terms[e] = terms[e] | extra
    ref = reference(runs)
    x = np.vstack([st.state for st in ref.states])
    u = np.vstack([st.inputs for st in ref.states])
    start = model_from_terms(terms, "poly3", envelope=envelope_from_data(x, u), extrapolation="frozen")
    return truth, start, ref


def _mask(model: SindyModel, eq: str, feature: str) -> tuple[int, int]:
    return ["vx", "vy", "omega"].index(eq), model.library.feature_names.index(feature)


def test_the_missing_terms_score_highest_at_a_fit_of_the_wrong_structure(runs):
    truth, start, ref = _wrong_start(runs)
    windows = ref.windows(3.0, 0.0, 0.05)
    fitted, _ = refine(start, windows)
    allowed = np.ones(fitted.coef.shape, bool)
    scores = term_scores(fitted, windows, np.zeros_like(allowed), allowed)
    assert np.all(scores[fitted.coef != 0] == 0.0)
    # each missing term the best of its equation's 56 - k candidates
    for e, f in MISSING.items():
        i, j = _mask(fitted, e, f)
        assert np.argmax(scores[i]) == j


def test_stepwise_output_error_recovers_the_known_structure_from_a_wrong_one(runs):
    truth, start, ref = _wrong_start(runs)
    windows = ref.windows(3.0, 0.0, 0.05)
    fitted, _ = refine(start, windows)
    allowed = np.ones(fitted.coef.shape, bool)
    step = stepwise_output_error(fitted, windows, allowed, lag_core(fitted))
    found = step.model.coef != 0
    true = truth.coef != 0
    assert np.all(found[true]), "a term of the true model was not found"
    for e, extra in SPURIOUS.items():
        for f in extra:
            assert not found[_mask(step.model, e, f)], f"the spurious {e}: {f} was kept"
    # at most one term beyond the truth (a t test at 5 % on about 40 windows; here u2^3, collinear
    # with omega^3 through the steady state, at t = 2.3)
    assert (found & ~true).sum() <= 1
    exact = np.all(found == true, axis=1)  # equations whose structure is the truth's
    assert exact.sum() >= 2
    np.testing.assert_allclose(step.model.coef[exact][true[exact]], truth.coef[exact][true[exact]], rtol=0.1)
    assert np.all(step.t_stat >= 2.0)
    # it stopped because a round left the structure as it was or returned to an earlier round's
    # (here: u2^3 added in round 2, dropped in round 3), not on its round limit
    assert step.rounds < MAX_ROUNDS and step.history[-1][0] in [h[0] for h in step.history[:-1]]
    assert len(step.history) == step.rounds + 1
    # as good as the truth at 5 s, and the wrong structure refined by output error alone far worse
    full = ref.windows()
    err = evaluate_model(step.model, full).pos_err_5s_m
    assert err < 1.2 * evaluate_model(truth, full).pos_err_5s_m + 1e-4
    assert err < 0.3 * evaluate_model(fitted, full).pos_err_5s_m


def test_terms_not_allowed_are_never_added_and_protected_ones_never_dropped(runs):
    truth, start, ref = _wrong_start(runs)
    windows = ref.windows(3.0, 0.0, 0.05)
    fitted, _ = refine(start, windows)
    allowed = np.ones(fitted.coef.shape, bool)
    e, f = _mask(fitted, "vx", MISSING["vx"])
    allowed[e, f] = False
    protected = lag_core(fitted)
    protected[_mask(fitted, "vy", "u1")] = True
    step = stepwise_output_error(fitted, windows, allowed, protected)
    assert step.model.coef[e, f] == 0.0
    assert step.model.coef[_mask(step.model, "vy", "u1")] != 0.0


def test_the_search_ends_after_max_rounds_rounds(runs):
    truth, start, ref = _wrong_start(runs)
    windows = ref.windows(3.0, 0.0, 0.05)
    fitted, _ = refine(start, windows)
    step = stepwise_output_error(fitted, windows, np.ones(fitted.coef.shape, bool), lag_core(fitted), max_rounds=1)
    assert step.rounds == 1 and len(step.history) == 2
    # one round adds the best term of each equation: the missing vx omega^2 is in after it
    assert step.model.coef[_mask(step.model, "vx", MISSING["vx"])] != 0.0


def _candidate(label, hp, folds_m, complexity, passed=True):
    folds_m = np.asarray(folds_m, float)
    return Candidate(label, hp, folds_m, np.full(len(folds_m), 10), folds_m * 100, complexity, passed)


def test_the_stepwise_search_starts_from_the_structure_the_rule_picks_else_the_best_grid_one():
    hp = {"s": 0.0, "tau": 1.0, "alpha": 0.01, "T": 0.1, "library": "poly3", "normalize": True}
    lag = _candidate("lag", None, [0.050, 0.052, 0.048], 5)
    rank1 = _candidate("grid rank 1", hp | {"output_error": True}, [0.012, 0.013, 0.011], 25)
    rank1_reg = _candidate("grid rank 1, regression", hp | {"output_error": False}, [0.0125, 0.0135, 0.0115], 20)
    rank5 = _candidate("grid rank 5", hp | {"T": 0.2, "output_error": True}, [0.005, 0.005, 0.005], 30, passed=False)
    # the rule picks the sparser regression candidate within one SE: the search starts from its structure
    label, spec = _stepwise_spec([lag, rank1, rank1_reg, rank5])
    assert label == "grid rank 1, stepwise" and spec == hp | {"output_error": STEPWISE}
    # the lag picked: from the grid candidate of smallest CV error that passed (not rank 5, it failed)
    good_lag = _candidate("lag", None, [0.010, 0.010, 0.010], 5)
    rank9 = _candidate("grid rank 9", hp | {"T": 0.3, "output_error": True}, [0.011, 0.011, 0.011], 30)
    label, spec = _stepwise_spec([good_lag, rank1, rank9, rank5])
    assert label == "grid rank 9, stepwise" and spec["T"] == 0.3
    assert _stepwise_spec([good_lag]) is None


def test_the_backward_elimination_without_refits_equals_least_squares_refitted_without_the_terms():
    """For a model linear in its parameters with the homoskedastic covariance, restricting the weak
    terms to zero one by one on the estimate and covariance is the least-squares refit without them
    (np.linalg.lstsq on the remaining columns, an independent computation), dropped weakest first."""
    rng = np.random.default_rng(3)
    n = 400
    X = rng.normal(size=(n, 5))
    X[:, 3] += 0.8 * X[:, 0]  # correlated: dropping one moves the others
    y = X @ np.array([1.0, -0.5, 0.02, 0.0, 0.3]) + 0.5 * rng.normal(size=n)
    theta, *_ = np.linalg.lstsq(X, y, rcond=None)
    sigma2 = np.sum((y - X @ theta) ** 2) / (n - 5)
    cov = sigma2 * np.linalg.inv(X.T @ X)
    fit = OutputErrorFit(names=tuple("abcde"), theta=theta, dead_time_s=(0.0, 0.0), cov=cov, rms_pos_m=0.0,
                         n_windows=n, nfev=0, success=True)
    droppable = np.array([False, True, True, True, True])
    restricted, dropped = wald_drop(fit, droppable)
    assert dropped.tolist() == [False, False, True, True, False]  # the two null terms, not the protected or true ones
    keep = ~dropped
    refit, *_ = np.linalg.lstsq(X[:, keep], y, rcond=None)
    np.testing.assert_allclose(restricted[keep], refit, rtol=1e-9, atol=1e-12)
    assert np.all(restricted[dropped] == 0.0)
    # one drop at a time (the search's backward step): the weakest term alone, by its t statistic
    # written out here, and the estimate the lstsq refit without it
    t = np.abs(theta) / np.sqrt(np.diag(cov))
    weakest = int(np.argmin(np.where(droppable, t, np.inf)))
    first, one = wald_drop(fit, droppable, max_drops=1)
    assert np.flatnonzero(one).tolist() == [weakest]
    keep = np.arange(5) != weakest
    np.testing.assert_allclose(first[keep], np.linalg.lstsq(X[:, keep], y, rcond=None)[0], rtol=1e-9, atol=1e-12)
    # nothing below the bound: nothing dropped, the estimate as it was
    same, none = wald_drop(fit, droppable, min_t=0.0)
    assert not none.any() and np.array_equal(same, theta)


def test_a_window_that_runs_away_to_huge_finite_numbers_does_not_score_terms(runs, monkeypatch):
    """A window whose prediction reaches 1e200 (finite; its squares overflow) counts as one that
    left the finite numbers: the scores equal those with that window spoilt to nan, no overflow
    warning, and the missing terms still score highest (an overflowed score was inf, taken first)."""
    import warnings

    from identification.sindy import stepwise

    truth, start, ref = _wrong_start(runs)
    windows = ref.windows(3.0, 0.0, 0.05)
    fitted, _ = refine(start, windows)
    allowed = np.ones(fitted.coef.shape, bool)
    real = stepwise.rollout_with_sensitivities
    scores = {}
    for runaway in (np.nan, 1e200):

        monkeypatch.setattr(stepwise, "rollout_with_sensitivities", spoilt_rollout(real, 2, runaway))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            scores[runaway] = term_scores(fitted, windows, np.zeros_like(allowed), allowed)
    np.testing.assert_array_equal(scores[1e200], scores[np.nan])
    assert np.all(np.isfinite(scores[1e200]))
    for e, f in MISSING.items():
        i, j = _mask(fitted, e, f)
        assert np.argmax(scores[1e200][i]) == j
