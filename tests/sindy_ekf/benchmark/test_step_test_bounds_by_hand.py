"""The step test's two bounds by hand (step_test.fixes_stepped's docstring): the levels pass at the
``1 - 1e-3`` quantile of chi-square with ``2 n - 2 k`` degrees of freedom, and with ``need_step`` one
level's mean must lie inside the filter's gate, the chi-square(2) quantile at ``GATE_PROB`` of a
horizontal fix."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from sindy_ekf.benchmark.step_test import fixes_stepped
from sindy_ekf.estimation.ekf import GATE_PROB

N = 24  # fixes: two levels of 12, 20 m apart in x, unit innovation covariance (weights 1)


def _two_levels(scatter: float, first_level=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    y = np.zeros((N, 2))
    y[:, 0] = scatter * (-1.0) ** np.arange(N)  # +-scatter: every even-length stretch has mean zero
    y[:] += first_level
    y[12:, 0] += 20.0
    return y, np.repeat(np.eye(2)[None], N, axis=0)


@pytest.mark.parametrize("a2, stepped", [(3.2, True), (3.3, False)])
def test_two_levels_pass_at_the_0_999_quantile_of_their_residual_sum(a2, stepped):
    # by hand: the two levels' residual sum is N a^2 (each fix a from its level's mean), against
    # chi2(2 N - 2 x 2 = 44): 0.999 quantile 78.7, 0.998 quantile 75.9. At a^2 = 3.2 the sum 76.8
    # lies between the two: the levels pass at a false alarm of 1e-3 (and not at 2e-3); at 3.3 the
    # sum 79.2 is beyond; more levels gain at most a^2 / 3 per odd stretch of three, not enough
    y, S = _two_levels(np.sqrt(a2))
    rss = N * a2
    assert chi2.ppf(1 - 2e-3, 44) < 76.8 <= chi2.ppf(1 - 1e-3, 44) < 79.2
    assert rss == pytest.approx(76.8 if stepped else 79.2)
    assert fixes_stepped(y, S) is stepped


@pytest.mark.parametrize("offset, agrees", [(3.6, True), (3.9, False)])
def test_a_first_step_needs_one_level_inside_the_filters_gate(offset, agrees):
    # the first level 3.6 m (NIS 12.96) or 3.9 m (NIS 15.21) off the filter, the second 20 m beyond:
    # the gate of a 2-dof fix at GATE_PROB = 0.999 is 13.82 (15.21 would be inside a 3-dof gate,
    # 16.27), so with need_step only the nearer first level agrees with the filter
    gate = chi2.ppf(GATE_PROB, 2)
    assert offset ** 2 <= gate if agrees else gate < offset ** 2 < chi2.ppf(GATE_PROB, 3)
    y, S = _two_levels(0.5, first_level=(offset, 0.0))
    assert fixes_stepped(y, S) is True  # a step either way
    assert fixes_stepped(y, S, need_step=True) is agrees


def test_optimal_partition_of_two_plain_levels_by_hand():
    # y = 0, 0, 5, 5, 5 (one coordinate, weights 1): one level costs the scatter about the mean 3,
    # 3 x 2^2 + 2 x 3^2 = 30; two levels split at 2 and cost 0; three levels of at least two fixes
    # do not fit in five fixes (inf). Tables for k = 0..max_levels and b = 0..n, arg[k, b] the start
    # of the last level of the best partition of y[:b]
    from sindy_ekf.benchmark.step_test import _partitions, _segment_rss

    y = np.column_stack([[0.0, 0.0, 5.0, 5.0, 5.0], np.zeros(5)])
    cost, arg = _partitions(_segment_rss(np.ones(5), y), max_levels=3)
    assert cost.shape == arg.shape == (4, 6)
    assert cost[0, 0] == 0.0 and np.isinf(cost[0, 1:]).all()
    assert cost[1, 5] == pytest.approx(30.0) and cost[2, 5] == 0.0 and np.isinf(cost[3, 5])
    assert arg[2, 5] == 2 and arg[1, 2] == 0  # the second level starts at fix 2, the first at 0
