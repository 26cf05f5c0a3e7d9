"""Measurement models against numerical derivatives and hand values (issue 14, item 5): the GNSS
antenna position with its lever arm (EKF and factor graph) at headings where the lever arm
matters, and the ``v_y = 0`` pseudo-measurement against the textbook Kalman update."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from sindy_ekf.estimation.ekf import h_gnss, lateral_update
from sindy_ekf.estimation.graph import X, _gnss_factor

LEVER = np.array([0.45, -0.30])  # antenna ahead and to the right of the body origin, m
HEADINGS = (0.0, 0.3, 1.2, math.pi / 2, 2.8, -2.0)


def _central_difference(fun, x, eps=1e-6):
    """Return the Jacobian of ``fun`` at ``x`` by central differences (independent of the code)."""
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((np.asarray(fun(x + d)) - np.asarray(fun(x - d))) / (2 * eps))
    return np.column_stack(cols)


def test_antenna_position_is_the_lever_arm_rotated_by_the_heading():
    # by hand: heading 90 deg turns the lever (0.45, -0.30) into (0.30, 0.45)
    h, _ = h_gnss(np.array([2.0, -1.0, math.pi / 2, 0.7, 0.0, 0.1]), LEVER)
    np.testing.assert_allclose(h, [2.30, -0.55], atol=1e-12)
    # heading 180 deg: (-0.45, 0.30)
    h, _ = h_gnss(np.array([0.0, 0.0, math.pi, 0.0, 0.0, 0.0]), LEVER)
    np.testing.assert_allclose(h, [-0.45, 0.30], atol=1e-12)


@pytest.mark.parametrize("psi", HEADINGS)
def test_gnss_jacobian_matches_central_differences(psi):
    x = np.array([3.0, -2.0, psi, 0.8, 0.05, -0.2])
    _, J = h_gnss(x, LEVER)
    J_num = _central_difference(lambda xx: h_gnss(xx, LEVER)[0], x)
    np.testing.assert_allclose(J, J_num, atol=1e-8)
    assert abs(J[0, 2]) + abs(J[1, 2]) > 0.3  # the heading column matters here


@pytest.mark.parametrize("psi", HEADINGS)
def test_graph_gnss_factor_predicts_the_ekf_antenna_position_and_its_jacobian(psi):
    """The factor graph's GNSS factor: zero error at the EKF's predicted antenna position, and its
    Jacobian (in gtsam's local pose coordinates) equal to central differences through retract."""
    x = np.array([1.5, 0.5, psi, 0.0, 0.0, 0.0])
    z, _ = h_gnss(x, LEVER)
    factor = _gnss_factor(0, z, np.array([0.3, 0.3, 0.6]), LEVER, robust=None)
    pose = gtsam.Pose2(x[0], x[1], x[2])

    def error(p):
        values = gtsam.Values()
        values.insert(X(0), p)
        return np.asarray(factor.unwhitenedError(values))

    np.testing.assert_allclose(error(pose), 0.0, atol=1e-12)
    # 10 cm off in x: an error of 10 cm whatever the heading (gtsam expresses it in the body
    # frame; the isotropic noise makes that the same cost)
    assert np.linalg.norm(error(gtsam.Pose2(x[0] + 0.1, x[1], x[2]))) == pytest.approx(0.1, abs=1e-12)
    values = gtsam.Values()
    values.insert(X(0), pose)
    H = factor.linearize(values).jacobian()[0] * 0.3  # whitened by sigma 0.3
    H_num = _central_difference(lambda xi: error(pose.retract(xi)), np.zeros(3))
    np.testing.assert_allclose(H, H_num, atol=1e-6)


def test_lateral_pseudo_measurement_is_the_textbook_kalman_update():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    P = A @ A.T + 0.1 * np.eye(6)
    x = rng.normal(size=6)
    r = 0.05 ** 2
    H = _central_difference(lambda xx: np.array([xx[4]]), x)  # h(x) = v_y
    S = H @ P @ H.T + r
    K = P @ H.T @ np.linalg.inv(S)
    x_ref = x + (K @ (0.0 - H @ x)).ravel()
    P_ref = (np.eye(6) - K @ H) @ P
    x1, P1, IKH = lateral_update(x[None], P[None], 0.05)
    np.testing.assert_allclose(x1[0], x_ref, atol=1e-10)
    np.testing.assert_allclose(P1[0], P_ref, atol=1e-10)
    np.testing.assert_allclose(IKH[0], np.eye(6) - K @ H, atol=1e-10)
