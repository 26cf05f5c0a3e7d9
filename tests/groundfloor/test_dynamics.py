"""The one dynamics interface: every motion model's six-state Jacobians against central differences
at headings in all four quadrants (where the kinematics' rotation matters), the kinematics against
eq. 5.75 written out, and the values of the Jacobian methods against the plain ones."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.dynamics import Dynamics, rk4_rollout_step
from identification.sindy.baselines import (
    ConstantVelocityModel,
    LagModel,
    UnicycleModel,
)
from identification.sindy.library import make_library
from identification.sindy.active_terms import StackedSindy
from identification.sindy.model import SindyModel, model_from_terms
from simulation.effects import EFFECTS, Effect
from simulation.robot import TrueDynamics
from sindy_ekf.diagnose.extend import ExtendedModel
from tests.support.estimation_helpers import LinearDynamics

HEADINGS = np.array([0.0, 0.7, np.pi / 2, 2.4, np.pi, -2.0, -np.pi / 2, -0.3])
TERMS = {"vx": {"u1": 2.0, "vx": -3.0, "omega vy": 0.4, "u2^2 vx": -0.2, "vx^3": 0.5},
         "vy": {"vy": -5.0, "omega vx": -0.3},
         "omega": {"u2": 1.5, "omega": -2.5, "u2 vx": 0.1, "omega^2 u2": -0.4}}


def _signsq_model() -> SindyModel:
    lib = make_library("poly3_signsq")
    coef = np.random.default_rng(2).normal(size=(3, lib.n_features))
    coef[np.random.default_rng(3).random(coef.shape) < 0.6] = 0.0
    return SindyModel(lib, coef)


def _models() -> list[Dynamics]:
    base = model_from_terms(TERMS)
    rng = np.random.default_rng(4)
    return [
        base,
        _signsq_model(),
        ConstantVelocityModel(),
        UnicycleModel(0.9, 1.3),
        LagModel(1.1, 0.3, 0.8, 0.15),
        TrueDynamics(),
        TrueDynamics(effect=Effect("heading_dependence", EFFECTS["heading_dependence"].moderate)),
        TrueDynamics(effect=Effect("lateral_slip", EFFECTS["lateral_slip"].moderate)),
        ExtendedModel(base, "heading_dependence", [], [0.2, -0.1, 0.05, 0.1]),
        ExtendedModel(base, "position_dependence", [0.5, 0.3, 1.0], [-3.0, -2.5]),
        LinearDynamics(rng.normal(size=(6, 6)), rng.normal(size=(6, 2))),
    ]


def _ids(model) -> str:
    effect = getattr(model, "effect", None)  # test ids only
    return f"{type(model).__name__}:{model.name}" + (f"+{effect.name}" if effect else "")


def _states(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    psi = np.resize(HEADINGS, n)
    x6 = np.column_stack([rng.uniform(-1, 1, (n, 2)), psi, rng.uniform(-0.6, 0.6, (n, 3))])
    return x6, rng.uniform(-0.9, 0.9, (n, 2))


def _central(fun, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    return np.stack([(fun(x + h * e) - fun(x - h * e)) / (2 * h) for e in np.eye(x.shape[-1])], axis=-1)


@pytest.mark.parametrize("model", _models(), ids=_ids)
def test_six_state_jacobians_match_central_differences(model):
    x6, u = _states(16, np.random.default_rng(0))
    t = 1.7
    f, J_x, J_u = model.derivative_and_jacobians(x6, u, t)
    np.testing.assert_allclose(f, model.derivative(x6, u, t), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(J_x, _central(lambda x: model.derivative(x, u, t), x6), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(J_u, _central(lambda v: model.derivative(x6, v, t), u), rtol=1e-6, atol=1e-7)
    f2, J_x2, none = model.derivative_and_jacobians(x6, u, t, input_jacobian=False)
    assert none is None
    np.testing.assert_array_equal(J_x2, J_x)
    assert f.shape == (16, 6) and J_x.shape == (16, 6, 6) and J_u.shape == (16, 6, 2)


@pytest.mark.parametrize("model", [m for m in _models() if not isinstance(m, LinearDynamics)], ids=_ids)
def test_acceleration_jacobians_match_central_differences(model):
    x6, u = _states(16, np.random.default_rng(1))
    a, J_a_x, J_a_u = model.accel_and_jacobians(x6, u, 0.4)
    np.testing.assert_allclose(a, model.accel(x6, u, 0.4), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(J_a_x, _central(lambda x: model.accel(x, u, 0.4), x6), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(J_a_u, _central(lambda v: model.accel(x6, v, 0.4), u), rtol=1e-6, atol=1e-7)


def test_pose_moves_by_eq_5_75_and_the_kinematic_unicycle_by_its_inputs():
    x6, u = _states(8, np.random.default_rng(2))
    psi, vx, vy, om = x6[:, 2], x6[:, 3], x6[:, 4], x6[:, 5]
    f = ConstantVelocityModel().derivative(x6, u)
    np.testing.assert_allclose(f[:, 0], vx * np.cos(psi) - vy * np.sin(psi), atol=1e-15)
    np.testing.assert_allclose(f[:, 1], vx * np.sin(psi) + vy * np.cos(psi), atol=1e-15)
    np.testing.assert_allclose(f[:, 2:], np.column_stack([om, np.zeros((8, 3))]), atol=1e-15)
    uni = UnicycleModel(0.9, 1.3)
    f = uni.derivative(x6, u)
    np.testing.assert_allclose(f[:, 0], 0.9 * u[:, 0] * np.cos(psi), atol=1e-15)
    np.testing.assert_allclose(f[:, 1], 0.9 * u[:, 0] * np.sin(psi), atol=1e-15)
    np.testing.assert_allclose(f[:, 2], 1.3 * u[:, 1], atol=1e-15)
    np.testing.assert_array_equal(f[:, 3:], 0.0)
    # its input Jacobian: the rotation of [k1, 0, k2] (pose rows only)
    _, _, J_u = uni.derivative_and_jacobians(x6, u)
    np.testing.assert_allclose(J_u[:, 0, 0], 0.9 * np.cos(psi), atol=1e-15)
    np.testing.assert_allclose(J_u[:, 1, 0], 0.9 * np.sin(psi), atol=1e-15)
    np.testing.assert_allclose(J_u[:, 2, 1], 1.3, atol=1e-15)


def test_active_terms_equal_the_full_library():
    for model in (model_from_terms(TERMS), _signsq_model()):
        x6, u = _states(20, np.random.default_rng(5))
        a, J_a_x, J_a_u = model.accel_and_jacobians(x6, u)
        f, J_f_x, J_f_u = model.f_and_jacobians(x6[:, 3:], u)
        np.testing.assert_allclose(a, f, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(J_a_x[..., 3:], J_f_x, rtol=1e-12, atol=1e-13)
        np.testing.assert_array_equal(J_a_x[..., :3], 0.0)
        np.testing.assert_allclose(J_a_u, J_f_u, rtol=1e-12, atol=1e-13)
    model = model_from_terms(TERMS)
    before = model.accel_and_jacobians(x6, u)[0]
    model.coef = 2.0 * model.coef  # new coefficients: the active terms are rebuilt
    np.testing.assert_allclose(model.accel_and_jacobians(x6, u)[0], 2.0 * before, rtol=1e-12)


def test_stacked_models_equal_each_model_alone():
    models = [model_from_terms(TERMS), model_from_terms({"vx": {"vx": -1.0, "u1": 0.5}, "omega": {"omega": -2.0}})]
    stack = StackedSindy(models[0].library, np.stack([m.coef for m in models]))
    x6, u = _states(12, np.random.default_rng(6))
    both = stack.derivative_and_jacobians(np.stack([x6, x6]), u)
    for k, m in enumerate(models):
        for got, want in zip(both, m.derivative_and_jacobians(x6, u)):
            np.testing.assert_allclose(got[k], want, rtol=1e-12, atol=1e-13)


def test_rk4_rollout_step_integrates_the_derivative():
    """A step with the input interpolated converges to scipy's integration of the same ODE at 4th order."""
    from scipy.integrate import solve_ivp

    model = TrueDynamics()
    x0 = np.array([1.0, -2.0, 2.5, 0.4, 0.02, 0.3])
    u0, slope = np.array([0.6, 0.2]), np.array([2.0, -6.0])  # input ramp, per second
    errors = []
    for dt in (0.02, 0.01):
        u1 = u0 + slope * dt
        x_rk4 = rk4_rollout_step(model, x0, u0, 0.5 * (u0 + u1), u1, np.float64(3.0), dt)
        ref = solve_ivp(lambda tt, x: model.derivative(x, u0 + slope * tt, 3.0 + tt), (0, dt), x0,
                        method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]
        errors.append(np.abs(x_rk4 - ref).max())
    assert errors[0] < 1e-6 and errors[0] / errors[1] > 20  # local error O(dt^5): ratio 32
