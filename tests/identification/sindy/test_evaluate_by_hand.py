"""The 5 s evaluation against errors computed by hand (issue 14, item 5): a robot whose speed
grows as ``c t^2 / 2`` predicted by constant velocity is off by ``c tau^2 (3 t0 + tau) / 6`` after
``tau`` in the window starting at ``t0``; different in every window, so an RMS over windows is
told from a mean of absolute errors or a single window."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.baselines import ConstantVelocityModel
from identification.sindy.evaluate import evaluate_model

DT, DURATION, C = 0.02, 20.0, 0.01  # s, s, m/s^3
WINDOW, STEP = 5.0, 2.5  # 5 s windows, 50 % overlap: starts 0, 2.5, ..., 15 s


def _states(t, x, y, yaw, vx, omega):
    zeros = np.zeros_like(t)
    return BodyStates(t=t, vx=vx, vy=zeros, omega=omega, u1=zeros, u2=zeros, x=x, y=y, yaw=yaw)


def _starts():
    return [k * STEP for k in range(int((DURATION - WINDOW) / STEP) + 1)]


def test_position_error_of_an_accelerating_robot_equals_the_hand_computation():
    t = np.arange(int(round(DURATION / DT)) + 1) * DT + 100.0
    s = t - t[0]
    heading = 0.7  # driving straight along this heading
    dist, speed = C * s ** 3 / 6, C * s ** 2 / 2
    st = _states(t, 1.0 + dist * math.cos(heading), -2.0 + dist * math.sin(heading), np.full_like(t, heading),
                 speed, np.zeros_like(t))
    res = evaluate_model(ConstantVelocityModel(), [st])
    errors = [C * WINDOW ** 2 * (3 * t0 + WINDOW) / 6 for t0 in _starts()]
    assert res.n_windows == len(errors) == 7
    np.testing.assert_allclose(np.diff(res.t_rel), 0.02, rtol=1e-9)  # 50 Hz steps (thesis 5.3.8)
    assert res.t_rel[-1] == pytest.approx(WINDOW)
    rms = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert res.pos_err_5s_m == pytest.approx(rms, rel=1e-6)
    assert res.pos_err_5s_m != pytest.approx(sum(errors) / len(errors), rel=1e-3)  # not a mean
    assert res.yaw_err_5s_deg == pytest.approx(0.0, abs=1e-9)
    # and half-way through the windows (tau = 2.5 s)
    half = [C * 2.5 ** 2 * (3 * t0 + 2.5) / 6 for t0 in _starts()]
    k = int(round(2.5 / DT))
    assert res.s_p[k] == pytest.approx(math.sqrt(sum(e * e for e in half) / len(half)), rel=1e-6)
    np.testing.assert_allclose(res.eps_p[:, -1], errors, rtol=1e-6)


def test_heading_error_of_a_spinning_robot_equals_the_hand_computation():
    t = np.arange(int(round(DURATION / DT)) + 1) * DT
    k_rad = 0.002  # rad/s^3: yaw = k t^3 / 6, omega = k t^2 / 2, standing on the spot
    st = _states(t, np.zeros_like(t), np.zeros_like(t), k_rad * t ** 3 / 6, np.zeros_like(t), k_rad * t ** 2 / 2)
    res = evaluate_model(ConstantVelocityModel(), [st])
    errors = [k_rad * WINDOW ** 2 * (3 * t0 + WINDOW) / 6 for t0 in _starts()]
    rms_deg = math.degrees(math.sqrt(sum(e * e for e in errors) / len(errors)))
    assert res.yaw_err_5s_deg == pytest.approx(rms_deg, rel=1e-6)
    assert res.pos_err_5s_m == pytest.approx(0.0, abs=1e-12)
    assert res.summary() == {"pos_err_5s_m": res.pos_err_5s_m, "yaw_err_5s_deg": res.yaw_err_5s_deg,
                             "n_windows": 7}


class _KnowsTheClock(ConstantVelocityModel):
    """Forward acceleration ``C t`` with ``t`` the seconds since the start of the window's run:
    exactly the accelerating robot's, so its predictions are exact if evaluate passes that time."""

    def accel(self, x6, u, t=0.0):
        a = np.zeros(np.shape(x6)[:-1] + (3,))
        a[..., 0] = C * np.broadcast_to(t, a.shape[:-1])
        return a


def test_time_passed_to_the_model_is_seconds_since_the_start_of_the_run():
    t = np.arange(int(round(DURATION / DT)) + 1) * DT + 100.0  # the run starts at 100 s
    s = t - t[0]
    st = _states(t, C * s ** 3 / 6, np.zeros_like(t), np.zeros_like(t), C * s ** 2 / 2, np.zeros_like(t))
    res = evaluate_model(_KnowsTheClock(), [st])
    assert res.n_windows == 7
    assert res.pos_err_5s_m < 1e-9  # RK4 is exact for a force linear in time


def test_heading_error_is_wrapped_to_minus_pi_pi_and_a_diverged_prediction_is_infinite():
    from identification.sindy.evaluate import (
        Windows,
        errors_from_rollout,
        rms_over_windows,
    )

    truth = np.zeros((2, 3, 3))
    truth[0, :, 2] = [0.0, 1.0, -3.0]
    windows = Windows(run=np.zeros(2, int), t0=np.zeros(2), x0=np.zeros((2, 6)), t_rel=np.array([0.0, 0.02, 0.04]),
                      u_half=np.zeros((2, 5, 2)), pose_truth=truth)
    pred = np.zeros((2, 3, 6))
    pred[0, :, 0] = [0.0, 3.0, -1.0]
    pred[0, :, 1] = [0.0, 4.0, 1.0]
    pred[0, :, 2] = [0.1 + 2 * np.pi, 1.0 + 3.5, -3.0 - 3.5]  # by hand: 0.1, 3.5 - 2 pi, 2 pi - 3.5
    pred[1, 2, :] = np.nan
    eps_p, eps_h = errors_from_rollout(pred, windows)
    np.testing.assert_allclose(eps_p[0], [0.0, 5.0, math.sqrt(2.0)], atol=1e-12)
    np.testing.assert_allclose(eps_h[0], [0.1, 3.5 - 2 * np.pi, 2 * np.pi - 3.5], atol=1e-12)
    assert np.isinf(eps_p[1, 2]) and np.isinf(eps_h[1, 2])
    np.testing.assert_allclose(rms_over_windows(eps_p[:, :2]), [0.0, math.sqrt(25.0 / 2)], atol=1e-12)


class _NoInputLagAttribute:
    """A model that is no :class:`Dynamics` and has no ``input_lag_s`` (only ``dead_time_s``): it
    sees the recorded inputs as they are. ``x' = vx``, ``vx' = u1``, ``psi' = omega``, ``omega' = u2``."""

    name = "no_input_lag_attribute"
    dead_time_s = (0.0, 0.0)

    def derivative(self, x6, u, t=0.0):
        f = np.zeros(np.broadcast_shapes(np.shape(x6), np.shape(u)[:-1] + (6,)))
        f[..., 0] = x6[..., 3]
        f[..., 2] = x6[..., 5]
        f[..., 3] = u[..., 0]
        f[..., 5] = u[..., 1]
        return f


def test_a_model_without_an_input_lag_attribute_sees_the_recorded_inputs():
    from identification.sindy.evaluate import (
        errors_from_rollout,
        evaluate_reference,
        make_windows,
        rollout,
    )

    # u1 = C s, so vx = C s^2 / 2 and x = C s^3 / 6 (u2, omega and psi the same with -2 C): exact for
    # RK4 with the inputs interpolated linearly; a lag T of u1 leaves vx behind by C T (1 - exp(-s / T))
    # (0.12 m at a window's end for 1 s)
    t = np.arange(int(round(DURATION / DT)) + 1) * DT + 100.0
    s = t - t[0]
    zeros = np.zeros_like(t)
    st = BodyStates(t=t, vx=C * s ** 2 / 2, vy=zeros, omega=-C * s ** 2, u1=C * s, u2=-2 * C * s,
                    x=C * s ** 3 / 6, y=zeros, yaw=-C * s ** 3 / 3)
    windows = make_windows([st])
    eps_p, eps_h = errors_from_rollout(rollout(_NoInputLagAttribute(), windows), windows)
    assert eps_p.max() < 1e-9 and np.abs(eps_h).max() < 1e-9
    ref = evaluate_reference(_NoInputLagAttribute(), [st])
    assert ref.eps_p.max() < 1e-6 and np.abs(ref.eps_h).max() < 1e-6


class _Damped(_NoInputLagAttribute):
    """``vx' = u1 - vx``: not a polynomial in time, so RK45's step control (its tolerances) shows."""

    def derivative(self, x6, u, t=0.0):
        f = super().derivative(x6, u, t)
        f[..., 3] -= x6[..., 3]
        return f


def test_the_reference_is_scipys_rk45_per_window_at_rtol_1e_8_atol_1e_10():
    # a second implementation: scipy's RK45 over the one window of a 5 s run, the inputs joined by
    # straight lines (np.interp), at the reference's documented tolerances
    from scipy.integrate import solve_ivp

    from identification.sindy.evaluate import evaluate_reference

    t = np.arange(251) * DT
    zeros = np.zeros_like(t)
    u1 = np.sin(3.0 * t)
    st = BodyStates(t=t, vx=zeros, vy=zeros, omega=zeros, u1=u1, u2=zeros, x=zeros, y=zeros, yaw=zeros)
    ref = evaluate_reference(_Damped(), [st])
    assert ref.eps_p.shape == (1, 251)
    model = _Damped()
    sol = solve_ivp(lambda tt, s: model.derivative(s, np.array([np.interp(tt, t, u1), 0.0]), tt), (0.0, 5.0),
                    np.zeros(6), t_eval=t, rtol=1e-8, atol=1e-10, method="RK45")
    np.testing.assert_allclose(ref.eps_p[0], np.abs(sol.y[0]), rtol=1e-12, atol=1e-15)


def test_the_two_step_method_evaluates_the_velocities_at_rk4_stage_times():
    # euler2 (eqs. 5.72 to 5.74): the velocities by RK4 with the model's time at t, t + dt/2 (twice)
    # and t + dt, exact for a force linear in time: vx = C s^2 / 2 at every step of every window
    from identification.sindy.evaluate import make_windows, rollout

    t = np.arange(int(round(DURATION / DT)) + 1) * DT + 100.0
    s = t - t[0]
    st = _states(t, C * s ** 3 / 6, np.zeros_like(t), np.zeros_like(t), C * s ** 2 / 2, np.zeros_like(t))
    windows = make_windows([st])
    pred = rollout(_KnowsTheClock(), windows, "euler2")
    s_at = windows.t0_run[:, None] + windows.t_rel[None, :]
    np.testing.assert_allclose(pred[..., 3], C * s_at ** 2 / 2, rtol=0, atol=1e-12)
    # a batch of models (here two copies): each predicts what it predicts alone
    batch = rollout(_KnowsTheClock(), windows, "euler2", batch_shape=(2,))
    assert batch.shape == (2,) + pred.shape
    np.testing.assert_allclose(batch, np.broadcast_to(pred, batch.shape), rtol=0, atol=1e-15)


def test_a_result_is_named_after_its_model_unless_named():
    t = np.arange(int(round(DURATION / DT)) + 1) * DT
    st = _states(t, 0.5 * t, np.zeros_like(t), np.zeros_like(t), np.full_like(t, 0.5), np.zeros_like(t))
    assert evaluate_model(ConstantVelocityModel(), [st]).name == ConstantVelocityModel().name
    assert evaluate_model(ConstantVelocityModel(), [st], name="cv on the test runs").name == "cv on the test runs"
