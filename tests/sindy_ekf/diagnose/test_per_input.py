"""Delay, lag and deadband per input, the smooth deadband and the one-axis delays (issue 15, item 1).

References independent of the code under test: transforms written out by hand or integrated by an ODE
solver; the parabola's vertex by hand; and simulated campaigns whose recorded inputs were rewritten
here, input by input, so that the real (simulated) motion looks as if each motor saw its command late
or through a deadband of its own (the ``inject`` construction, per input: the truth is known per input).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose import diagnose_states
from sindy_ekf.diagnose.families import MECHANISMS, PER_INPUT, mechanism_spec
from sindy_ekf.diagnose.per_input import per_input_form, resolved_difference
from tests.support.diagnose_synth import fit_reference_with_lateral_law

RUN_S, RATE_HZ = 60.0, 25.0


def test_per_input_delay_and_deadband_by_hand():
    t = np.arange(6) * 0.1
    u = np.column_stack([np.linspace(0, 0.5, 6), np.linspace(0.5, 0, 6)])
    delay = PER_INPUT[("input_delay", "")].motor_inputs(t, u, [slice(None)], np.array([[0.0, 0.2]]))[0]
    np.testing.assert_allclose(delay[:, 0], u[:, 0])  # u1 not delayed
    np.testing.assert_allclose(delay[:, 1], [0.5, 0.5, 0.5, 0.4, 0.3, 0.2])  # u2 two samples late, first held
    db = PER_INPUT[("deadband", "")].motor_inputs(t, np.array([[0.05, 0.05], [0.3, -0.3]]), [slice(None)],
                                                  np.array([[0.1, 0.0]]))[0]
    np.testing.assert_allclose(db, [[0.0, 0.05], [0.2 / 0.9, -0.3]])
    one = mechanism_spec("input_delay", "transport_u2").motor_inputs(t, u, [slice(None)], np.array([[0.2]]))[0]
    np.testing.assert_allclose(one, delay)  # the one-axis form: the same as the per-input one at (0, d)


def test_smooth_deadband_by_hand():
    """Quadratic onset below twice the threshold, the hard deadband's line above, continuous in value
    and slope at 2v, and the input itself without a deadband."""
    v = 0.1
    u = np.array([[0.0, 0.1], [0.2, -0.3], [-0.15, 1.0]])
    got = mechanism_spec("deadband", "smooth").motor_inputs(None, u, None, np.array([[v], [0.0]]))
    want = np.array([[0.0, 0.01 / 0.4], [0.04 / 0.4, -0.2], [-0.0225 / 0.4, 0.9]]) / 0.9
    np.testing.assert_allclose(got[0], want)
    np.testing.assert_allclose(got[1], u)
    a = np.array([[2 * v - 1e-7, 0.0], [2 * v + 1e-7, 0.0]])
    vals = mechanism_spec("deadband", "smooth").motor_inputs(None, a, None, np.array([[v]]))[0, :, 0]
    assert abs(vals[1] - vals[0]) < 1e-6  # no jump at 2v


def test_per_input_lag_against_an_ode_solver():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.05, 0.15, 100))
    t -= t[0]
    u = rng.uniform(-1, 1, (100, 2))
    got = PER_INPUT[("input_delay", "first_order_lag")].motor_inputs(t, u, [slice(None)], np.array([[0.0, 0.25]]))[0]
    np.testing.assert_array_equal(got[:, 0], u[:, 0])  # no lag on u1: the input itself
    sol = solve_ivp(lambda s, y: (np.interp(s, t, u[:, 1]) - y) / 0.25, (t[0], t[-1]), [u[0, 1]], t_eval=t,
                    rtol=1e-10, atol=1e-12, max_step=0.01)
    np.testing.assert_allclose(got[:, 1], sol.y[0], atol=1e-6)


def test_a_difference_is_resolved_by_the_runs_and_by_the_grid_by_hand():
    assert resolved_difference([0.0, 0.175], [0.0, 0.0096], 0.04)  # 0.175 > 2 x 0.0096 and > 0.04
    assert not resolved_difference([0.137, 0.125], [0.002, 0.003], 0.04)  # 0.012 > 2 x 0.0036, < one step
    assert not resolved_difference([0.10, 0.20], [0.03, 0.04], 0.04)  # 0.10 < 2 x 0.05
    assert not resolved_difference([0.0, 0.2], [np.nan, 0.01], 0.04)  # one train run: no uncertainty


def test_every_one_axis_and_pooled_form_has_its_per_input_form():
    assert [s.mechanism for s in MECHANISMS["input_delay"]] == ["", "first_order_lag", "transport_u1", "transport_u2"]
    for family in ("input_delay", "deadband"):
        for spec in MECHANISMS[family]:
            per = per_input_form(spec)
            assert per is not None and per.per_input and len(per.theta_names) == 2
            assert per.extra["of"] == spec.extra.get("of", spec.mechanism)
    assert per_input_form(mechanism_spec("asymmetry")) is None


@pytest.fixture(scope="module")
def lab():
    """The lab's model (effect-free campaign, lateral law) and an effect-free campaign of other seeds."""
    model = fit_reference_with_lateral_law(n_runs=4, run_s=RUN_S, rate_hz=RATE_HZ)
    return model, simulate_states_campaign(777, None, n_train=4, n_test=2, run_s=RUN_S, rate_hz=RATE_HZ)


def _delayed(states, delay_s):
    """Return ``states`` with each input recorded ``delay_s[j]`` earlier than the motion answers it."""
    out = []
    for s in states:
        t = s.t - s.t[0]
        u = [np.interp(t + d, t, x) for d, x in zip(delay_s, (s.u1, s.u2))]
        out.append(dataclasses.replace(s, u1=u[0], u2=u[1]))
    return out


def _inverse_deadband(states, threshold):
    """Return ``states`` with the recorded inputs mapped so that a deadband ``threshold[j]`` gives them back."""
    out = []
    for s in states:
        u = [np.where(x != 0, np.sign(x) * (np.abs(x) * (1 - v) + v), 0.0) if v else x
             for v, x in zip(threshold, (s.u1, s.u2))]
        out.append(dataclasses.replace(s, u1=u[0], u2=u[1]))
    return out


@pytest.mark.parametrize("family, rewrite, truth", [
    ("input_delay", _delayed, (0.0, 0.2)),
    ("deadband", _inverse_deadband, (0.05, 0.15)),
])
def test_a_mechanism_that_differs_between_the_inputs_is_found_per_input(lab, family, rewrite, truth):
    """A delay of the steering alone, a deadband three times wider on the steering than on the
    throttle: the family is named, its value per input is the injected one (within 25 %, or below a
    quarter of the other's where it is zero), the per-input form is the extension's, and it lowers the
    5 s error of the test runs. The pooled fit alone says one value between the two (0.10 s for the
    delay)."""
    model, (train, test, a, b) = lab
    d = diagnose_states(model, rewrite(train, truth), rewrite(test, truth), a, b)
    assert d.verdict == family
    est = d.ranked[0].score.estimate
    for u, v in zip(("u1", "u2"), truth):
        if v:
            assert est["per_input"][u] == pytest.approx(v, rel=0.25)
        else:
            assert abs(est["per_input"][u]) < 0.25 * max(truth)
    assert est["per_input_differ"] and d.extended.spec.per_input
    assert d.after.pos_err_5s_m < 0.5 * d.before.pos_err_5s_m


def test_a_mechanism_on_both_inputs_keeps_its_pooled_form(lab):
    """The same delay on both inputs: the per-input values are not told apart, so the extension keeps
    the pooled form (one parameter), both values near the truth."""
    model, (train, test, a, b) = lab
    d = diagnose_states(model, _delayed(train, (0.15, 0.15)), _delayed(test, (0.15, 0.15)), a, b)
    assert d.verdict == "input_delay"
    est = d.ranked[0].score.estimate
    assert not est["per_input_differ"] and not d.extended.spec.per_input
    for u in ("u1", "u2"):
        assert est["per_input"][u] == pytest.approx(0.15, rel=0.25)
