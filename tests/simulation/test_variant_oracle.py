"""The true dynamics of variants and effect forms: Jacobians against central differences, the
float code against the numpy dynamics, and the oracle rebuilt from truth/ reproducing the
simulated states (motor inputs and RK4 with the recorded process noise)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from simulation.campaign import simulate_campaign
from simulation.effects import EFFECTS, Effect, draw_effect, effect_from_dict
from simulation.rk4_codegen import compile_stepper
from simulation.robot import TrueDynamics, simulate_run
from simulation.truth import campaign_summary, read_truth, true_dynamics_of
from simulation.variant import Variant
from simulation.variants import draw_variant
from tests.support.robot_synth import random_states

VARIANTS = tuple(range(1, 11))
FORMS = [draw_effect(name, form, spec.forms[form].moderate, np.random.default_rng(3))
         for name, spec in EFFECTS.items() for form in spec.forms]


def _central(fun, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    return np.stack([(fun(x + h * e) - fun(x - h * e)) / (2 * h) for e in np.eye(x.shape[-1])], axis=-1)


def _check_jacobians(dyn: TrueDynamics, seed: int) -> None:
    rng = np.random.default_rng(seed)
    x6 = random_states(rng, 40, track_max=1.3, w_max=1.6)  # the limiters' range too
    u = rng.uniform(-1, 1, (40, 2))
    _, J_x, J_u = dyn.accel_and_jacobians(x6, u, 0.0)
    np.testing.assert_allclose(J_x, _central(lambda x: dyn.accel(x, u), x6), rtol=1e-6, atol=2e-6)
    np.testing.assert_allclose(J_u, _central(lambda v: dyn.accel(x6, v), u), rtol=1e-6, atol=2e-6)


@pytest.mark.parametrize("index", VARIANTS)
def test_jacobians_of_every_variant(index):
    _check_jacobians(TrueDynamics.of_variant(draw_variant(index)), index)


@pytest.mark.parametrize("effect", FORMS, ids=lambda e: f"{e.name}:{e.form}")
def test_jacobians_and_float_code_of_every_form_on_a_variant(effect):
    """Every form on a variant (with a non-linear lateral law, variant 1's tanh): analytic
    Jacobians against central differences, the generated float code against numpy."""
    variant = draw_variant(1)
    dyn = TrueDynamics.of_variant(variant, effect)
    _check_jacobians(dyn, 7)
    _check_jacobians(TrueDynamics(effect=effect), 8)
    _, acc = compile_stepper(variant.robot, effect, variant.lateral)
    rng = np.random.default_rng(5)
    x6, u = random_states(rng, 30, track_max=1.3, w_max=1.6), rng.uniform(-1, 1, (30, 2))
    a_float = np.array([acc(*s, *v) for s, v in zip(x6.tolist(), u.tolist())])
    np.testing.assert_allclose(a_float, dyn.accel(x6, u), rtol=1e-12, atol=1e-12)


def _rk4_replay(oracle: TrueDynamics, run, dt: float) -> np.ndarray:
    """Integrate the oracle from the run's first state with its motor inputs and process noise
    held over each step (what the simulator does, here in numpy)."""
    x = np.array([run.x[0], run.y[0], run.psi[0], run.vx[0], run.vy[0], run.omega[0]])
    out = [x]
    for k in range(len(run.t) - 1):
        u, w = run.u_motor[k], np.r_[0.0, 0.0, 0.0, run.noise[k]]

        def f(s, u=u, w=w, t=run.t[k]):
            return oracle.derivative(s, u, t) + w

        k1 = f(x)
        k2 = f(x + 0.5 * dt * k1)
        k3 = f(x + 0.5 * dt * k2)
        k4 = f(x + dt * k3)
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x)
    return np.array(out)


CASES = [(2, None), (5, Effect("input_delay", 0.15, "motor_lag")), (1, Effect("deadband", 0.2, "hysteresis")),
         (7, Effect("lateral_slip", 4.0, "tanh")), (4, Effect("position_dependence", 0.4, "bumps", {"seed": 2})),
         (9, Effect("asymmetry", 0.05, "friction")), (3, Effect("time_dependence", 0.3, "early")),
         (0, Effect("heading_dependence", 1.5, "slope", {"azimuth_deg": 120.0})), (6, Effect("input_delay", 0.1))]


@pytest.mark.parametrize("index, effect", CASES, ids=lambda c: str(c) if isinstance(c, int) else (c.label() if c else "none"))
def test_oracle_rebuilt_from_truth_reproduces_the_run(index, effect):
    dt = 0.004
    variant = draw_variant(index)
    run = simulate_run(2.0, np.random.default_rng(index + 30), effect=effect, variant=variant, dt=dt)
    # what truth/ holds, through YAML
    v_back = Variant.from_dict(yaml.safe_load(yaml.safe_dump(variant.to_dict())))
    e_back = effect_from_dict(yaml.safe_load(yaml.safe_dump(effect.to_dict()))) if effect else None
    oracle = TrueDynamics.of_variant(v_back, e_back)
    np.testing.assert_array_equal(oracle.motor_inputs(run.t, run.t_joy, run.u_joy), run.u_motor)
    states = _rk4_replay(oracle, run, dt)
    true = np.column_stack([run.x, run.y, run.psi, run.vx, run.vy, run.omega])
    np.testing.assert_allclose(states, true, rtol=0, atol=1e-9)


def test_variant_campaign_truth_rebuilds_its_true_dynamics(tmp_path):
    """A 2.25-minute campaign of variant 6 with a motor lag: truth/ records variant and form; the
    oracle read back equals the one built from the variant; the tracker noise is the variant's."""
    out = tmp_path / "v6"
    effect = Effect("input_delay", 0.1, "motor_lag")
    truth = simulate_campaign(out, seed=5, minutes=2.25, effects=["input_delay:motor_lag=0.1"], variant=6)
    doc = yaml.safe_load((out / "truth" / "truth.yaml").read_text())
    assert doc["variant"]["index"] == 6 and doc["effects"][0]["form"] == "motor_lag"
    assert "simulator variant 6" in (out / "campaign.yaml").read_text()
    back = read_truth(out, states=False)
    variant = draw_variant(6)
    assert back.simulator_variant() == variant and back.effect() == effect
    assert back.noise["at960"]["a_m"] == pytest.approx(3.75e-6 * variant.tracker_noise_scale[0])
    oracle, direct = true_dynamics_of(out), TrueDynamics.of_variant(variant, effect)
    rng = np.random.default_rng(0)
    x6, u = random_states(rng, 30), rng.uniform(-1, 1, (30, 2))
    np.testing.assert_array_equal(oracle.accel(x6, u), direct.accel(x6, u))
    t_joy, u_joy = np.sort(rng.uniform(0, 5, 60)), rng.uniform(-1, 1, (60, 2))
    t = np.linspace(0, 6, 300)
    np.testing.assert_array_equal(oracle.motor_inputs(t, t_joy, u_joy), direct.motor_inputs(t, t_joy, u_joy))
    assert oracle.motor_lag_s == variant.motor_lag_s > 0
    summary = json.loads(json.dumps(campaign_summary(truth)))
    assert summary["variant"]["index"] == 6 and summary["effects"][0]["form"] == "motor_lag"
    # the motors' inputs in states.csv are the lagged ones: never a jump of a whole step
    st = read_truth(out).runs[1].states
    assert np.abs(np.diff(st.u1)).max() < 0.5


def test_default_campaign_truth_has_no_variant(small_campaign):
    doc = yaml.safe_load((small_campaign / "truth" / "truth.yaml").read_text())
    assert "variant" not in doc and doc["effects"] == []
    assert read_truth(small_campaign, states=False).simulator_variant() == Variant()
