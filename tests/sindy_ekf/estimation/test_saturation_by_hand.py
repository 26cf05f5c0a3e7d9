"""The model's velocity envelope and the saturated step by hand (process_models): the bounds are the
envelope widened by 10 % of its width on both sides, a velocity on the bound is inside, and a
state beyond it is projected onto it before the step (``step(clip(x))``), the projected velocity's
column of ``F`` the unit column and every other column the map's central differences."""

from __future__ import annotations

import numpy as np
import pytest

from sindy_ekf.estimation.process_models import ProcessModel, outside_bounds
from tests.support.estimation_helpers import PolyBody, linear_gaussian_model


class _OnlyVx(PolyBody):
    envelope = {"vx": [0.0, 2.0], "u1": [-1, 1], "u2": [-1, 1]}


def test_velocity_bounds_are_the_envelope_widened_by_a_tenth_of_its_width():
    lo, hi = ProcessModel(PolyBody()).velocity_bounds()  # vx, omega in [-1, 1], vy in [-0.3, 0.3]
    np.testing.assert_allclose(lo, [-1.2, -0.36, -1.2], rtol=1e-12)
    np.testing.assert_allclose(hi, [1.2, 0.36, 1.2], rtol=1e-12)
    lo, hi = ProcessModel(PolyBody()).velocity_bounds(margin=0.5)
    np.testing.assert_allclose(hi, [2.0, 0.6, 2.0], rtol=1e-12)
    lo, hi = ProcessModel(_OnlyVx()).velocity_bounds()  # unbounded sides stay infinite
    np.testing.assert_allclose(lo, [-0.2, -np.inf, -np.inf])
    np.testing.assert_allclose(hi, [2.2, np.inf, np.inf])
    assert ProcessModel(linear_gaussian_model().dynamics).velocity_bounds() is None  # no envelope


class _OneSided(PolyBody):
    envelope = {"vx": [0.0, np.inf], "vy": [-np.inf, 0.3], "omega": [-1.0, 1.0], "u1": [-1, 1], "u2": [-1, 1]}


def test_a_bound_with_an_unbounded_other_side_is_not_widened():
    # the width of a one-sided envelope is infinite: no finite pad is a tenth of it, so the finite
    # side stays where it is (SindyModel._outside's rule, np.where(isfinite(width), width, 0))
    lo, hi = ProcessModel(_OneSided()).velocity_bounds()
    np.testing.assert_array_equal(lo, [0.0, -np.inf, -1.2])
    np.testing.assert_array_equal(hi, [np.inf, 0.3, 1.2])


@pytest.mark.parametrize("v, outside", [([0.0, 0.0, 0.0], False), ([1.2, -0.36, 1.2], False),
                                        ([1.2 + 1e-9, 0.0, 0.0], True), ([0.0, -0.36 - 1e-9, 0.0], True),
                                        ([0.0, 0.0, 1.3], True), ([0.0, 0.0, -1.3], True)])
def test_outside_bounds_is_strictly_beyond_a_bound(v, outside):
    lo, hi = np.array([-1.2, -0.36, -1.2]), np.array([1.2, 0.36, 1.2])
    x = np.zeros((2, 6))
    x[1, 3:] = v  # the second row decides: every row is checked
    assert outside_bounds(x, lo, hi) is outside


def test_a_velocity_beyond_the_envelope_is_projected_onto_it_and_its_covariance_carried_over():
    model = ProcessModel(PolyBody())
    bounds = model.velocity_bounds()
    x = np.array([[0.5, -0.2, 0.3, 2.0, 0.1, -0.4],     # vx beyond 1.2
                  [0.0, 0.0, -1.0, 0.4, -0.5, 1.5],     # vy below -0.36 and omega beyond 1.2
                  [1.0, 1.0, 0.2, 0.3, 0.0, 0.2]])      # inside
    u = np.array([[0.5, 0.1], [0.2, -0.3], [0.1, 0.4]])
    t, dt = np.zeros(3), np.full(3, 0.02)
    x_next, F, held = model.saturated_step_and_jac(x, u, t, dt, bounds)
    np.testing.assert_array_equal(held, [True, True, False])

    def g(x_in):  # the documented map: the step from the state projected onto the envelope
        x_sat = x_in.copy()
        x_sat[:, 3:] = np.clip(x_in[:, 3:], *bounds)
        return model.step(x_sat, u, t, dt)

    # by hand: the projected states
    x_sat = x.copy()
    x_sat[0, 3], x_sat[1, 4], x_sat[1, 5] = 1.2, -0.36, 1.2
    np.testing.assert_allclose(x_next, model.step(x_sat, u, t, dt), atol=1e-14)
    h = 1e-6
    projected = {(0, 3), (1, 4), (1, 5)}
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        fd = (g(x + e) - g(x - e)) / (2 * h)  # central differences of the map
        for i in range(3):
            if (i, j) in projected:  # not the map's derivative (zero): the unit column, covariance kept
                np.testing.assert_array_equal(F[i, :, j], np.eye(6)[j])
            else:
                np.testing.assert_allclose(F[i, :, j], fd[i], atol=1e-7, err_msg=f"{i}, {j}")
