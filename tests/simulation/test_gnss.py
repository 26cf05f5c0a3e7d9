"""Degraded GNSS generator: noise levels, lever arm, bias, latency, outages against their
definitions. (The checks of a series, :func:`groundfloor.gnss.check_gnss`, are tested in
``tests/groundfloor/test_gnss.py``.)"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundfloor.gnss import FLAG_OUTLIER
from simulation.gnss import PROFILES, GnssProfile, schedule_outages, simulate_gnss


def _circle(duration=600.0, rate=50.0):
    t = 1000.0 + np.arange(0, duration, 1 / rate)
    yaw = 0.1 * (t - t[0])
    return t, 10 * np.sin(yaw), -10 * np.cos(yaw), yaw  # radius 10 m, heading along the path


def test_lever_arm_puts_the_antenna_where_the_body_frame_says():
    t, x, y, yaw = _circle(60)
    exact = GnssProfile("exact", 10.0, 0.0, 0.0, 0.0, 0.0)
    g = simulate_gnss(t, x, y, yaw, exact, lever_arm_body=(0.5, -0.3, 0.7), outages=np.empty((0, 2)))
    # independent: complex rotation of the lever arm, truth evaluated analytically
    psi = 0.1 * (g.t_valid - t[0])
    p = 10 * np.sin(psi) - 1j * 10 * np.cos(psi) + np.exp(1j * psi) * (0.5 - 0.3j)
    np.testing.assert_allclose(g.p_local[:, 0], p.real, atol=2e-3)  # linear interpolation of 50 Hz truth
    np.testing.assert_allclose(g.p_local[:, 1], p.imag, atol=2e-3)
    np.testing.assert_allclose(g.p_local[:, 2], 0.7)
    np.testing.assert_allclose(np.diff(g.t_valid), 0.1, atol=1e-9)


@pytest.mark.parametrize("name", ["rtk", "dgnss"])
def test_white_noise_level_and_rate_match_the_profile(name):
    t, x, y, yaw = _circle(600)
    prof = replace(PROFILES[name], outlier_prob=0.0)
    g = simulate_gnss(t, x, y, yaw, prof, seed=3, lever_arm_body=(0, 0, 0), outages=np.empty((0, 2)))
    exact = simulate_gnss(t, x, y, yaw, replace(prof, std_m=0.0, std_up_m=0.0), seed=3,
                          lever_arm_body=(0, 0, 0), outages=np.empty((0, 2)))
    err = g.p_local[:, :2] - exact.p_local[:, :2]
    assert len(g.t_valid) == pytest.approx(600 * prof.rate_hz, abs=2)
    assert err.std() == pytest.approx(prof.std_m, rel=0.05)
    assert abs(err.mean()) < 4 * prof.std_m / np.sqrt(err.size)


def test_standalone_bias_wanders_slowly_with_its_stationary_std():
    t, x, y, yaw = _circle(3600, rate=5.0)
    prof = replace(PROFILES["standalone"], outlier_prob=0.0, std_m=0.0)
    errs = []
    for seed in range(8):
        g = simulate_gnss(t, x, y, yaw, prof, seed=seed, lever_arm_body=(0, 0, 0),
                          outages=np.empty((0, 2)))
        ref = simulate_gnss(t, x, y, yaw, replace(prof, bias_std_m=0.0), seed=seed,
                            lever_arm_body=(0, 0, 0), outages=np.empty((0, 2)))
        errs.append(g.p_local[:, 0] - ref.p_local[:, 0])
    e = np.array(errs)
    assert e.std() == pytest.approx(1.1, rel=0.2)  # 8 x 12 correlation times
    lag = int(prof.bias_tau_s)  # 1 Hz: one correlation time later the correlation is 1/e
    rho = np.mean(e[:, :-lag] * e[:, lag:]) / e.var()
    assert rho == pytest.approx(np.exp(-1), abs=0.15)
    assert np.mean(e[:, :-1] * e[:, 1:]) / e.var() > 0.99


def test_latency_and_outliers_follow_the_profile():
    t, x, y, yaw = _circle(1200)
    prof = PROFILES["dgnss"]
    g = simulate_gnss(t, x, y, yaw, prof, seed=5, outages=np.empty((0, 2)))
    delay = g.t_arrival - g.t_valid
    assert delay.min() >= prof.latency_s
    assert delay.mean() == pytest.approx(prof.latency_s + prof.latency_jitter_s, abs=0.003)
    frac = np.mean(g.flags & FLAG_OUTLIER > 0)
    assert frac == pytest.approx(prof.outlier_prob, abs=0.006)


def test_scheduled_outages_hold_no_fix_and_have_the_required_lengths():
    t, x, y, yaw = _circle(420)
    g = simulate_gnss(t, x, y, yaw, "rtk", seed=1)
    np.testing.assert_allclose(np.diff(g.outages, axis=1).ravel()[:4], [5, 10, 30, 60])
    for a, b in g.outages:
        assert not np.any((g.t_valid >= a) & (g.t_valid < b))
        assert np.any(np.abs(g.t_valid - b) < 0.11)  # fixes resume at the end
    assert schedule_outages(0.0, 420.0)[-1, 1] <= 420.0


def test_same_seed_same_series_other_seed_other_series():
    t, x, y, yaw = _circle(60)
    a = simulate_gnss(t, x, y, yaw, "dgnss", seed=11)
    b = simulate_gnss(t, x, y, yaw, "dgnss", seed=11)
    c = simulate_gnss(t, x, y, yaw, "dgnss", seed=12)
    np.testing.assert_array_equal(a.p_local, b.p_local)
    assert not np.allclose(a.p_local, c.p_local)
