"""Clock synchronisation and the AT960 offset (thesis 5.2.2) against synthetic truth.

The synthetic runs (tests/tests.support.tracker_synth.py) know their drifts, duty cycles, lost and spurious
pulses; the simulator-based checks are in test_preprocess.py.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import PointSeries
from identification.preprocessing import clock_sync, extra_offset, sync
from tests.support.tracker_synth import R_LT, T_LT, synth_run


@pytest.fixture(scope="module")
def run_and_truth():
    raw, truth = synth_run(seed=11, minutes=1.0)
    return raw, truth, sync.sync_run(raw, R_LT, T_LT)


def test_gap_detection_finds_exactly_the_skipped_pulses():
    slot = np.arange(2000)
    slot = slot[slot % 150 != 7]
    t = slot * 0.02
    gaps = clock_sync.detect_gaps(t)
    expected = (np.arange(7, 2000, 150) - 1) * 0.02  # stamp before each skipped slot
    np.testing.assert_allclose(gaps, expected[expected < t[-1]])


def test_xcorr_recovers_a_known_shift():
    rng = np.random.default_rng(0)
    slot = np.arange(3000)
    s = (slot[(slot + 5) % 150 != 0]) * 0.02
    tau_true = 12.3456
    s_tracker = s[200:] + tau_true + rng.normal(0, 1e-6, s.size - 200)  # starts later too
    s_tracker -= s_tracker[0]
    tau, _ = clock_sync.coarse_shift(s, s_tracker, s_receive=s[200:])
    # tau maps tracker time to trigger time: s_tracker - tau = s (to the 1 ms grid)
    assert abs((s_tracker[0] - tau) - s[200]) <= 1.5e-3


def test_match_nearest_is_one_to_one_and_agrees_with_brute_force():
    rng = np.random.default_rng(1)
    a = np.sort(rng.uniform(0, 10, 300))
    b = np.sort(rng.uniform(0, 10, 250))
    ia, ib = clock_sync.match_nearest(a, b, tol=0.01)
    assert np.unique(ib).size == ib.size
    d = np.abs(a[:, None] - b[None, :])
    for i, j in zip(ia, ib):
        assert d[i, j] <= 0.01 and d[i, j] == d[i].min()
    # every a whose nearest b is within tol and uncontested is matched
    near = d.argmin(axis=1)
    ok = d.min(axis=1) <= 0.01
    uncontested = ok & (np.bincount(near[ok], minlength=b.size)[near] == 1)
    assert set(np.flatnonzero(uncontested)) <= set(ia)


def test_linear_clock_fit_agrees_with_polyfit_and_its_covariance():
    rng = np.random.default_rng(2)
    x = np.sort(rng.uniform(0, 300, 200))
    y = (1 + 28.5e-6) * x + 0.7 + rng.normal(0, 2e-6, x.size)
    k, d, k_std, d_std, s0 = clock_sync.fit_linear_clock(x, y)
    (k2, d2), cov = np.polyfit(x, y, 1, cov="unscaled")
    assert abs(k - k2) < 1e-12 and abs(d - d2) < 1e-9
    s0_ref = np.sqrt(np.sum((y - k2 * x - d2) ** 2) / (x.size - 2))
    assert k_std == pytest.approx(s0_ref * np.sqrt(cov[0, 0]), rel=1e-6)
    assert s0 == pytest.approx(2e-6, rel=0.15)


def test_clock_drifts_against_truth(run_and_truth):
    _, truth, r = run_and_truth
    ltd, at = r.clock["ltd800"], r.clock["at960"]
    assert abs(ltd.drift_ppm - truth["drift_ltd_ppm"]) < 0.05
    assert abs(at.drift_ppm - truth["drift_at_ppm"]) < 3 * at.drift_std_ppm
    assert ltd.n_gaps_matched >= 18 and at.n_gaps_matched >= 15


def test_extra_offset_found_from_data_within_20_us(run_and_truth):
    _, truth, r = run_and_truth
    assert r.offset_tracker == "at960"  # the one whose stamps scatter (varying duty cycle)
    assert abs(r.offset.dt - truth["mean_duty_s"]) < 20e-6
    # the timing error shows as correlation with speed before, and is gone after
    assert abs(r.r_speed_before) > 0.8 and abs(r.r_speed_after) < 0.3
    assert r.baseline_rms_m("after") < 0.2 * r.baseline_rms_m("before")


def test_offset_std_is_the_propagated_vertex_std(run_and_truth):
    _, _, r = run_and_truth
    o = r.offset
    a, b, c = o.coeffs

    def vertex(p):
        return -p[1] / (2 * p[0])

    J = np.array([(vertex(o.coeffs + h) - vertex(o.coeffs - h)) / (2 * h[i])
                  for i, h in enumerate(np.diag([1e-6 * abs(a), 1e-6 * max(abs(b), 1e-12), 1e-6]))])
    assert np.sqrt(J @ o.cov @ J) == pytest.approx(o.dt_std, rel=1e-4)


def test_counts_match_the_generated_lost_and_spurious_pulses(run_and_truth):
    raw, truth, r = run_and_truth
    c = r.counts["at960"]
    assert c.samples == raw.at960.t_tracker.size
    assert c.matched + c.spurious + c.outside == c.samples and c.outside == 0
    assert abs(c.lost - truth["lost_at960"]) <= 3
    assert abs(c.spurious - truth["spurious_at960"]) <= 3
    assert r.counts["ltd800"].lost == 0 and r.counts["ltd800"].spurious == 0


@pytest.mark.parametrize("method, degree", [("linear", 1), ("cubic", 3)])
def test_interpolation_is_exact_to_its_degree_and_refuses_long_gaps(method, degree):
    rng = np.random.default_rng(3)
    s = np.concatenate([np.arange(0, 0.2, 0.02), np.arange(0.5, 0.7, 0.02)])  # a 0.3 s dropout
    coef = rng.normal(size=(degree + 1, 3))
    xyz = np.polynomial.polynomial.polyval(s, coef).T
    q = np.array([0.011, 0.0713, 0.17, 0.3, 0.55, 0.75, -0.1])
    p = extra_offset.interpolate_at(q, s, xyz, max_gap_s=0.05, method=method)
    inside = np.array([1, 1, 1, 0, 1, 0, 0], bool)
    np.testing.assert_allclose(p[inside], np.polynomial.polynomial.polyval(q[inside], coef).T, atol=1e-12)
    assert np.isnan(p[~inside]).all()
    if method == "linear":  # and linear is not exact for a cubic: the test can tell them apart
        xyz3 = np.polynomial.polynomial.polyval(s, rng.normal(size=(4, 3))).T
        assert not np.allclose(extra_offset.interpolate_at(q[inside], s, xyz3, 0.05, "linear"),
                               extra_offset.interpolate_at(q[inside], s, xyz3, 0.05, "cubic"), atol=1e-9)


def test_nan_coordinates_are_dropped_and_counted():
    raw, _ = synth_run(seed=4, minutes=0.5)
    xyz = raw.ltd800.xyz.copy()
    xyz[100:105] = np.nan
    r = sync.sync_run(replace(raw, ltd800=PointSeries(raw.ltd800.t_tracker, xyz)), R_LT, T_LT)
    assert r.counts["ltd800"].dropped_nan == 5
    assert np.isfinite(r.baseline_after_m).sum() > 0.9 * r.s_trigger.size


def test_ambiguous_alignment_is_decided_by_receive_times():
    raw, truth = synth_run(seed=5, minutes=1.0)
    ps = raw.at960
    keep = ps.t_tracker - ps.t_tracker[0] > 4.5  # the AT960 starts 4.5 s late: gaps 3 s apart tie
    late = replace(raw, at960=PointSeries(ps.t_tracker[keep], ps.xyz[keep]),
                   t_receive_utc={**raw.t_receive_utc, "at960": raw.t_receive_utc["at960"][keep]})
    r = sync.sync_run(late, R_LT, T_LT)
    assert r.clock["at960"].xcorr_peak_ratio > clock_sync.AMBIGUOUS_RATIO
    assert abs(r.offset.dt - truth["mean_duty_s"]) < 20e-6


def test_no_gaps_names_run_and_topic():
    raw, _ = synth_run(seed=6, minutes=0.5)
    s = np.arange(raw.ltd800.t_tracker.size) * 0.02 + 100.0  # a tracker clock without gaps
    bad = replace(raw, ltd800=PointSeries(s, raw.ltd800.xyz))
    with pytest.raises(InputError, match=r"run run_01: topic /ltd800/measurement: no detectable gaps"):
        sync.sync_run(bad, R_LT, T_LT)


def test_trackers_that_disagree_are_refused():
    raw, _ = synth_run(seed=7, minutes=0.5)
    wrong = replace(raw, ltd800=PointSeries(raw.ltd800.t_tracker, raw.ltd800.xyz[::-1].copy()))
    with pytest.raises(InputError, match=r"run run_01: .*(disagree|no minimum)"):
        sync.sync_run(wrong, R_LT, T_LT)


def test_offset_unbiased_and_jackknife_std_honest_over_seeds():
    """Over eight synthetic runs the offset error has no bias and scales with the jackknife std
    (the eq. 5.21 std only measures how well ten spread samples lie on a parabola)."""
    err, z = [], []
    for seed in range(40, 48):
        raw, truth = synth_run(seed=seed, minutes=0.5)
        o = sync.sync_run(raw, R_LT, T_LT).offset
        err.append(o.dt - truth["mean_duty_s"])
        z.append(err[-1] / o.dt_std_jackknife)
    assert abs(np.mean(err)) < 3 * np.std(err) / np.sqrt(len(err))
    assert 0.4 < np.sqrt(np.mean(np.square(z))) < 2.5


def test_tracker_samples_before_the_trigger_train_are_outside_not_spurious():
    raw, _ = synth_run(seed=8, minutes=0.5)
    late = replace(raw, t_trigger_utc=raw.t_trigger_utc[250:])  # the trigger log starts 5 s late
    r = sync.sync_run(late, R_LT, T_LT)
    c = r.counts["ltd800"]
    assert c.outside == 250 and c.spurious == 0 and c.matched == c.samples - 250


def test_spurious_pulse_next_to_a_lost_one_is_matched_but_not_fitted():
    raw, truth = synth_run(seed=9, minutes=0.5)
    t = raw.ltd800.t_tracker.copy()
    t[700] += 0.8e-3  # the pulse was lost, a spurious one came 0.8 ms later
    r = sync.sync_run(replace(raw, ltd800=PointSeries(t, raw.ltd800.xyz)), R_LT, T_LT)
    c = r.clock["ltd800"]
    assert r.counts["ltd800"].matched == t.size and c.n_fit == t.size - 1
    assert abs(c.drift_ppm - truth["drift_ltd_ppm"]) < 0.05 and c.residual_std < 1e-6


def test_run_without_hub_azimuths_uses_the_thesis_estimate():
    raw, truth = synth_run(seed=10, minutes=0.5)
    r = sync.sync_run(replace(raw, t_hub_utc=np.empty(0), hub_azimuth=np.empty((0, 2))), R_LT, T_LT)
    assert not r.offset.hub_terms and r.offset.dt == r.offset.dt_without_hub
    assert abs(r.offset.dt - truth["mean_duty_s"]) < 20e-6 and abs(r.r_speed_after) < 0.3


def test_dropout_does_not_pull_the_coarse_alignment():
    """A 2 s dropout in a 15 s run: clipped into the gap signal it out-correlated the gaps."""
    raw, truth = synth_run(seed=12, minutes=0.25)
    ps = raw.ltd800
    s = ps.t_tracker - ps.t_tracker[0]
    keep = (s < 2.9) | (s > 5.1)
    run = replace(raw, ltd800=PointSeries(ps.t_tracker[keep], ps.xyz[keep]),
                  t_receive_utc={**raw.t_receive_utc, "ltd800": raw.t_receive_utc["ltd800"][keep]})
    r = sync.sync_run(run, R_LT, T_LT)
    assert abs(r.clock["ltd800"].tau) < 2e-3  # both clocks start with the run here
    assert abs(r.clock["ltd800"].drift_ppm - truth["drift_ltd_ppm"]) < 0.05
    assert r.counts["ltd800"].out_of_view >= 100


def test_spurious_sample_beside_a_true_one_does_not_bend_the_positions():
    """A spurious pulse 0.5 ms after a true one: a spline through both would swing by mm."""
    raw, truth = synth_run(seed=13, minutes=0.5, p_spur=0.0)
    ps = raw.at960
    i = 900
    t_extra = ps.t_tracker[i] + 0.5e-3
    xyz_extra = ps.xyz[i] + [30e-6, -30e-6, 0.0]  # its own noise
    at = PointSeries(np.insert(ps.t_tracker, i + 1, t_extra), np.insert(ps.xyz, i + 1, xyz_extra, axis=0))
    rx = {**raw.t_receive_utc, "at960": np.insert(raw.t_receive_utc["at960"], i + 1,
                                                   raw.t_receive_utc["at960"][i] + 0.5e-3)}
    r = sync.sync_run(replace(raw, at960=at, t_receive_utc=rx), R_LT, T_LT)
    base = r.baseline_after_m - np.nanmedian(r.baseline_after_m)
    assert r.counts["at960"].spurious == 1
    assert np.nanmax(np.abs(base)) < 0.2e-3


def test_coarse_alignment_some_ms_off_is_recentred_on_the_gaps(monkeypatch):
    raw, truth = synth_run(seed=14, minutes=0.5)
    true_shift = clock_sync.coarse_shift

    def off_by_5ms(*args, **kwargs):
        tau, ratio = true_shift(*args, **kwargs)
        return tau + 5e-3, ratio  # beyond the 4 ms gap matching of the thesis

    monkeypatch.setattr(clock_sync, "coarse_shift", off_by_5ms)
    r = sync.sync_run(raw, R_LT, T_LT)
    assert abs(r.clock["ltd800"].drift_ppm - truth["drift_ltd_ppm"]) < 0.05
    assert r.clock["ltd800"].n_gaps_matched >= 9
