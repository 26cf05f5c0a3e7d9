"""GNSS faults against their own definitions: each fault laid over a series changes exactly the
fixes it names by exactly what it states, and the draws respect their ranges and the seed."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.gnss import FLAG_OUTLIER
from simulation.gnss import GnssProfile, simulate_gnss
from simulation.gnss_faults import (
    COV_TOO_SMALL,
    FAULT_MIXES,
    FLAG_BURST,
    FLAG_JUMPED,
    FaultMix,
    GnssFaults,
    apply_gnss_faults,
    draw_gnss_faults,
)


def _series(duration=200.0, seed=0):
    t = 500.0 + np.arange(0.0, duration, 0.02)
    yaw = 0.05 * (t - t[0])
    prof = GnssProfile("test", 5.0, 0.3, 0.6, 0.1, 0.02)
    return simulate_gnss(t, 20 * np.sin(yaw), -20 * np.cos(yaw), yaw, prof, seed=seed, outages=np.empty((0, 2)))


def test_no_fault_leaves_the_series_unchanged():
    g = _series()
    f = apply_gnss_faults(g, GnssFaults())
    for name in ("t_valid", "t_arrival", "p_local", "std", "flags", "outages"):
        np.testing.assert_array_equal(getattr(f, name), getattr(g, name))


def test_stated_covariance_is_exactly_a_tenth_of_the_true_one():
    g = _series()
    f = apply_gnss_faults(g, GnssFaults(cov_scale=COV_TOO_SMALL))
    np.testing.assert_allclose(f.std ** 2, 0.1 * g.std ** 2, rtol=1e-14)
    np.testing.assert_array_equal(f.p_local, g.p_local)  # the fixes themselves are untouched


def test_a_jump_moves_every_later_fix_by_its_offset_and_no_earlier_one():
    g = _series()
    tj = float(g.t_valid[400]) - 0.05  # between two fixes
    f = apply_gnss_faults(g, GnssFaults(jump_t=np.array([tj]), jump_offset_m=np.array([[3.0, -4.0]])))
    d = f.p_local - g.p_local
    after = g.t_valid >= tj
    assert after.sum() == len(g.t_valid) - 400
    np.testing.assert_allclose(d[after, :2], np.broadcast_to([3.0, -4.0], (after.sum(), 2)), atol=1e-12)
    np.testing.assert_array_equal(d[~after], 0.0)
    np.testing.assert_array_equal(d[:, 2], 0.0)  # horizontal only
    assert np.all((f.flags & FLAG_JUMPED).astype(bool) == after)


def test_two_jumps_add_up():
    g = _series()
    t1, t2 = g.t_valid[100], g.t_valid[300]
    f = apply_gnss_faults(g, GnssFaults(jump_t=np.array([t1, t2]), jump_offset_m=np.array([[1.0, 0.0], [0.0, 2.0]])))
    d = (f.p_local - g.p_local)[:, :2]
    np.testing.assert_allclose(d[200], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(d[-1], [1.0, 2.0], atol=1e-12)


def test_a_burst_covers_its_interval_and_nothing_else():
    g = _series()
    a, b = 559.9, 566.1
    f = apply_gnss_faults(g, GnssFaults(bursts=np.array([[a, b]]), burst_offset_m=np.array([[-2.0, 1.5]])))
    d = (f.p_local - g.p_local)[:, :2]
    inside = (g.t_valid >= a) & (g.t_valid < b)
    assert inside.sum() == 31  # the 5 Hz fixes 560.0, 560.2, ..., 566.0
    np.testing.assert_allclose(d[inside], np.broadcast_to([-2.0, 1.5], (inside.sum(), 2)), atol=1e-12)
    np.testing.assert_array_equal(d[~inside], 0.0)
    assert np.all((f.flags & FLAG_BURST).astype(bool) == inside)


def test_outliers_hit_the_named_fixes_only():
    g = _series()
    hit = g.t_valid[[10, 250, 700]]
    off = np.array([[10.0, 0.0], [0.0, -5.0], [2.0, 2.0]])
    f = apply_gnss_faults(g, GnssFaults(outlier_t=hit, outlier_offset_m=off))
    d = (f.p_local - g.p_local)[:, :2]
    np.testing.assert_allclose(d[[10, 250, 700]], off, atol=1e-12)
    assert np.count_nonzero(np.any(d != 0, axis=1)) == 3
    assert np.flatnonzero(f.flags & FLAG_OUTLIER).tolist() == [10, 250, 700]


def test_an_outage_removes_every_fix_in_it_and_is_recorded():
    g = _series()
    o = np.array([[600.0, 660.0]])
    f = apply_gnss_faults(g, GnssFaults(outages=o))
    assert not np.any((f.t_valid >= 600.0) & (f.t_valid < 660.0))
    assert len(g.t_valid) - len(f.t_valid) == 60 * 5
    np.testing.assert_array_equal(f.outages, o)
    assert f.t_arrival.shape == f.t_valid.shape and f.std.shape == f.p_local.shape


def test_an_outlier_time_off_the_fixes_is_an_error():
    g = _series()
    with pytest.raises(InputError, match="outlier time"):
        apply_gnss_faults(g, GnssFaults(outlier_t=np.array([g.t_valid[3] + 0.01]),
                                        outlier_offset_m=np.zeros((1, 2))))


def test_draws_respect_their_ranges_and_the_seed():
    g = _series()
    mix = FAULT_MIXES["all"]
    a = draw_gnss_faults(g.t_valid, mix, seed=7)
    assert a.kinds() == ("outliers", "multipath", "jump", "cov_small", "outage")
    t0 = g.t_valid[0] + mix.warmup_s
    assert np.all(a.outlier_t >= t0) and np.all(a.jump_t >= t0) and np.all(a.bursts[:, 0] >= t0)
    mags = np.hypot(a.outlier_offset_m[:, 0], a.outlier_offset_m[:, 1])
    assert np.all((mags >= 2.0) & (mags <= 20.0))
    assert 1 <= len(a.bursts) <= 3
    durations = np.diff(a.bursts, axis=1)
    assert np.all((durations >= 2.0) & (durations <= 10.0))
    d = float(a.outages[0, 1] - a.outages[0, 0])
    assert min(abs(d - c) for c in mix.outage_choices_s) < 1e-9 and a.outages[0, 0] >= t0
    assert a.outages[0, 1] <= g.t_valid[-1] - mix.margin_s
    b = draw_gnss_faults(g.t_valid, mix, seed=7)
    np.testing.assert_array_equal(a.outlier_offset_m, b.outlier_offset_m)
    np.testing.assert_array_equal(a.outages, b.outages)
    c = draw_gnss_faults(g.t_valid, mix, seed=8)
    assert not np.array_equal(a.outlier_t, c.outlier_t)


def test_outlier_rate_matches_its_probability():
    g = _series(duration=2000.0)
    f = draw_gnss_faults(g.t_valid, FaultMix(outlier_prob=0.05), seed=1)
    n = np.sum(g.t_valid >= g.t_valid[0] + 30.0)
    assert abs(f.outlier_t.size / n - 0.05) < 4 * np.sqrt(0.05 * 0.95 / n)


def test_an_outage_that_cannot_fit_is_an_error():
    g = _series(duration=80.0)
    with pytest.raises(InputError, match="60 s outage does not fit"):
        draw_gnss_faults(g.t_valid, FaultMix(n_outages=1, outage_choices_s=(60.0,)), seed=0)
