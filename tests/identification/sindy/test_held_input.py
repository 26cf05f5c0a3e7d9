"""The held-input check (identification.sindy.checks.held_input): a model that runs away while an
input is held is refused, the simulator's true dynamics of every variant never are.

References independent of the check: the closed-form solution of a linear ODE (when a state leaves
the box), and the simulator's own true dynamics (simulation.robot.TrueDynamics) of 10 variants.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from identification.sindy.checks import (
    DISSIPATIVE_WIDTHS,
    HELD_INPUT_DT_S,
    HELD_INPUT_HORIZON_S,
    held_excursion,
    held_input,
    run_checks,
    widened_box,
)
from identification.sindy.model import envelope_from_data, model_from_terms
from simulation.robot import TrueDynamics
from simulation.short_campaign import simulate_states_campaign
from simulation.variants import draw_variant
from tests.support.sindy_synth import lag_f, simulate_states


def test_the_time_a_held_input_takes_a_state_out_of_the_box_matches_the_closed_form_solution():
    # vx' = r vx + b with r > 0 (a held input that destabilises), vy, omega at rest:
    # vx(t) = (vx0 + b / r) e^(r t) - b / r leaves [-1, 1] at t = ln((1 + b / r) / (vx0 + b / r)) / r
    # (the last start leaves through the lower face: vx -> -vx, b -> -b mirrors the first)
    r, b = np.array([0.8, 1.5, 0.3, 0.8]), np.array([0.2, 0.0, 0.1, -0.2])
    u = np.column_stack([r, b])  # the inputs carry each start's own r and b

    def f(x, u):
        return np.column_stack([u[:, 0] * x[:, 0] + u[:, 1], -x[:, 1], -x[:, 2]])

    x0 = np.array([[0.1, 0.0, 0.0], [0.05, 0.0, 0.0], [0.2, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    lo, hi = -np.ones(3), np.ones(3)
    left = held_excursion(f, x0, u, lo, hi, horizon_s=20.0)
    exact = np.log((1 + np.abs(b) / r) / (np.abs(x0[:, 0]) + np.abs(b) / r)) / r
    # the first step at or after the exact time (RK4's error at this step is far below one step)
    assert np.all((left >= exact) & (left < exact + HELD_INPUT_DT_S))
    assert left[3] == left[0]
    # a stable one (r < 0) never leaves; over a short horizon the unstable ones have not left yet
    stay = held_excursion(f, x0, np.column_stack([-r, b]), lo, hi, horizon_s=20.0)
    assert np.all(np.isinf(stay))
    assert np.all(np.isinf(held_excursion(f, x0, u, lo, hi, horizon_s=0.5 * exact.min())))


@pytest.mark.parametrize("index", range(1, 11))
def test_the_true_dynamics_of_every_simulator_variant_stay_in_the_box_under_every_held_training_input(index):
    """The simulator's robot has a steady motion for every input its driver gave: held from any
    training state, it stays in the envelope widened as the check widens it."""
    train, *_ = simulate_states_campaign(index, n_train=2, n_test=0, run_s=60.0, rate_hz=25.0, variant=index)
    x = np.vstack([st.state for st in train])
    u = np.vstack([st.inputs for st in train])
    truth = TrueDynamics.of_variant(draw_variant(index), None)
    env = envelope_from_data(x, u)
    lo = np.array([env[v][0] for v in ("vx", "vy", "omega")])
    hi = np.array([env[v][1] for v in ("vx", "vy", "omega")])
    w = hi - lo
    pick = np.round(np.linspace(0, len(x) - 1, 400)).astype(int)

    def f(xb, ub):
        return truth.accel(np.concatenate([np.zeros(xb.shape[:-1] + (3,)), xb], axis=-1), ub)

    # integrated at the simulator's own step: its lateral dynamics are stiffer than RK4 at the check's step allows
    left = held_excursion(f, x[pick], u[pick], lo - DISSIPATIVE_WIDTHS * w, hi + DISSIPATIVE_WIDTHS * w, dt=0.004)
    assert np.all(np.isinf(left)), f"variant {index}: {np.isfinite(left).sum()} held inputs leave the box"


@pytest.fixture(scope="module")
def lag_states():
    """Four 40 s runs of a first-order lag per axis."""
    return simulate_states(40.0, [21, 22, 23, 24], f=lag_f())


def _lag_model(states, extra: dict | None = None):
    x = np.vstack([st.state for st in states])
    u = np.vstack([st.inputs for st in states])
    terms = {"vx": {"vx": -1 / 0.3, "u1": 1.8 / 0.3}, "vy": {"vy": -1 / 0.3},
             "omega": {"omega": -1 / 0.2, "u2": 1.2 / 0.2}}
    for e, t in (extra or {}).items():
        terms[e] = terms[e] | t
    return model_from_terms(terms, "poly3", envelope=envelope_from_data(x, u), extrapolation="frozen")


def test_a_model_without_a_steady_state_for_a_held_turn_fails_the_check(lag_states):
    """``vx' = -vx / 0.3 + ... + c vx u2^2``: for ``c u2^2 > 1 / 0.3`` the held turn has no steady
    forward speed and vx runs away; the model is stable at rest (``u2 = 0``). The lag it extends passes."""
    good = _lag_model(lag_states)
    u2_max = max(np.max(np.abs(st.inputs[:, 1])) for st in lag_states)
    c = 2.0 / 0.3 / (0.8 * u2_max) ** 2  # unstable once |u2| > 0.8 max|u2| / sqrt(2) of the data
    bad = _lag_model(lag_states, {"vx": {"vx u2^2": c}})
    assert held_input(good, lag_states)["passed"]
    out = held_input(bad, lag_states)
    assert not out["passed"] and out["n_left"] > 0 and out["first_left_s"] <= HELD_INPUT_HORIZON_S
    # the sample it left from holds a turn past the bound where the forward equation turns unstable
    assert c * out["worst_start"]["u2"] ** 2 > 1 / 0.3
    checks = run_checks(bad, lag_states)
    assert not checks["passed"] and checks["held_input"] == out
    assert checks["stable_at_rest"]["passed"]
    box = widened_box(bad)
    assert box is not None and math.isclose(box[1][0] - box[0][0],
                                            (1 + 2 * DISSIPATIVE_WIDTHS) * np.ptp(np.vstack([s.state for s in lag_states])[:, 0]))
