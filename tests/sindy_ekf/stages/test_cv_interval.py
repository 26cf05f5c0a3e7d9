"""The warning that the test runs are not like the train groups: the test score outside the
prediction interval the cross-validation folds give for one more held-out group.

Reference: a Monte Carlo of the rule itself, independent of its formula. Fold errors and a test
error drawn alike (the test runs one more group like the others) must be warned about in about
5 % of draws, the rule's stated level; a test error drawn from groups 5 fold standard deviations
worse must be warned about nearly always. The rule it replaced (one fold standard deviation) warns
in 41 to 48 % of exchangeable draws with 3 to 5 folds.
"""

from __future__ import annotations

import numpy as np
import pytest

from sindy_ekf.stages.evaluation import CV_PREDICTION_LEVEL, CvComparison

N_DRAWS = 20_000


def _warn_rate(k: int, shift_sd: float, rng) -> float:
    """Return the share of draws warned about: ``k`` fold errors N(0.2, 0.01) and a test error
    N(0.2 + shift_sd * 0.01, 0.01), the CV estimate the folds' mean."""
    folds = rng.normal(0.2, 0.01, size=(N_DRAWS, k))
    test = rng.normal(0.2 + shift_sd * 0.01, 0.01, size=N_DRAWS)
    warned = [CvComparison(float(f.mean()), float(f.std(ddof=1)), float(x), "k-fold", k).disagree
              for f, x in zip(folds, test)]
    return float(np.mean(warned))


@pytest.mark.parametrize("k", [3, 5, 8])
def test_a_test_group_like_the_folds_is_warned_about_at_the_stated_rate(k):
    rate = _warn_rate(k, 0.0, np.random.default_rng(k))
    # binomial standard error of the share over 20 000 draws: 0.0015
    assert rate == pytest.approx(1.0 - CV_PREDICTION_LEVEL, abs=0.006)


@pytest.mark.parametrize("k", [5, 8])
def test_a_test_group_far_from_the_folds_is_warned_about(k):
    assert _warn_rate(k, 5.0, np.random.default_rng(100 + k)) > 0.8


def test_fewer_than_two_folds_give_no_interval_and_no_warning():
    one = CvComparison(0.2, float("nan"), 5.0, "k-fold", 1)
    assert np.isnan(one.interval_m) and one.disagree is False
    assert one.to_json()["interval_m"] is None and one.to_json()["spread_m"] is None
