"""Integral regression pieces against hand computations: the condition number of a diagonal
matrix, the QR compression's normal equations, and a run too short for any window."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.regression import condition_number, integral_problem


def _states(duration_s: float, phase: float) -> BodyStates:
    t = np.arange(0.0, duration_s, 0.02)
    return BodyStates(t=t, vx=np.sin(t + phase), vy=0.1 * np.cos(2 * t), omega=0.3 * np.sin(0.5 * t + phase),
                      u1=np.cos(1.3 * t + phase), u2=np.sin(0.7 * t) ** 2, x=t, y=t, yaw=t)


def test_condition_number_of_a_diagonal_matrix_is_its_largest_over_smallest_entry():
    assert condition_number(np.diag([0.5, 4.0, 2.0])) == pytest.approx(8.0, rel=1e-12)
    assert condition_number(np.array([[3.0, 0.0], [0.0, 0.0]])) == np.inf  # singular


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
