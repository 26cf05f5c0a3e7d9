"""Prediction windows (thesis 5.3.8) and the thesis's two-step integration (eqs. 5.72 to 5.74)
against hand computations: window starts and grids of a run whose signals are linear in time
(so interpolation is exact), and a linear velocity decay integrated step by step here."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.evaluate import make_windows, rollout

T_START = 100.0  # not zero: window starts are sample times, t0_run seconds since the run start


def _linear_run(duration_s: float = 20.0) -> BodyStates:
    t = T_START + np.arange(int(round(duration_s / 0.02)) + 1) * 0.02
    s = t - T_START
    return BodyStates(t=t, vx=0.5 + 0.01 * s, vy=0.02 * s, omega=0.1 - 0.003 * s, u1=0.3 + 0.01 * s,
                      u2=-0.2 + 0.02 * s, x=1.0 + 0.5 * s, y=-2.0 + 0.1 * s, yaw=0.2 + 0.05 * s)


def test_windows_start_every_half_window_and_sample_the_run_on_their_grids():
    run = _linear_run()
    w = make_windows([run], window_s=5.0, overlap=0.5, dt=0.02)
    np.testing.assert_allclose(w.t_rel, np.arange(251) * 0.02, atol=1e-12)  # 0, dt, ..., 5 s
    starts = np.array([0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0])  # the last one ends at the run's end
    np.testing.assert_allclose(w.t0, T_START + starts, atol=1e-9)
    np.testing.assert_allclose(w.t0_run, starts, atol=1e-9)
    np.testing.assert_array_equal(w.run, np.zeros(7, int))
    np.testing.assert_allclose(w.x0, np.column_stack([1.0 + 0.5 * starts, -2.0 + 0.1 * starts, 0.2 + 0.05 * starts,
                                                      0.5 + 0.01 * starts, 0.02 * starts, 0.1 - 0.003 * starts]),
                               atol=1e-12)
    # inputs at the grid and its midpoints, poses at the grid (linear signals: interpolation is exact)
    s_half = starts[:, None] + np.arange(501)[None, :] * 0.01
    np.testing.assert_allclose(w.u_half[..., 0], 0.3 + 0.01 * s_half, atol=1e-12)
    np.testing.assert_allclose(w.u_half[..., 1], -0.2 + 0.02 * s_half, atol=1e-12)
    s_grid = starts[:, None] + w.t_rel[None, :]
    np.testing.assert_allclose(w.pose_truth[..., 0], 1.0 + 0.5 * s_grid, atol=1e-12)
    np.testing.assert_allclose(w.pose_truth[..., 2], 0.2 + 0.05 * s_grid, atol=1e-12)


@pytest.mark.parametrize("base", [0.0, 100.0, 1671615000.0, 1722278751.228780031])
def test_the_windows_do_not_depend_on_the_time_base(base):
    # the same 20 s run stamped from 0, 100 s or UTC: by hand seven windows, the last ending on the
    # run's last sample (UTC stamps resolve 2.4e-7 s, coarser than the selection's 1e-9 s tolerance)
    run = _linear_run()
    moved = BodyStates(**{**run.__dict__, "t": base + (run.t - T_START)})
    w = make_windows([moved], window_s=5.0, overlap=0.5, dt=0.02)
    np.testing.assert_allclose(w.t0_run, [0.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0], atol=1e-6)


def test_windows_without_overlap_and_with_another_step():
    w = make_windows([_linear_run()], window_s=5.0, overlap=0.0, dt=0.04)
    np.testing.assert_allclose(w.t0_run, [0.0, 5.0, 10.0, 15.0], atol=1e-9)
    np.testing.assert_allclose(w.t_rel, np.arange(126) * 0.04, atol=1e-12)
    w = make_windows([_linear_run(9.0)], window_s=4.0, overlap=0.75, dt=0.02)
    np.testing.assert_allclose(w.t0_run, np.arange(0.0, 5.0 + 1e-9, 1.0), atol=1e-9)


class Decay(Dynamics):
    """Body velocities decaying at the rates ``A``: ``v_dot = -A v`` (inputs unused)."""

    A = np.array([1.0, 3.0, 2.0])

    def accel_and_jacobians(self, x6, u, t=0.0):
        raise NotImplementedError  # the rollout needs the accelerations only

    def accel(self, x6, u, t=0.0):
        return -self.A * np.asarray(x6)[..., 3:]


def test_two_step_method_is_rk4_on_the_velocities_then_euler_on_the_pose():
    w = make_windows([_linear_run(12.0)], window_s=5.0, overlap=0.5, dt=0.02)
    pred = rollout(Decay(), w, method="euler2")
    h = 0.02
    z = h * Decay.A
    g = 1 - z + z ** 2 / 2 - z ** 3 / 6 + z ** 4 / 24  # RK4 of v_dot = -a v, one step
    for k in range(w.n_windows):
        s = w.x0[k].copy()
        for i in range(len(w.t_rel) - 1):
            np.testing.assert_allclose(pred[k, i], s, atol=1e-12)
            c, sn = np.cos(s[2]), np.sin(s[2])
            vx, vy, om = s[3:]
            pose = s[:3] + h * np.array([vx * c - vy * sn, vx * sn + vy * c, om])  # the step's start velocities
            s = np.concatenate([pose, s[3:] * g])
        np.testing.assert_allclose(pred[k, -1], s, atol=1e-12)


def test_overlap_must_be_below_one_and_two_samples_spanning_a_window_make_one():
    for overlap in (1.0, 1.5, -0.1):
        with pytest.raises(InputError, match="overlap"):
            make_windows([_linear_run()], window_s=5.0, overlap=overlap)
    t = np.array([T_START, T_START + 5.0])
    two = BodyStates(t=t, vx=np.ones(2), vy=np.zeros(2), omega=np.zeros(2), u1=np.ones(2), u2=np.zeros(2),
                     x=np.array([0.0, 5.0]), y=np.zeros(2), yaw=np.zeros(2))
    w = make_windows([two], window_s=5.0, overlap=0.5, dt=0.02)
    np.testing.assert_allclose(w.t0_run, [0.0])
    np.testing.assert_allclose(w.pose_truth[0, :, 0], w.t_rel, atol=1e-12)  # x = t between the two samples
