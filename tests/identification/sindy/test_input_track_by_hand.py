"""The inputs a model sees in the windows (evaluate.InputTrack, Windows.inputs_for) by hand:
held samples averaged over the step around the query time, straight lines between samples, their
time derivatives, a dead time per input, and a first-order lag against ``1 - exp(-t / T)``."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.evaluate import make_windows
from identification.sindy.input_track import InputTrack

ZOH = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[1.0, 10.0], [3.0, 30.0], [5.0, 50.0]]), "zoh", 0.2)
LINEAR = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[1.0, 10.0], [3.0, 30.0], [4.0, 20.0]]), "linear")


@pytest.mark.parametrize("t, u1", [(0.5, 1.0), (1.0, 2.0), (1.05, 2.5), (1.95, 3.5), (-5.0, 1.0), (10.0, 5.0)])
def test_held_samples_are_averaged_over_the_step_around_the_query(t, u1):
    # by hand: the mean of the held value over [t - 0.1, t + 0.1]; before the first sample it holds
    np.testing.assert_allclose(ZOH.at(np.array([t])), [[u1, 10.0 * u1]], rtol=1e-9)


@pytest.mark.parametrize("t, du1", [(0.5, 0.0), (1.0, 10.0), (1.05, 10.0), (1.95, 10.0), (-5.0, 0.0)])
def test_rate_of_held_samples_is_the_jump_over_the_step_width(t, du1):
    np.testing.assert_allclose(ZOH.rate(np.array([t])), [[du1, 10.0 * du1]], rtol=1e-9)


def test_each_input_has_its_own_dead_time_and_several_dead_times_stack():
    # u1 at 1.5 - 0.5 = 1.0 (half 1, half 3); u2 at 1.5 - 0.4 = 1.1 (all 30)
    np.testing.assert_allclose(ZOH.at(np.array([1.5]), (0.5, 0.4)), [[2.0, 30.0]], rtol=1e-9)
    both = ZOH.at(np.array([1.5, 0.5]), np.array([[0.5, 0.4], [0.0, 0.0]]))
    np.testing.assert_allclose(both, [[[2.0, 30.0], [1.0, 10.0]], [[3.0, 30.0], [1.0, 10.0]]], rtol=1e-9)


def test_straight_lines_between_samples_and_their_slopes():
    np.testing.assert_allclose(LINEAR.at(np.array([0.5, 1.5, -1.0, 3.0])),
                               [[2.0, 20.0], [3.5, 25.0], [1.0, 10.0], [4.0, 20.0]], rtol=1e-9)
    np.testing.assert_allclose(LINEAR.at(np.array([1.5]), (0.25, 1.0)), [[3.25, 20.0]], rtol=1e-9)
    # slopes: 2 and 20 on (0, 1), 1 and -10 on (1, 2), none outside the samples
    np.testing.assert_allclose(LINEAR.rate(np.array([0.5, 1.5, -1.0, 2.5])),
                               [[2.0, 20.0], [1.0, -10.0], [0.0, 0.0], [0.0, 0.0]], rtol=1e-9)


def test_a_first_order_lag_follows_one_minus_exp_after_a_step():
    # the run's inputs from 2 s on (a track need not start at zero), a step at 3 s
    track = InputTrack(np.array([2.0, 3.0, 8.0]), np.array([[0.0, 0.0], [1.0, 2.0], [1.0, 2.0]]), "zoh", 0.001)
    assert track.lagged((0.0, 0.0)) is track
    lagged = track.lagged((0.2, 0.5))
    for s in (0.1, 0.4, 1.0):
        got = lagged.at(np.array([3.0 + s]))[0]
        np.testing.assert_allclose(got, [1.0 - math.exp(-s / 0.2), 2.0 * (1.0 - math.exp(-s / 0.5))], atol=5e-3)
    np.testing.assert_allclose(lagged.at(np.array([2.9]))[0], [0.0, 0.0], atol=1e-9)  # at rest before the step
    one = track.lagged((0.3, 0.0))  # one lag only: the other input passes unchanged
    np.testing.assert_allclose(one.at(np.array([3.3]))[0], [1.0 - math.exp(-1.0), 2.0], atol=5e-3)


def test_held_samples_are_averaged_over_20_ms_by_default():
    # a switch from 1 to 3 at 1 s; 5 ms after it the 20 ms around the query are a quarter before it
    track = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[1.0, 10.0], [3.0, 30.0], [3.0, 30.0]]), "zoh")
    np.testing.assert_allclose(track.at(np.array([1.005])), [[2.5, 25.0]], rtol=1e-9)
    np.testing.assert_allclose(track.rate(np.array([1.005])), [[100.0, 1000.0]], rtol=1e-9)  # the jump / 20 ms


def test_a_track_of_two_samples_is_lagged_as_well():
    # two samples joined by a straight line: a ramp from rest, whose lag is t - T (1 - exp(-t / T))
    # (the lag's grid is exact for inputs linear between its points)
    ramp = InputTrack(np.array([0.0, 1.0]), np.array([[0.0, 0.0], [1.0, 2.0]]), "linear")
    lagged = ramp.lagged((0.2, 0.5))
    for s in (0.5, 1.0):
        np.testing.assert_allclose(lagged.at(np.array([s]))[0],
                                   [s - 0.2 * (1 - math.exp(-s / 0.2)), 2 * (s - 0.5 * (1 - math.exp(-s / 0.5)))],
                                   atol=1e-9)
    one = InputTrack(np.array([0.0]), np.array([[1.0, 2.0]]), "linear")  # one sample: nothing to lag
    assert one.lagged((0.2, 0.5)) is one


def test_windows_give_each_model_its_delayed_inputs_and_their_rates():
    t = 100.0 + np.arange(601) * 0.02  # 12 s; inputs linear in the time since the start
    s = t - 100.0
    z = np.zeros_like(t)
    st = BodyStates(t=t, vx=z, vy=z, omega=z, u1=3.0 + s, u2=2.0 * s, x=z, y=z, yaw=z)
    w = make_windows([st])
    tq = w.t0_run[:, None] + w.t_half[None, :]
    np.testing.assert_allclose(w.t_half[:3], [0.0, 0.01, 0.02], atol=1e-15)
    got = w.inputs_for((0.1, 0.2))
    # by hand where the delayed time is inside the run (the first window's first 0.2 s is not)
    inside = tq >= 0.2
    np.testing.assert_allclose(got[..., 0][inside], (3.0 + tq - 0.1)[inside], atol=1e-9)
    np.testing.assert_allclose(got[..., 1][inside], (2.0 * (tq - 0.2))[inside], atol=1e-9)
    rate = w.inputs_for((0.1, 0.2), rate=True)
    np.testing.assert_allclose(rate[..., 0][inside & (tq < 11.9)], 1.0, atol=1e-9)
    np.testing.assert_allclose(rate[..., 1][inside & (tq < 11.9)], 2.0, atol=1e-9)
    still = w.inputs_for((0.0, 0.0), rate=True)  # no dead time: the rates all the same
    np.testing.assert_allclose(still[..., 0][tq < 11.9], 1.0, atol=1e-9)
    stacked = w.inputs_for(np.array([[0.0, 0.0], [0.1, 0.2]]))
    np.testing.assert_allclose(stacked[1], got, atol=1e-12)
    np.testing.assert_allclose(stacked[0], w.u_half, atol=1e-12)
    assert w.inputs_for(np.zeros((3, 2))).shape == (3,) + w.u_half.shape
    # by default no dead time (and no lag): the recorded inputs and their slopes 1 and 2 as they are
    assert w.inputs_for() is w.u_half
    np.testing.assert_allclose(w.u_half[..., 0], 3.0 + tq, atol=1e-9)
    default_rate = w.inputs_for(rate=True)
    np.testing.assert_allclose(default_rate[..., 0][tq < 11.9], 1.0, atol=1e-9)
    np.testing.assert_allclose(default_rate[..., 1][tq < 11.9], 2.0, atol=1e-9)
    np.testing.assert_allclose(default_rate[..., 0][tq < 0.05], 1.0, atol=1e-9)  # from the run's start on


def test_windows_hold_recorded_inputs_from_their_own_stamps():
    from groundfloor.types import InputSeries

    t = 100.0 + np.arange(301) * 0.02  # 6 s of states, one 5 s window
    z = np.zeros_like(t)
    st = BodyStates(t=t, vx=z, vy=z, omega=z, u1=z, u2=z, x=z, y=z, yaw=z)
    # commands at 10 Hz, stamped 0.05 s off the states': u1 = 0.1 k at 100.05 + 0.1 k (held)
    t_cmd = 100.05 + np.arange(60) * 0.1
    cmd = InputSeries(t=t_cmd, u1=0.1 * np.arange(60), u2=-0.2 * np.arange(60))
    w = make_windows([st], inputs=[cmd])
    assert w.n_windows == 1 and w.t0_run[0] == 0.0
    # by hand at t = 100.5 s (half-step 50): the command of 100.45 s (k = 4), 0.05 s from a change
    np.testing.assert_allclose(w.u_half[0, 50], [0.4, -0.8], atol=1e-9)
    # before the first command the first one holds; at 100.25 s (a command's stamp) the average over
    # [100.24, 100.26] is half k = 1, half k = 2
    np.testing.assert_allclose(w.u_half[0, 0], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(w.u_half[0, 25], [0.15, -0.3], atol=1e-9)
