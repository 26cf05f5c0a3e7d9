"""The cause step (issue 15, item 2): evidence that assumes no mechanism form.

References are forward mechanisms written here and integrated by an ODE solver (a transport
delay, a first-order actuator lag) driving a plain first-order plant that the "model" knows
without any delay; structure planted by hand in residuals; and rankings built by hand.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from groundfloor.types import BodyStates
from sindy_ekf.diagnose.cause import (
    highpass,
    named_by_response_lag,
    response_lag,
    threshold,
    unexplained_structure,
)
from sindy_ekf.diagnose.data import split_from_states
from sindy_ekf.diagnose.fitting import FamilyScore
from sindy_ekf.diagnose.rank import RankedCause

A_1_S, B = np.array([4.0, 3.0]), np.array([2.0, 1.5])  # plant: v' = -a v + b u_motor, per axis


class PlantModel:
    """The plant as a model knows it: no delay, no lag (``f`` of a SINDy model's signature)."""

    def f(self, x, u):
        x, u = np.asarray(x, float), np.asarray(u, float)
        return np.stack([-A_1_S[0] * x[..., 0] + B[0] * u[..., 0], np.zeros(x.shape[:-1]),
                         -A_1_S[1] * x[..., 2] + B[1] * u[..., 1]], axis=-1)


def smooth_inputs(rng, t):
    """Return inputs (n, 2): random steps every 0.5-3 s, each ramped over 0.2 s."""
    knots = np.cumsum(rng.uniform(0.5, 3.0, 200))
    levels = rng.uniform(-0.8, 0.8, (200, 2))
    ramp_t = np.sort(np.concatenate([knots, knots + 0.2]))
    ramp_v = np.repeat(levels, 2, axis=0)[1:-1]
    return np.column_stack([np.interp(t, ramp_t[1:-1], ramp_v[:, j]) for j in range(2)])


def plant_runs(mechanism: str, value: float, n_runs: int = 3, run_s: float = 60.0, rate_hz: float = 25.0,
               seed: int = 0):
    """Return runs (BodyStates) of the plant driven through ``mechanism`` (solve_ivp)."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(n_runs):
        t = np.arange(0.0, run_s, 1.0 / rate_hz)
        u = smooth_inputs(rng, t)

        def motor(s, m):
            if mechanism == "transport_delay":  # one delay, or one per input
                return np.array([np.interp(s - np.broadcast_to(value, 2)[j], t, u[:, j]) for j in range(2)])
            return m  # first-order actuator lag: the motor state itself

        def rhs(s, y):
            v, m = y[:2], y[2:]
            u_now = np.array([np.interp(s, t, u[:, j]) for j in range(2)])
            dm = (u_now - m) / value if mechanism == "first_order_lag" else np.zeros(2)
            return np.concatenate([-A_1_S * v + B * motor(s, m), dm])

        sol = solve_ivp(rhs, (t[0], t[-1]), np.concatenate([np.zeros(2), u[0]]), t_eval=t, max_step=0.01,
                        rtol=1e-8, atol=1e-10)
        v = sol.y[:2].T + rng.normal(0, 0.002, (len(t), 2))
        z = np.zeros(len(t))
        runs.append(BodyStates(t=t, vx=v[:, 0], vy=z, omega=v[:, 1], u1=u[:, 0], u2=u[:, 1], x=np.cos(0.1 * t),
                               y=np.sin(0.1 * t), yaw=z))
    return split_from_states(runs, [f"run{i}" for i in range(n_runs)], 1.0)


@pytest.mark.parametrize("delay_s", [0.0, 0.1, 0.25])
def test_response_lag_reads_a_transport_delay(delay_s):
    lag = response_lag(PlantModel(), plant_runs("transport_delay", delay_s))
    assert lag.delay_s == pytest.approx(delay_s, abs=0.02)
    assert set(lag.per_run) == {"run0", "run1", "run2"}
    assert all(v == pytest.approx(delay_s, abs=0.04) for v in lag.per_run.values())


def test_response_lag_per_input_reads_each_inputs_own_transport_delay():
    # the throttle's motor sees its input 0.05 s late, the steering's 0.3 s: each input's response
    # lag is its own delay, their mean the pooled one; one delay for both reads it on both
    lag = response_lag(PlantModel(), plant_runs("transport_delay", (0.05, 0.3), n_runs=4))
    assert lag.per_input["u1"] == pytest.approx(0.05, abs=0.02)
    assert lag.per_input["u2"] == pytest.approx(0.3, abs=0.02)
    assert lag.delay_s == pytest.approx(0.5 * (lag.per_input["u1"] + lag.per_input["u2"]), abs=1e-12)
    assert all(0 < lag.per_input_std[k] < 0.02 for k in ("u1", "u2"))
    same = response_lag(PlantModel(), plant_runs("transport_delay", 0.2, n_runs=4))
    assert same.per_input == pytest.approx({"u1": 0.2, "u2": 0.2}, abs=0.02)


def test_response_lag_sees_a_lag_of_another_form():
    # a first-order actuator lag, a form the transport delay does not share: a positive lag of the
    # order of its time constant, above the threshold; none without it
    lag = response_lag(PlantModel(), plant_runs("first_order_lag", 0.2))
    assert threshold("delay_s") < lag.delay_s < 0.3
    assert abs(response_lag(PlantModel(), plant_runs("first_order_lag", 1e-3)).delay_s) < 0.02


def test_highpass_against_a_hand_moving_average():
    t = np.arange(0, 10, 0.1)
    x = np.sin(t) + 0.3 * t
    n = 21  # 2 s at 10 Hz
    padded = np.concatenate([np.full(n // 2, x[0]), x, np.full(n // 2, x[-1])])
    hand = x - np.array([padded[i:i + n].mean() for i in range(len(x))])
    np.testing.assert_allclose(highpass(x, t, 2.0), hand, atol=1e-12)
    np.testing.assert_allclose(highpass(np.full(50, 3.0), t[:50], 2.0), 0.0, atol=1e-12)


def heading_split(strength: float, seed: int):
    """Return a split whose omega residual (against PlantModel) depends on the heading by ``strength``."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(3):
        t = np.arange(0.0, 60.0, 0.04)
        yaw = 0.4 * t + rng.uniform(0, 6)
        u = smooth_inputs(rng, t)
        dt = t[1] - t[0]
        v = np.zeros((len(t), 2))
        for k in range(1, len(t)):  # Euler forward, fine step: the plant plus a heading push on omega
            v[k] = v[k - 1] + dt * (-A_1_S * v[k - 1] + B * u[k - 1] + [0.0, strength * np.sin(yaw[k - 1])])
        v += rng.normal(0, 0.002, v.shape)
        runs.append(BodyStates(t=t, vx=v[:, 0], vy=np.zeros(len(t)), omega=v[:, 1], u1=u[:, 0], u2=u[:, 1],
                               x=np.cos(0.1 * t), y=np.sin(0.1 * t), yaw=yaw))
    return split_from_states(runs, ["a", "b", "c"], 1.0)


def test_unexplained_structure_finds_a_planted_regressor():
    eta2, eq, reg = unexplained_structure(PlantModel(), heading_split(0.3, 1), heading_split(0.3, 2))
    assert (eq, reg) == ("omega", "heading") and eta2 > threshold("eta2")
    assert unexplained_structure(PlantModel(), heading_split(0.0, 1), heading_split(0.0, 2))[0] < threshold("eta2")


def cause(name, gain, significant, estimate=None):
    score = FamilyScore(name, np.zeros(1), np.zeros(0), gain, {}, gain, dict(estimate or {}))
    return RankedCause(name, gain, 0.03, significant, score)


def lag_of(delay_s):
    return replace(response_lag(PlantModel(), plant_runs("transport_delay", 0.0, n_runs=1, run_s=20.0)),
                   delay_s=delay_s)


def test_response_lag_names_the_delay_only_when_train_and_test_agree():
    ranked = [cause("deadband", 0.001, False), cause("input_delay", -0.01, False)]
    big, small = lag_of(0.15), lag_of(0.5 * threshold("delay_s"))
    assert [c.significant for c in named_by_response_lag(ranked, big, small)] == [False, False]
    out = named_by_response_lag(ranked, big, big)
    assert out[0].name == "input_delay" and out[0].significant
    assert out[0].score.estimate["delay_s"] == 0.15 and out[0].score.estimate["evidence"] == "response_lag"
    # a family significant by its own out-of-sample gain keeps the first place
    out = named_by_response_lag([cause("deadband", 0.2, True), cause("input_delay", -0.01, False)], big, big)
    assert [c.name for c in out] == ["deadband", "input_delay"] and all(c.significant for c in out)


def test_unexplained_structure_is_what_a_refit_of_the_models_own_terms_cannot_absorb():
    from identification.sindy.model import model_from_terms
    from sindy_ekf.diagnose.cause import beyond_own_terms
    from sindy_ekf.diagnose.residuals import residual_structure

    # the plant as a SINDy model, its omega damping off by half: residuals grow with omega itself
    off = model_from_terms({"vx": {"vx": -A_1_S[0], "u1": B[0]}, "vy": {},
                            "omega": {"omega": -0.5 * A_1_S[1], "u2": B[1]}}, "poly1")
    tr, te = heading_split(0.0, 1), heading_split(0.0, 2)
    raw = min(residual_structure(off, tr)["omega"]["omega"].eta2, residual_structure(off, te)["omega"]["omega"].eta2)
    assert raw > threshold("eta2")  # what the statistic saw before the refit was taken out
    assert unexplained_structure(off, tr, te)[0] < threshold("eta2")
    # a heading push is no term of the model: it stays after the refit, the strongest structure by far
    # (a push of 0.3 rad/s^2 keeps eta2 0.25, below the threshold recalibrated on variant 5's quick
    # model, 0.51: the unexplained verdict needs it stronger there; issue 15, open)
    clean = unexplained_structure(off, tr, te)[0]
    eta2, eq, reg = unexplained_structure(off, heading_split(0.3, 1), heading_split(0.3, 2))
    assert (eq, reg) == ("omega", "heading") and eta2 > 5 * clean and eta2 > 0.2
    r_tr, r_te = beyond_own_terms(off, tr, te)
    assert np.std(r_te[:, 2]) < 0.2 * np.std(te.delta_v[:, 2] / te.tau - te.integrate(off.f(te.v_body, te.u))[:, 2] / te.tau)
