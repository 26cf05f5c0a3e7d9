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


def test_gap_grid_keeps_skipped_pulses_and_drops_dropouts_by_hand():
    # 20 ms stamps with one skipped pulse (a 40 ms step: a trigger gap, kept) and one dropout of
    # 5 periods (100 ms: the prism was lost, no alignment, set to the period). At 100 Hz the grid
    # reads the step that starts at or before each grid time (np.interp between stamps' steps),
    # less the 20 ms period: 20 ms over the skipped pulse, 0 over the dropout, hand values.
    from identification.preprocessing.clock_sync import _gap_grid

    t = np.array([0.00, 0.02, 0.04, 0.08, 0.10, 0.12, 0.22, 0.24, 0.26])
    grid = _gap_grid(t, rate_hz=100.0)
    # steps: 20, 20, 40, 20, 20, 100 -> 20 (dropout), 20, 20 ms at t_i = 0, .02, .04, .08, .10, .12, .22, .24
    steps_at = np.array([0.00, 0.02, 0.04, 0.08, 0.10, 0.12, 0.22, 0.24])
    steps = np.array([0.02, 0.02, 0.04, 0.02, 0.02, 0.02, 0.02, 0.02])
    q = np.arange(0.0, 0.24, 0.01)
    np.testing.assert_allclose(grid, np.interp(q, steps_at, steps) - 0.02, atol=1e-12)
    assert grid[np.searchsorted(q, 0.04 - 1e-9)] == pytest.approx(0.02)  # the skipped pulse
    assert np.all(np.abs(grid[(q > 0.12) & (q < 0.22)]) < 1e-12)  # the dropout, not a gap
