"""The coarse clock alignment (eqs. 5.7, 5.8) does not depend on where either time axis starts.

Reference: the simulated truth. The tracker stamps are the trigger stamps (from the 200th on;
pulses lost at random, so that the gap pattern does not repeat)
plus a known shift ``tau_true``, so ``s_tracker - tau_true`` is on the trigger's time base; both
series are then moved to arbitrary origins, which moves the true shift by their difference.
"""

from __future__ import annotations

import numpy as np
import pytest

from identification.preprocessing import clock_sync


@pytest.mark.parametrize("trigger_origin_s, tracker_origin_s", [(0.0, 0.0), (2.5, 7.0), (-1.25, 100.0)])
def test_coarse_shift_maps_tracker_time_to_trigger_time_whatever_the_origins(trigger_origin_s,
                                                                             tracker_origin_s):
    rng = np.random.default_rng(4)
    slot = np.arange(3000)
    s = slot[rng.random(slot.size) > 0.01] * 0.02  # 50 Hz trigger, 1 % of the pulses lost at random: the gaps
    tau_true = 12.3456
    s_tracker = s[200:] + tau_true + rng.normal(0, 1e-6, s.size - 200)
    s_trigger = s + trigger_origin_s
    shift = tracker_origin_s - s_tracker[0]
    s_tracker = s_tracker + shift
    # tracker time t maps to trigger time t - tau: s_tracker[i] - tau = s_trigger[200 + i]
    tau_expected = tau_true + shift - trigger_origin_s
    tau, ratio = clock_sync.coarse_shift(s_trigger, s_tracker)
    assert abs(tau - tau_expected) <= 1.5e-3
    assert ratio < clock_sync.AMBIGUOUS_RATIO  # irregular gaps: one clear peak
    lags_s, corr = clock_sync.xcorr_gap_signals(s_trigger, s_tracker)
    assert abs(lags_s[np.argmax(corr)] - tau_expected) <= 1.5e-3
