"""Checks of a GNSS series (the filters' measurement type): bad series rejected naming the
stamp, or repaired with counts. Series come from the simulator's generator."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundfloor.gnss import check_gnss
from simulation.gnss import simulate_gnss


def _series():
    """Return two minutes of dgnss fixes on a circle of radius 10 m, heading along the path."""
    t = 1000.0 + np.arange(0, 120, 1 / 50.0)
    yaw = 0.1 * (t - t[0])
    return simulate_gnss(t, 10 * np.sin(yaw), -10 * np.cos(yaw), yaw, "dgnss", seed=2, outages=np.empty((0, 2)))


def test_nan_fixes_are_dropped_and_counted():
    g = _series()
    p = g.p_local.copy()
    p[[3, 40, 41], 0] = np.nan
    clean, repairs = check_gnss(replace(g, p_local=p), "run_03 gnss")
    assert repairs["nan_fixes_dropped"] == 3
    assert len(clean.t_valid) == len(g.t_valid) - 3 and np.all(np.isfinite(clean.p_local))


def test_duplicate_stamps_are_an_error_naming_the_stamp():
    g = _series()
    t = g.t_valid.copy()
    t[10] = t[9]
    with pytest.raises(ValueError, match=r"run_03 gnss: duplicate GNSS time of validity .*index 9"):
        check_gnss(replace(g, t_valid=t), "run_03 gnss")


def test_decreasing_stamps_are_an_error():
    g = _series()
    t = g.t_valid.copy()
    t[10] = t[8] - 0.05
    with pytest.raises(ValueError, match="run_03 gnss: GNSS times of validity decrease at index 10"):
        check_gnss(replace(g, t_valid=t, t_arrival=t + 0.1), "run_03 gnss")


def test_unscheduled_gaps_are_counted():
    g = _series()
    keep = (g.t_valid < 1030) | (g.t_valid > 1034)  # 4 s hole, no outage scheduled
    clean, repairs = check_gnss(replace(g, t_valid=g.t_valid[keep], t_arrival=g.t_arrival[keep],
                                        p_local=g.p_local[keep], std=g.std[keep],
                                        flags=g.flags[keep]), "gnss")
    assert repairs["unscheduled_gaps"] == 1
