"""The smoothing spline of eq. 5.68 against scipy's independent implementation and numerical slopes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline

from identification.preprocessing.smoothing_spline import _Reinsch, smoothing_spline


def test_smoothing_spline_is_scipys_smoothing_spline_and_meets_eq_5_68():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.015, 0.025, 1500))
    std = rng.uniform(0.5e-3, 2e-3, t.size)
    y = np.sin(0.7 * t) + rng.normal(0, 1, t.size) * std
    for s in (0.0005, 0.5, 3.0):
        spline, lam = smoothing_spline(t, y, std, s)
        assert np.mean(((y - spline(t)) / std) ** 2) == pytest.approx(s, rel=0.01)  # eq. 5.68
        ref = make_smoothing_spline(t, y, w=1 / std**2, lam=lam)  # independent implementation
        np.testing.assert_allclose(spline(t), ref(t), atol=1e-9 * (1 + 1e-3 / s))
        np.testing.assert_allclose(spline(t, 1), ref.derivative()(t), atol=1e-6)
    spline, lam = smoothing_spline(t, y, std, 0.0)
    assert lam == 0.0 and np.allclose(spline(t), y)


def test_penalty_slope_matches_numerical_derivative():
    """The Newton search for the penalty uses d ln F / d ln lam analytically: check it."""
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.5, 1.5, 400))
    var = rng.uniform(0.5, 2.0, t.size)
    y = 30 * np.sin(0.05 * t) + rng.normal(0, 1, t.size) * np.sqrt(var)
    problem = _Reinsch(t, y, var)
    for lam in (0.01, 1.0, 100.0):
        F, slope = problem.chi2_and_slope(lam)
        assert F == pytest.approx(np.mean((y - problem.values(lam)) ** 2 / var), rel=1e-9)
        eps = 1e-4
        num = (np.log(problem.chi2_and_slope(lam * np.exp(eps))[0])
               - np.log(problem.chi2_and_slope(lam * np.exp(-eps))[0])) / (2 * eps)
        assert slope == pytest.approx(num, rel=1e-5)
