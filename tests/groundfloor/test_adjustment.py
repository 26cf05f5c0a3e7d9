"""The global test of the variance factor, against printed chi-square quantiles and against simulated adjustments."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.adjustment import variance_factor_test


def test_interval_is_the_chi_square_quantiles_over_dof():
    # chi2 quantiles of a printed table (e.g. Abramowitz & Stegun 26.8): dof 15, 2.5 % and 97.5 %
    t = variance_factor_test(1.0, 15)
    assert t.lower == pytest.approx(6.262 / 15, abs=1e-3) and t.upper == pytest.approx(27.488 / 15, abs=1e-3)
    assert t.accepted and t.p_value > 0.5
    # dof 1: 0.000982 and 5.024
    t1 = variance_factor_test(1.0, 1)
    assert t1.lower == pytest.approx(0.000982, rel=1e-2) and t1.upper == pytest.approx(5.024, abs=1e-3)


def test_verdicts_and_their_words():
    small, large = variance_factor_test(0.14, 15), variance_factor_test(2.5, 15)
    assert (small.verdict, large.verdict) == ("too small", "too large")
    assert not small.accepted and small.p_value < 0.05
    assert "pessimistic (about 2.7 times)" in small.sentence()  # 1 / sqrt(0.14)
    assert "optimistic" in large.sentence() and "rejected" in large.sentence()
    assert set(small.to_json()) == {"s0_sq", "dof", "alpha", "lower", "upper", "p_value", "verdict"}
    with pytest.raises(ValueError, match="dof = 0"):
        variance_factor_test(1.0, 0)


def _line_fit_s0_sq(rng, n: int, sigma_true: float, sigma_apriori: float) -> float:
    """Return s0^2 = v^T P v / (n - 2) of a weighted straight-line fit to noisy points."""
    x = np.linspace(0.0, 1.0, n)
    y = 2.0 + 3.0 * x + rng.normal(0.0, sigma_true, n)
    A = np.column_stack([np.ones(n), x])
    v = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    return float(v @ v / sigma_apriori**2 / (n - 2))


def test_right_weights_are_accepted_95_percent_of_the_time():
    # simulated adjustments, independent of scipy's chi-square: the level of the test is its rejection rate
    rng = np.random.default_rng(7)
    n = 12
    verdicts = [variance_factor_test(_line_fit_s0_sq(rng, n, 0.01, 0.01), n - 2).verdict for _ in range(4000)]
    rate = np.mean([v == "accepted" for v in verdicts])
    assert rate == pytest.approx(0.95, abs=0.012)
    assert abs(verdicts.count("too small") - verdicts.count("too large")) < 0.02 * len(verdicts)  # two-sided, 2.5 % each
    # a priori sigmas three times too large: s0^2 about 1/9, nearly always "too small"
    wrong = [variance_factor_test(_line_fit_s0_sq(rng, 40, 0.01, 0.03), 38).verdict for _ in range(200)]
    assert wrong.count("too small") >= 195
