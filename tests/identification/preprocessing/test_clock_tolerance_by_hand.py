"""The samples' matching tolerance by hand: ten times the robust spread of the gap residuals (the
median absolute deviation about their median, times 1.4826), at least 1 ms (fit_clock_model). One
of six gaps stamped 1.2 ms late skews the residuals: their median is not zero, and the spread about
the median stays small, so a stamp 2 ms off is beyond the tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from identification.preprocessing.clock_sync import fit_clock_model


def test_a_late_gap_skews_the_residuals_but_not_their_spread_about_the_median():
    # 18 s of 50 Hz pulses, one skipped every 3 s: six gaps; exact stamps on the tracker's clock
    # (s_trigger = k (t_tracker - 1000 s) + d), except the third gap's stamp 1.2 ms late and one
    # ordinary stamp 2 ms late
    slots = np.arange(901)
    s_trigger = slots[slots % 150 != 149] * 0.02
    k, d = 1.0 + 40e-6, -0.25
    t_tracker = 1000.0 + (s_trigger - d) / k
    gap = np.flatnonzero(np.diff(s_trigger) > 0.035)
    assert len(gap) == 6
    t_tracker[gap[2]] += 1.2e-3
    t_tracker[400] += 2e-3
    # by hand: the line through the six gaps (tracker time -> trigger time) and its residuals
    x, y = t_tracker[gap] - 1000.0, s_trigger[gap]
    res = y - np.polyval(np.polyfit(x, y, 1), x)
    assert abs(np.median(res)) > 1.5e-4  # skewed: one residual far out on one side
    spread = 1.4826 * np.median(np.abs(res - np.median(res)))
    tol = float(np.clip(10 * spread, 1e-3, 5e-3))
    assert tol < 2e-3 - 1e-4  # the stamp 2 ms off is beyond it
    model, i_trig, j_tr = fit_clock_model("at960", s_trigger, t_tracker)
    assert model.n_gaps_matched == 6
    assert 400 not in j_tr and gap[2] not in j_tr  # 2 and 1.2 ms off: both beyond the tolerance
    assert i_trig.size == s_trigger.size - 2  # every other pulse matched
    assert model.drift_ppm == pytest.approx(40.0, abs=1.0)
