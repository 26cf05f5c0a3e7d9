"""Small pieces of the estimators by hand: the closed-form inverse of a 2 x 2 innovation covariance
against the textbook adjugate formula, iSAM2's initial guesses for a model that reads the clock
(a run that does not start at zero: the time since the run's start, as the dynamics factors use)
and its computing time (within the call's), and the Gauss-Markov fit refusing a series that grows
instead of reverting (``phi`` not in (0, 1)).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from sindy_ekf.estimation.ekf import inverse_2x2
from sindy_ekf.estimation.graph import smooth_isam2
from sindy_ekf.estimation.process_models import (
    ProcessModel,
    StateSeries,
    fit_mean_reversion,
)
from tests.support.estimation_helpers import PolyBody


@pytest.mark.parametrize("S", [[[2.0, 0.5], [0.3, 4.0]], [[0.04, -0.01], [-0.03, 0.09]], [[3.0, 0.0], [0.0, 0.5]]])
def test_inverse_2x2_is_the_adjugate_over_the_determinant(S):
    # by hand: [[a, b], [c, d]]^-1 = [[d, -b], [-c, a]] / (a d - b c); non-symmetric and det != 1 so
    # that every entry's division shows
    (a, b), (c, d) = S
    det = a * d - b * c
    want = np.array([[d, -b], [-c, a]]) / det
    got = inverse_2x2(np.array(S))
    np.testing.assert_allclose(got, want, rtol=1e-14)
    np.testing.assert_allclose(got @ np.array(S), np.eye(2), atol=1e-12)


C = 0.8  # forward acceleration per second since the run's start, m/s^3


class _KnowsTheClock(PolyBody):
    """PolyBody with a forward push ``C t`` (t: seconds since the run's start, as the filters pass it)."""

    name = "knows_the_clock"

    def accel_and_jacobians(self, x6, u, t=0.0):
        f, J_x, J_u = super().accel_and_jacobians(x6, u, t)
        f = f.copy()
        f[..., 0] += C * np.broadcast_to(np.asarray(t, float), f.shape[:-1])
        return f, J_x, J_u


def test_isam2_without_fixes_dead_reckons_a_clock_reading_model_from_the_runs_start():
    # priors and dynamics alone: the most probable trajectory is the model's own from x0, with the
    # model's time counted from the run's start (100 s here). The states iSAM2 adds are initialised
    # by the same step: a guess at another time (e.g. t[k-1] + t[0]: a push 200 s on) would start
    # Gauss-Newton far off (vx by C x 200 s x 0.02 s per step), which one update per 10 steps does not undo
    model = ProcessModel(_KnowsTheClock())
    model.Q_rate_ = np.diag([1e-4, 1e-4, 1e-4, 1e-2, 1e-3, 1e-2])
    t = 100.0 + np.arange(101) * 0.02
    u = np.column_stack([0.3 * np.sin(t - 100.0), 0.2 * np.cos(t - 100.0)])
    x0 = np.array([0.0, 0.0, 0.2, 0.3, 0.0, 0.1])
    P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2
    t_start = time.perf_counter()
    got = smooth_isam2(model, t, u, x0, P0, None)
    elapsed_s = time.perf_counter() - t_start
    assert 0.0 < got.runtime_s <= elapsed_s  # its own computing time, within the call's
    # the reference by hand: RK4 of the same derivative with time from 0 at the run's start
    d = model.dynamics.derivative
    ref = [x0]
    for k in range(len(t) - 1):
        s, h, x = t[k] - t[0], t[k + 1] - t[k], ref[-1]
        k1 = d(x, u[k], s)
        k2 = d(x + 0.5 * h * k1, u[k], s + 0.5 * h)
        k3 = d(x + 0.5 * h * k2, u[k], s + 0.5 * h)
        k4 = d(x + h * k3, u[k], s + h)
        ref.append(x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))
    ref = np.array(ref)
    assert ref[-1, 3] > x0[3] + 0.3  # the push is felt: vx grows by about C s^2 / 2 = 0.8 m/s at 2 s, less the drag
    np.testing.assert_allclose(got.x, ref, atol=1e-7)


def _series(v: np.ndarray, dt: float = 0.1) -> StateSeries:
    x6 = np.zeros((len(v), 6))
    x6[:, 4] = v
    return StateSeries("gm", np.arange(len(v)) * dt, x6, np.zeros((len(v), 2)))


@pytest.mark.parametrize("phi, reverts", [(0.9, True), (0.5, True), (1.0, False), (1.5, False), (-0.5, False)])
def test_mean_reversion_only_for_a_lag_one_ratio_between_zero_and_one(phi, reverts):
    # v_k = phi^k exactly: the lag-one least squares gives phi itself (sum v_k v_k+1 / sum v_k^2);
    # a time constant exists only for 0 < phi < 1 (tau = -dt / ln phi), a growing or flipping
    # series has none
    v = phi ** np.arange(12)
    tau = fit_mean_reversion([_series(v)], 4)
    if reverts:
        assert tau == pytest.approx(-0.1 / np.log(phi), rel=1e-9)
    else:
        assert tau is None
