"""The oracle of ``evaluate`` is driven as the simulator drove the robot (its motor inputs).

Independent references: the motor inputs against a first-order lag written out here from the
joystick messages (exact for a held input), and the simulator's own trajectory, which the oracle
fed its motor inputs must follow far better than fed the recorded joystick.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.types import TrajectoryCampaign
from identification.sindy.evaluate import evaluate_on_runs
from identification.sindy.model import model_from_terms
from simulation.robot import TrueDynamics
from simulation.short_campaign import simulate_trajectory_runs
from simulation.variants import draw_variant
from sindy_ekf.stages.evaluation import MOTOR_INPUT_DT_S, ORACLE, as_driven, evaluation_stage

RUNS = (("run_01", "train", 40.0), ("run_02", "test", 40.0))
LAGGED = 1  # variant 1 draws a motor lag of 0.25 s


def _campaign(variant) -> TrajectoryCampaign:
    return TrajectoryCampaign("mem", f"variant {variant}", tuple(simulate_trajectory_runs(3, RUNS, variant=variant)))


def test_motor_inputs_are_a_first_order_lag_of_the_joystick():
    v = draw_variant(LAGGED)
    assert v.motor_lag_s > 0.2
    run = _campaign(LAGGED).split("test")[0]
    driven = as_driven(run, TrueDynamics.of_variant(v))
    # written out: y' = (u_joy(t) - y) / tau with the joystick held between messages, from y = 0
    t_joy, u_joy = np.asarray(run.inputs.t), np.column_stack([run.inputs.u1, run.inputs.u2])
    t, y, k = np.asarray(driven.inputs.t), np.zeros(2), 0
    expected = np.empty((t.size, 2))
    held, last = np.zeros(2), t[0]
    for i, ti in enumerate(t):
        while k < t_joy.size and t_joy[k] <= ti:  # integrate to the message, then switch the held input
            y = held + (y - held) * np.exp(-(t_joy[k] - last) / v.motor_lag_s)
            last, held, k = t_joy[k], u_joy[k], k + 1
        y = held + (y - held) * np.exp(-(ti - last) / v.motor_lag_s)
        last = ti
        expected[i] = y
    got = np.column_stack([driven.inputs.u1, driven.inputs.u2])
    assert np.max(np.abs(got - expected)) < 1e-6
    assert np.max(np.abs(got - expected)) < 0.01 * np.max(np.abs(np.diff(got, axis=0))) / MOTOR_INPUT_DT_S


def test_without_motor_lag_the_recorded_inputs_are_kept():
    run = _campaign(0).split("test")[0]
    assert as_driven(run, TrueDynamics()) is run


@pytest.mark.parametrize("variant", [LAGGED, 3])
def test_oracle_fed_its_motor_inputs_follows_the_simulator(variant):
    v = draw_variant(variant)
    camp = _campaign(variant)
    model = model_from_terms(v.robot.terms(), hyperparameters={"s": 0.0005})
    oracle = TrueDynamics.of_variant(v)
    ev = evaluation_stage(camp, model, oracle)
    driven = ev.errors()[ORACLE].pos_err_5s_m
    # the same oracle on the same windows handed the recorded joystick (what evaluate did before)
    recorded = evaluate_on_runs({ORACLE: oracle}, camp.split("test"), 0.0005)[ORACLE]["rk4"].pos_err_5s_m
    print(f"variant {variant}: oracle 5 s error {driven:.4f} m driven, {recorded:.4f} m fed the joystick")
    assert driven < 0.5 * recorded, (driven, recorded)

