"""The NIS divergence alarm (health.nis_alarm) against a loop over the windows written here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from sindy_ekf.benchmark.health import nis_alarm


def _by_hand(nis, gate, window, dof, false_alarm, tolerance):
    clipped = [gate if not math.isfinite(v) else min(v, gate) for v in nis]
    bound = tolerance * chi2.ppf(1.0 - false_alarm, dof * window)
    for i in range(len(clipped) - window + 1):
        total = sum(clipped[i:i + window])
        if total > bound:
            return i, total, bound
    return None, float("nan"), bound


@pytest.mark.parametrize("start", [0, 1, 17, 40])
def test_first_alarming_window_and_its_sum_match_the_loop(start):
    rng = np.random.default_rng(start)
    nis = rng.chisquare(2, 60)
    nis[start:start + 10] += 9.0  # the filter stops following the fixes here
    nis[start + 2] = np.inf  # a non-finite NIS counts as the gate value
    nis[start + 4] = np.nan
    nis[50] = 1e6  # one outlier adds at most the gate
    args = dict(window=10, dof=2, false_alarm=1e-3, tolerance=1.0)
    i, total, bound = nis_alarm(nis, 13.8, **args)
    i_ref, total_ref, bound_ref = _by_hand(nis, 13.8, **args)
    assert bound == pytest.approx(bound_ref, rel=1e-12)
    assert i == i_ref
    assert i is not None and i <= start
    assert total == pytest.approx(total_ref, rel=1e-12)


def test_window_sum_exactly_at_the_bound_is_no_alarm_and_just_above_is():
    bound = 2.0 * chi2.ppf(1.0 - 1e-6, 2 * 5)
    at = np.full(5, bound / 5)
    assert nis_alarm(at, np.inf, window=5, dof=2, false_alarm=1e-6, tolerance=2.0)[0] is None
    above = at * (1 + 1e-9)
    i, total, got_bound = nis_alarm(above, np.inf, window=5, dof=2, false_alarm=1e-6, tolerance=2.0)
    assert i == 0 and total == pytest.approx(bound, rel=1e-8) and got_bound == pytest.approx(bound, rel=1e-12)


def test_fewer_fixes_than_a_window_and_a_quiet_filter_give_no_alarm():
    i, total, _ = nis_alarm(np.full(19, 100.0), 13.8, window=20)
    assert i is None and math.isnan(total)
    i, total, bound = nis_alarm(np.full(100, 2.0), 13.8)  # the defaults: 20 fixes, 2 dof
    assert i is None and math.isnan(total)
    assert bound == pytest.approx(2.0 * chi2.ppf(1.0 - 1e-6, 40), rel=1e-12)
