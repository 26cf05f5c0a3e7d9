"""Integral regression pieces against hand computations: the condition number of a diagonal
matrix, of one column and of a singular matrix, the warning above 1e8, the QR compression's normal
equations, a run too short for any window, and STLSQ's default of 20 rounds on a problem that drops
one term per round."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.regression import (
    IllConditionedWarning,
    check_conditioning,
    condition_number,
    fit_stlsq,
    integral_problem,
)


def _states(duration_s: float, phase: float) -> BodyStates:
    t = np.arange(0.0, duration_s, 0.02)
    return BodyStates(t=t, vx=np.sin(t + phase), vy=0.1 * np.cos(2 * t), omega=0.3 * np.sin(0.5 * t + phase),
                      u1=np.cos(1.3 * t + phase), u2=np.sin(0.7 * t) ** 2, x=t, y=t, yaw=t)


def test_condition_number_of_a_diagonal_matrix_is_its_largest_over_smallest_entry():
    assert condition_number(np.diag([0.5, 4.0, 2.0])) == pytest.approx(8.0, rel=1e-12)
    assert condition_number(np.array([[3.0, 0.0], [0.0, 0.0]])) == np.inf  # singular


def test_condition_number_of_one_column_is_one_and_of_a_singular_matrix_infinite():
    assert condition_number(np.array([[2.0]])) == 1.0
    assert condition_number(np.array([[-3.0], [4.0]])) == 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # infinite by the guard, not by a division by zero
        assert condition_number(np.diag([3.0, 2.0, 0.0])) == np.inf


def test_a_condition_number_above_1e8_is_reported_ill_conditioned():
    with pytest.warns(IllConditionedWarning, match=r"problem A: .*condition number 1\.5e\+08"):
        assert check_conditioning(np.diag([1.0, 1.0 / 1.5e8]), "problem A") == pytest.approx(1.5e8, rel=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_conditioning(np.diag([2.0, 2.0 / 0.9e8]), "problem B") == pytest.approx(0.9e8, rel=1e-12)


def test_compressed_problem_has_the_normal_equations_of_the_full_one():
    """R^T R = Theta'^T Theta' and R^T (Q^T Delta X) = Theta'^T Delta X (least squares unchanged)."""
    problem = integral_problem([_states(20.0, 0.0), _states(15.0, 1.0)], "poly2", tau=2.0)
    r, c = problem.compressed()
    th, dx = problem.theta_int, problem.delta_x
    np.testing.assert_allclose(r.T @ r, th.T @ th, rtol=1e-9, atol=1e-9 * np.abs(th.T @ th).max())
    np.testing.assert_allclose(r.T @ c, th.T @ dx, rtol=1e-9, atol=1e-9 * np.abs(th.T @ dx).max())


def test_a_run_shorter_than_the_window_adds_no_window_and_no_row():
    long_run, short_run = _states(20.0, 0.0), _states(1.0, 1.0)  # 1 s of data, tau 2 s
    both = integral_problem([long_run, short_run], "poly2", tau=2.0)
    alone = integral_problem([long_run], "poly2", tau=2.0)
    assert both.n_windows == alone.n_windows
    assert not np.any(both.run_index == 1)
    n_features = both.theta_int.shape[1]
    assert both.r_factors[1].shape == (0, n_features)
    assert both.qt_targets[1].shape == (0, 3)
    np.testing.assert_array_equal(both.compressed()[0], alone.compressed()[0])
    np.testing.assert_array_equal(both.compressed()[1], alone.compressed()[1])


def test_stlsq_stops_after_20_rounds_by_default():
    # a problem that drops exactly one term per round (by hand): column j is ones on rows 0..j, so
    # on the first m columns least squares gives xi_j = y_j - y_{j+1} for j < m - 1 and
    # xi_{m-1} = y_{m-1}; with y alternating +-0.6 the differences are +-1.2 (kept by a threshold of
    # 1) and only the last column's 0.6 falls under it. Of 30 columns, 20 rounds leave the first 10
    # (then refitted by least squares on them); 21 would leave 9, and to convergence none.
    n = 30
    theta = np.triu(np.ones((n, n)))
    y = 0.6 * (-1.0) ** np.arange(n)
    expected = np.zeros(n)
    expected[:9] = y[:9] - y[1:10]
    expected[9] = y[9]
    np.testing.assert_allclose(fit_stlsq(theta, y[:, None], threshold=1.0, alpha=0.0)[0], expected, atol=1e-9)
    rounds_21 = np.zeros(n)
    rounds_21[:8], rounds_21[8] = y[:8] - y[1:9], y[8]
    np.testing.assert_allclose(fit_stlsq(theta, y[:, None], threshold=1.0, alpha=0.0, max_iter=21)[0], rounds_21,
                               atol=1e-9)


def test_by_default_windows_are_3_s_long_and_none_spans_a_step_longer_than_0_2_s():
    # 10 s at 50 Hz with a hole from 5.0 to 5.3 s (a 0.3 s step): by hand, the windows [t0, t0 + 3 s]
    # that lie on either side of the hole start at 0, 0.02, ..., 2.0 s and at 5.3, ..., 7.0 s
    t = np.arange(501) * 0.02
    t = t[(t < 5.0 + 1e-9) | (t > 5.3 - 1e-9)]
    st = BodyStates(t=t, vx=np.sin(t), vy=0.1 * np.cos(2 * t), omega=0.3 * np.sin(0.5 * t),
                    u1=np.cos(1.3 * t), u2=np.sin(0.7 * t) ** 2, x=t, y=t, yaw=t)
    problem = integral_problem([st])
    expected = np.concatenate([np.arange(101) * 0.02, 5.3 + np.arange(86) * 0.02])
    np.testing.assert_allclose(problem.t_start, expected, atol=1e-9)
    assert problem.tau == 3.0
