"""Clock-model pieces at their smallest inputs, by hand: the linear fit of three points (one
degree of freedom) and nearest matching against an empty series."""

from __future__ import annotations

import numpy as np
import pytest

from identification.preprocessing.clock_sync import fit_linear_clock, match_nearest


def test_three_point_clock_fit_has_one_degree_of_freedom():
    x = np.array([0.0, 1.0, 2.0])
    y = np.array([0.0, 1.0 + 1e-3, 2.0])  # y = k x + d with residuals (-1, 2, -1) e-3 / 3
    k, d, k_std, d_std, s0 = fit_linear_clock(x, y)
    assert k == pytest.approx(1.0, abs=1e-12)
    assert d == pytest.approx(1e-3 / 3, rel=1e-9)
    res = np.array([-1.0, 2.0, -1.0]) * 1e-3 / 3
    assert s0 == pytest.approx(np.sqrt(res @ res / 1), rel=1e-9)  # n - 2 = 1 degree of freedom
    # (A^T A)^-1 of A = [x, 1]: [[1/2, -1/2], [-1/2, 5/6]]
    assert k_std == pytest.approx(s0 * np.sqrt(0.5), rel=1e-9)
    assert d_std == pytest.approx(s0 * np.sqrt(5 / 6), rel=1e-9)


@pytest.mark.parametrize("a, b", [(np.array([1.0, 2.0]), np.empty(0)), (np.empty(0), np.array([1.0, 2.0]))])
def test_matching_against_an_empty_series_matches_nothing(a, b):
    ia, ib = match_nearest(a, b, 0.1)
    assert ia.size == 0 and ib.size == 0
