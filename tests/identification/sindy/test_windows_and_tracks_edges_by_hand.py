"""Edges of the evaluation windows and of the input tracks by hand: a window crossing the run's end
by a nanosecond is left out (make_windows' docstring), a stacked model's dead times (one per model)
each read their own delayed inputs in one rollout, held inputs of a run longer than the padding
beyond its ends (hours), and ``lagged_at`` (one input through a first-order lag) against
``1 - exp(-t / T)`` and, without a lag, against the held samples themselves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.baselines import ConstantVelocityModel
from identification.sindy.evaluate import make_windows, rollout
from identification.sindy.input_track import InputTrack


def _still(t: np.ndarray, u1=None) -> BodyStates:
    z = np.zeros_like(t)
    return BodyStates(t=t, vx=z, vy=z, omega=z, u1=z if u1 is None else u1, u2=z, x=z, y=z, yaw=z)


@pytest.mark.parametrize("short_by, starts", [(0.0, [0.0, 2.5, 5.0]), (1e-9, [0.0, 2.5]), (0.25, [0.0, 2.5])])
def test_a_window_crossing_the_runs_end_is_left_out(short_by, starts):
    # samples every 0.5 s up to 10 s, the last one ``short_by`` early: 5 s windows start every 2.5 s;
    # the one from 5 s ends at 10 s, which crosses the run's end when the run stops a nanosecond
    # short (the round-off tolerance is below that, 1e-9 s exclusive)
    t = np.arange(21) * 0.5
    t[-1] -= short_by
    w = make_windows([_still(t)], window_s=5.0, overlap=0.5, dt=0.5)
    np.testing.assert_array_equal(w.t0, starts)


class _PushedByU1(ConstantVelocityModel):
    """Forward acceleration equal to input 1 as the model sees it (after its dead times): vx is
    the integral of the delayed input; one dead time per stacked model (``(3, 2)``)."""

    name = "pushed_by_u1"
    dead_time_s = np.array([[0.0, 0.0], [0.1, 0.0], [0.4, 0.3]])

    def accel(self, x6, u, t=0.0):
        a = np.zeros(np.broadcast_shapes(np.shape(x6)[:-1], np.shape(u)[:-1]) + (3,))
        a[..., 0] = u[..., 0]
        return a


def test_a_stacked_model_feeds_each_model_its_own_dead_time():
    # u1 = 1 + s (s: seconds since the run's start): with dead time d, vx after tau from a window's
    # start t0 is vx0 + tau (1 - d) + ((t0 + tau)^2 - t0^2) / 2 (RK4 is exact for a force linear
    # in time); inside the run from t0 - d >= 0 on, so the first window is left out of the check
    t = np.arange(601) * 0.02
    w = make_windows([_still(t, 1.0 + t)], window_s=5.0, overlap=0.5)
    model = _PushedByU1()
    pred = rollout(model, w, batch_shape=(3,))
    assert pred.shape == (3, len(w.t0), len(w.t_rel), 6)
    t0, tau = w.t0_run[1:, None], w.t_rel[None, :]
    for b, (d, _) in enumerate(model.dead_time_s):
        want = tau * (1.0 - d) + ((t0 + tau) ** 2 - t0 ** 2) / 2
        np.testing.assert_allclose(pred[b, 1:, :, 3], want, atol=1e-9)


def test_held_inputs_of_a_run_longer_than_the_padding_hold_at_both_ends():
    # three hours of commands (longer than the 1e4 s the held values are padded by): before the first
    # sample the first holds, after the last the last, and in between each sample until the next
    t = np.array([0.0, 1.0, 6000.0, 12000.0])
    u = np.array([[1.0, -1.0], [2.0, -2.0], [3.0, -3.0], [4.0, -4.0]])
    track = InputTrack(t, u, "zoh", 0.2)
    got = track.at(np.array([-5.0, 0.5, 3000.0, 9000.0, 12000.5, 12030.0]))
    np.testing.assert_allclose(got[:, 0], [1.0, 1.0, 2.0, 3.0, 4.0, 4.0], rtol=1e-9)
    np.testing.assert_allclose(got[:, 1], -got[:, 0], rtol=1e-9)
    np.testing.assert_allclose(track.at(np.array([12000.0]))[:, 0], [3.5], rtol=1e-9)  # half 3, half 4


ZOH = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[1.0, 10.0], [3.0, 30.0], [5.0, 50.0]]), "zoh", 0.2)


@pytest.mark.parametrize("i", [0, 1])
def test_lagged_at_without_a_lag_is_the_held_input(i):
    # no lag: the samples held and averaged over 0.2 s, by hand (u2 = 10 u1), up to the last value
    # after the track (not a grid over the track's span held at its end: 4 there, half 3, half 5)
    tq = np.array([0.5, 1.05, 2.0, 10.0])
    got = ZOH.lagged_at(i, (0.0, 0.0), tq, (0.0, 0.0))
    np.testing.assert_allclose(got, (10.0 ** i) * np.array([1.0, 2.5, 4.0, 5.0]), rtol=1e-9)
    # with a dead time per input: u_i(t - d_i), the other's dead time not read
    got = ZOH.lagged_at(i, (0.0, 0.0), np.array([1.5]), (0.5, 0.4))
    np.testing.assert_allclose(got, [[2.0, 30.0][i]], rtol=1e-9)


@pytest.mark.parametrize("lag_s", [0.2, 0.5])
def test_lagged_at_follows_one_minus_exp_after_a_step(lag_s):
    # a step of input 1 from 0 to 1 at 3 s through a lag of T well under a second: 1 - exp(-s / T)
    track = InputTrack(np.array([2.0, 3.0, 8.0]), np.array([[0.0, 0.0], [1.0, 2.0], [1.0, 2.0]]), "zoh", 0.001)
    s = np.array([0.1, 0.4, 1.0])
    got = track.lagged_at(0, (lag_s, 0.0), 3.0 + s, (0.0, 0.0))
    np.testing.assert_allclose(got, 1.0 - np.exp(-s / lag_s), atol=5e-3)
    # the second input without a lag passes unchanged
    np.testing.assert_allclose(track.lagged_at(1, (lag_s, 0.0), 3.0 + s, (0.0, 0.0)), 2.0, atol=1e-9)
    assert math.isclose(float(track.lagged_at(0, (lag_s, 0.0), np.array([2.9]), (0.0, 0.0))[0]), 0.0, abs_tol=1e-9)


def test_the_rate_of_held_inputs_is_zero_long_before_and_after_the_track():
    # the end values hold on both sides: no change, whatever the distance (here beyond the 1e4 s
    # the held values are padded by, where the rate's table ends: its indices stay inside it)
    got = ZOH.rate(np.array([-3e4, -5.0, 10.0, 3e4]))
    np.testing.assert_array_equal(got, np.zeros((4, 2)))
