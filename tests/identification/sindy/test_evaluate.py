"""Multi-step evaluation (thesis 5.3.7, 5.3.8): batched RK4 against one solve_ivp per window,
truth dynamics predicting their own data, RK4 against the thesis's Euler two-step, window
counts, kinematic and constant-velocity baselines, and bad inputs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel
from identification.sindy.evaluate import (
    evaluate_model,
    evaluate_reference,
    make_windows,
)
from identification.sindy.model import EnvelopeWarning, model_from_terms
from tests.support.sindy_synth import SPARSE_TERMS, simulate_states, sparse_f


@pytest.fixture(scope="module")
def clean_runs():
    """Two noise-free 30 s runs of the known sparse model."""
    return simulate_states(30.0, [41, 42], noise_std=0.0)


def test_batched_rk4_equals_one_solve_ivp_per_window_to_1mm(clean_runs):
    model = model_from_terms(SPARSE_TERMS)
    st = clean_runs[0]
    part = [BodyStates(**{f.name: getattr(st, f.name)[:751] for f in dataclasses.fields(st)})]  # 15 s
    fast = evaluate_model(model, part)
    ref = evaluate_reference(model, part)
    assert fast.n_windows == ref.n_windows == 5
    np.testing.assert_allclose(fast.eps_p, ref.eps_p, atol=1e-3)
    np.testing.assert_allclose(fast.eps_h, ref.eps_h, atol=1e-4)


def test_true_dynamics_predict_their_own_trajectory_and_rk4_beats_euler(clean_runs):
    model = model_from_terms(SPARSE_TERMS)
    rk4 = evaluate_model(model, clean_runs, method="rk4")
    euler = evaluate_model(model, clean_runs, method="euler2")
    assert rk4.pos_err_5s_m < 2e-4 and rk4.yaw_err_5s_deg < 0.01  # only input-interpolation error is left
    assert euler.pos_err_5s_m > 5 * rk4.pos_err_5s_m
    assert rk4.s_p[0] == 0 and euler.s_p[0] == 0  # both start at the data
    assert rk4.summary()["n_windows"] == 22


class SparseDynamics(Dynamics):
    """The known sparse model written directly on the six states (as the simulator's oracle is)."""

    def accel_and_jacobians(self, x6, u, t=0.0):
        raise NotImplementedError  # the evaluation needs the accelerations only

    def accel(self, x6, u, t=0.0):
        return sparse_f(x6[..., 3:], u)


def test_dynamics_on_six_states_give_the_same_prediction(clean_runs):
    direct = evaluate_model(model_from_terms(SPARSE_TERMS), clean_runs)
    six = evaluate_model(SparseDynamics(), clean_runs)
    np.testing.assert_allclose(six.eps_p, direct.eps_p, atol=1e-12)


def test_windows_overlap_by_half_and_start_at_samples(clean_runs):
    w = make_windows(clean_runs, window_s=5.0, overlap=0.5)
    t0 = w.t0[w.run == 0]
    np.testing.assert_allclose(np.diff(t0), 2.5, atol=0.011)
    assert np.all(np.isin(t0, clean_runs[0].t))
    np.testing.assert_allclose(w.x0[0], [clean_runs[0].x[0], clean_runs[0].y[0], clean_runs[0].yaw[0],
                                         clean_runs[0].vx[0], clean_runs[0].vy[0], clean_runs[0].omega[0]])


def _kinematic_run(k1: float, k2: float, seed: int) -> BodyStates:
    """A run whose velocities are exactly ``[k1 u1, 0, k2 u2]`` with the pose integrated finely."""
    from tests.support.sindy_synth import smooth_inputs

    t_fine = np.arange(0, 30, 0.001)
    u = smooth_inputs(30.0, np.random.default_rng(seed))(t_fine)
    yaw = np.concatenate([[0], np.cumsum(0.5 * (u[1:, 1] + u[:-1, 1]) * k2 * 0.001)])
    vx_l, vy_l = k1 * u[:, 0] * np.cos(yaw), k1 * u[:, 0] * np.sin(yaw)
    x = np.concatenate([[0], np.cumsum(0.5 * (vx_l[1:] + vx_l[:-1]) * 0.001)])
    y = np.concatenate([[0], np.cumsum(0.5 * (vy_l[1:] + vy_l[:-1]) * 0.001)])
    i = np.arange(0, len(t_fine), 20)
    return BodyStates(t=t_fine[i], vx=k1 * u[i, 0], vy=0 * u[i, 0], omega=k2 * u[i, 1], u1=u[i, 0], u2=u[i, 1],
                      x=x[i], y=y[i], yaw=yaw[i])


def test_unicycle_gains_fitted_and_its_kinematics_exact():
    run = _kinematic_run(0.9, 1.3, seed=5)
    uni = UnicycleModel().fit([run])
    assert uni.k1_ == pytest.approx(0.9, rel=1e-9) and uni.k2_ == pytest.approx(1.3, rel=1e-9)
    res = evaluate_model(uni, [run])
    assert res.pos_err_5s_m < 1e-3 and res.yaw_err_5s_deg < 0.02


def test_constant_velocity_model_is_exact_on_a_circle():
    t = np.arange(0, 20, 0.02)
    r, om = 2.0, 0.4
    run = BodyStates(t=t, vx=np.full_like(t, r * om), vy=0 * t, omega=np.full_like(t, om), u1=np.sin(t),
                     u2=np.cos(t), x=r * np.sin(om * t), y=r - r * np.cos(om * t), yaw=om * t)
    res = evaluate_model(ConstantVelocityModel(), [run])
    assert res.pos_err_5s_m < 1e-6 and res.n_windows == 6  # starts 0, 2.5, ..., 12.5 s; data end at 19.98 s


def test_runs_shorter_than_a_window_are_named(clean_runs):
    st = clean_runs[0]
    short = BodyStates(**{f.name: getattr(st, f.name)[:100] for f in dataclasses.fields(st)})
    with pytest.raises(InputError, match="runs run_07: none is longer than one 5 s window"):
        make_windows([short], names=["run_07"])


def test_evaluation_warns_when_test_data_leave_the_training_envelope(clean_runs):
    model = model_from_terms(SPARSE_TERMS)
    model.envelope = {"vx": [-0.1, 0.1], "vy": [-1, 1], "omega": [-5, 5], "u1": [-1, 1], "u2": [-1, 1]}
    with pytest.warns(EnvelopeWarning, match="test runs: .* vx"):
        evaluate_model(model, clean_runs)


def test_diverging_model_scores_infinite_not_nan(clean_runs):
    unstable = model_from_terms({"vx": {"vx^3": 50.0}, "omega": {"omega": 40.0}})
    res = evaluate_model(unstable, clean_runs)
    assert res.pos_err_5s_m == np.inf


def test_windows_keep_a_short_hole_of_10_hz_data_and_drop_a_long_one():
    """10 Hz stamps: a 0.6 s hole is below gap_threshold_s (1 s) and is bridged, a 1.5 s hole is not."""
    t = np.arange(0, 30, 0.1)
    t = t[(t < 6.0) | (t > 6.55)]  # 0.6 s hole
    t = t[(t < 20.0) | (t > 21.45)]  # 1.5 s hole
    n = len(t)
    st = BodyStates(t=t, vx=np.ones(n), vy=np.zeros(n), omega=np.zeros(n), u1=np.zeros(n), u2=np.zeros(n),
                    x=t, y=np.zeros(n), yaw=np.zeros(n))
    w = make_windows([st])
    t0 = w.t0
    assert np.any((t0 < 6.0) & (t0 + 5 > 6.6))  # a window across the short hole
    assert not np.any((t0 < 20.0) & (t0 + 5 > 21.4))  # none across the long one
    w_old = make_windows([st], max_gap_s=0.5)
    assert not np.any((w_old.t0 < 6.0) & (w_old.t0 + 5 > 6.6))
