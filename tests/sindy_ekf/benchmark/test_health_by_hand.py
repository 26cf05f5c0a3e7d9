"""Health by hand: the reset's position with a lever arm at a general heading, which fix counts as
"after" the alarm at the 1 us grid tolerance, where a result is cut and how it is spliced, and a
whole recovery redone step by step from its description (the variance factor carried over)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundfloor.gnss import GnssSeries
from sindy_ekf.benchmark.health import RESET_INFLATION, _cut, reset_state
from sindy_ekf.estimation.ekf import EkfResult

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def _gnss():
    fixes = np.array([[10.0, 5.0, 0.0], [11.0, 5.5, 0.0], [12.0, 6.0, 0.0]])
    std = np.array([[0.02, 0.03, 0.05], [0.04, 0.01, 0.05], [0.02, 0.02, 0.05]])
    return GnssSeries("rtk", np.array([1.0, 2.0, 3.0]), np.array([1.1, 2.1, 3.1]), fixes, std,
                      np.zeros(3, np.uint8), np.array([0.3, -0.2, 0.1]), np.empty((0, 2)))


def test_reset_removes_the_lever_arm_rotated_by_a_general_heading():
    x = np.array([0.0, 0.0, 0.7, 1.0, 0.1, 0.2])
    x1, P1 = reset_state(x, P0, _gnss(), t_from=1.5)
    c, s = math.cos(0.7), math.sin(0.7)
    # by hand: antenna = body + R(psi) [0.3, -0.2]
    lever_local = [0.3 * c + 0.2 * s, 0.3 * s - 0.2 * c]
    np.testing.assert_allclose(x1[:2], [11.0 - lever_local[0], 5.5 - lever_local[1]], atol=1e-12)
    np.testing.assert_allclose(x1[2:], x[2:], atol=0)
    np.testing.assert_allclose(np.diag(P1)[:2], [0.04 ** 2, 0.01 ** 2] + RESET_INFLATION ** 2 * np.diag(P0)[:2])
    np.testing.assert_allclose(np.diag(P1)[2:], RESET_INFLATION ** 2 * np.diag(P0)[2:])
    assert np.count_nonzero(P1 - np.diag(np.diag(P1))) == 0


@pytest.mark.parametrize("t_from, x_fix", [(2.0, 12.0), (2.0 - 0.5e-6, 12.0), (2.0 - 1.5e-6, 11.0),
                                           (1.0, 11.0), (0.0, 10.0)])
def test_the_fix_after_the_alarm_is_the_first_more_than_1_us_later(t_from, x_fix):
    g = _gnss()
    x = np.array([0.0, 0.0, 0.0, 1.0, 0.1, 0.2])  # heading 0: the lever arm is [0.3, -0.2] as it is
    x1, _ = reset_state(x, P0, g, t_from)
    assert x1[0] == pytest.approx(x_fix - 0.3, abs=1e-12)


def _result():
    t = np.round(np.arange(11) * 0.2, 12)
    nis_t = np.array([0.2, 0.4, 1.0 - 1.5e-6, 1.0 - 0.5e-6, 1.0, 1.4])
    m = len(nis_t)
    return EkfResult("r", t, np.arange(11.0)[:, None] * np.ones(6), np.ones((11, 6, 6)), np.arange(m, dtype=float),
                     nis_t, np.ones(m, bool), 13.8, 0, np.zeros(11, bool), 1.0, {},
                     np.arange(2.0 * m).reshape(m, 2), np.ones((m, 2, 2)), np.arange(m, dtype=float) + 1.0)


def test_a_result_cut_at_a_time_keeps_what_lies_more_than_1_us_before_it():
    cut = _cut(_result(), 1.0)
    np.testing.assert_array_equal(cut.t, np.round(np.arange(5) * 0.2, 12))  # up to 0.8 s, 1.0 s excluded
    assert cut.x.shape == (5, 6) and cut.P.shape == (5, 6, 6) and cut.outside_envelope.shape == (5,)
    # the fixes at 1.0 s and 0.5 us before it are the same instant: excluded; 1.5 us before: kept
    np.testing.assert_array_equal(cut.nis, [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(cut.nis_t, [0.2, 0.4, 1.0 - 1.5e-6])
    np.testing.assert_array_equal(cut.innovation, [[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]])
    np.testing.assert_array_equal(cut.r_scale, [1.0, 2.0, 3.0])
    assert cut.accepted.shape == (3,) and cut.innovation_cov.shape == (3, 2, 2)
    # half a tolerance past a grid time cuts there too
    assert len(_cut(_result(), 1.0 + 0.5e-6).t) == 5
    assert len(_cut(_result(), 1.0 + 1.5e-6).t) == 6


def test_a_spliced_result_is_the_head_before_the_tail_then_the_tail_with_the_counts_added():
    from dataclasses import replace

    from sindy_ekf.benchmark.health import _splice

    head = replace(_result(), pd_repairs=2, saturated_steps=5, runtime_s=1.5)
    t_tail = np.round(1.0 + np.arange(3) * 0.2, 12)
    tail = EkfResult("r", t_tail, np.full((3, 6), -1.0), np.zeros((3, 6, 6)), np.array([7.0]), np.array([1.2]),
                     np.zeros(1, bool), 13.8, 1, np.ones(3, bool), 0.25, {}, np.full((1, 2), 9.0),
                     np.full((1, 2, 2), 9.0), np.array([4.0]), saturated_steps=3)
    got = _splice(head, tail)
    np.testing.assert_array_equal(got.t, np.round(np.r_[np.arange(5) * 0.2, 1.0, 1.2, 1.4], 12))
    np.testing.assert_array_equal(got.x[:, 0], [0.0, 1.0, 2.0, 3.0, 4.0, -1.0, -1.0, -1.0])
    np.testing.assert_array_equal(got.nis, [0.0, 1.0, 2.0, 7.0])
    np.testing.assert_array_equal(got.nis_t, [0.2, 0.4, 1.0 - 1.5e-6, 1.2])
    np.testing.assert_array_equal(got.r_scale, [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(got.outside_envelope, [False] * 5 + [True] * 3)
    assert (got.pd_repairs, got.saturated_steps, got.runtime_s) == (3, 8, 1.75)


def test_eight_fixes_on_two_levels_are_a_step_and_seven_are_too_few_to_tell():
    from sindy_ekf.benchmark.step_test import fixes_stepped

    rng = np.random.default_rng(3)
    y = np.zeros((8, 2)) + 0.01 * rng.standard_normal((8, 2))
    y[4:, 0] += 1.0  # a 1 m step under 1 cm noise (innovation std 1 cm)
    S = np.repeat(1e-4 * np.eye(2)[None], 8, axis=0)
    assert fixes_stepped(y, S, need_step=True)
    assert not fixes_stepped(y[1:], S[1:], need_step=True)  # fewer than 8 fixes: no test


@pytest.mark.parametrize("n_levels, stepped", [(8, True), (9, False)])
def test_eight_levels_of_four_fixes_are_a_step_and_nine_are_more_than_the_test_tells_apart(n_levels, stepped):
    # levels alternating between 0 and 1 m in x (4 fixes each, 1 cm noise): no quadratic follows a
    # zigzag, so the levels win whenever they pass their test; by the docstring at most eight
    # levels are told apart (MAX_LEVELS), and any partition of nine levels into eight merges two
    # levels 1 m apart, 1e4 variances off per fix, far beyond the chi-square bound
    from sindy_ekf.benchmark.step_test import fixes_stepped

    n = 4 * n_levels
    rng = np.random.default_rng(11)
    y = 0.01 * rng.standard_normal((n, 2))
    y[:, 0] += np.repeat(np.arange(n_levels) % 2, 4) * 1.0
    S = np.repeat(1e-4 * np.eye(2)[None], n, axis=0)
    assert fixes_stepped(y, S) == stepped


def test_segment_fit_of_fixes_with_weights_below_one_matches_a_direct_computation():
    # weights 1 / var below one (innovation variances above 1 m^2, a poor fix): a segment whose
    # weights sum to less than one is not empty, its residual sum is the direct one
    from sindy_ekf.benchmark.step_test import _segment_rss

    rng = np.random.default_rng(4)
    y, w = rng.normal(size=(6, 2)), rng.uniform(0.05, 0.2, 6)
    rss = _segment_rss(w, y)
    for a in range(7):
        assert rss[a, a] == 0.0  # empty
        for b in range(a + 1, 7):
            m = np.sum(w[a:b, None] * y[a:b], axis=0) / np.sum(w[a:b])
            assert rss[a, b] == pytest.approx(np.sum(w[a:b, None] * (y[a:b] - m) ** 2), rel=1e-9, abs=1e-12)
    assert rss[0, 6] > 0.1  # the whole series scatters: not the zero of an empty segment


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_an_isolated_outlier_on_either_side_is_left_out_of_the_step_test(sign):
    # two levels of six fixes under 1 cm noise and one fix 5 m off (either way): its squared
    # distance from the running median is 2.5e5 variances, beyond the 0.999 chi-square bound, so it is
    # left out (one of 13, under the 20 % share) and the rest is a step
    from sindy_ekf.benchmark.step_test import fixes_stepped

    rng = np.random.default_rng(5)
    y = 0.01 * rng.standard_normal((13, 2))
    y[6:, 0] += 1.0
    y[3] += sign * 5.0
    S = np.repeat(1e-4 * np.eye(2)[None], 13, axis=0)
    assert fixes_stepped(y, S, need_step=True)


def test_combined_status_names_the_worst_run_and_counts_the_others():
    from sindy_ekf.benchmark.health import RunStatus, combined_status

    ok = RunStatus(recoveries=1, fix_steps=2)
    bad = RunStatus("diverged", 3.0, "NIS alarm", 1)
    worse = RunStatus("failed", 0.0, "ValueError: x")
    got = combined_status({"a": ok, "b": bad, "c": bad, "d": worse})
    assert got.status == "failed" and got.reason == "d: ValueError: x (and 2 other run(s))"
    assert got.recoveries == 3 and got.fix_steps == 2
    assert combined_status({"a": ok, "b": bad}).reason == "b: NIS alarm"  # no other run: no count
    assert combined_status({"a": ok, "b": ok}) == RunStatus(recoveries=2, fix_steps=4)


def test_a_reset_carries_over_the_variance_factor_learnt_up_to_the_alarm_window():
    # the recovery redone by hand from its description (module docstring of health): fixes whose
    # stated std is a third of their noise (the filter's variance factor grows to about 9) jump
    # 20 m east at 15 s; the plain filter's first NIS alarm window starts at fix j, the alarm is at
    # its first gated fix, and the filter is re-initialised from the next fix with the stated
    # covariance times the factor of fix j - 1 (reset and tail alike), the head kept as it was
    from dataclasses import replace

    from simulation.gnss import PROFILES, simulate_gnss
    from sindy_ekf.benchmark.health import guarded_ekf_batch, nis_alarm
    from sindy_ekf.estimation.ekf import (
        GRID_TOL_S,
        EkfRun,
        estimation_grid,
        run_ekf_batch,
    )
    from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
    from tests.support.estimation_helpers import (
        PolyBody,
        inputs_at,
        simulate_truth,
        simulate_truths,
    )

    oracle = ProcessModel(PolyBody(), name="oracle")
    model = fit_process_noise(oracle, simulate_truths(oracle, 30.0, np.random.default_rng(100), n_runs=4))
    truth = simulate_truth(model, 40.0, np.random.default_rng(7))
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2],
                         replace(PROFILES["dgnss"], outlier_prob=0.0), seed=1, outages=np.empty((0, 2)))
    p = gnss.p_local.copy()
    p[gnss.t_valid >= truth.t[0] + 15.0, 0] += 20.0
    gnss = replace(gnss, p_local=p, std=gnss.std / 3.0)
    t = estimation_grid(truth.t, gnss.t_valid)
    run = EkfRun("jumpy", t, inputs_at(truth, t), truth.x6[0], P0, gnss)
    [(res, status)] = guarded_ekf_batch(model, [run], step_test=False)
    assert status.status == "ok" and status.recoveries == 1

    plain = run_ekf_batch(model, [run])[0]
    j = nis_alarm(plain.nis, plain.gate_nis)[0]
    assert plain.r_scale[j - 1] > 2.0 and abs(plain.r_scale[j - 1] - plain.r_scale[j - 2]) > 1.0  # learnt, varying
    t_alarm = plain.nis_t[j + np.flatnonzero(plain.nis[j:j + 20] > plain.gate_nis)[0]]
    k = int(np.searchsorted(t, t_alarm - GRID_TOL_S))
    scaled = replace(gnss, std=gnss.std * math.sqrt(plain.r_scale[j - 1]))
    x0, P0_reset = reset_state(plain.x[k], P0, scaled, t_alarm)
    after = gnss.t_valid > t_alarm + GRID_TOL_S
    tail_gnss = replace(scaled, **{f: getattr(scaled, f)[after] for f in ("t_valid", "t_arrival", "p_local", "std",
                                                                        "flags")})
    tail = run_ekf_batch(model, [EkfRun("jumpy", t[k:], run.u[k:], x0, P0_reset, tail_gnss)])[0]
    np.testing.assert_array_equal(res.x[:k], plain.x[:k])
    np.testing.assert_allclose(res.x[k:], tail.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.P[k], P0_reset, rtol=0, atol=1e-15)
