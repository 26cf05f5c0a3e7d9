"""The alternative mechanism forms of every effect family (issue 15) against hand computations and
an independent ODE solver; parsing, parameters, round trip through truth/; every form changes a
run and keeps it sane at the top of its range."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from groundfloor.errors import InputError
from simulation.actuator import InputMemo
from simulation.driver import DrivingArea
from simulation.effects import EFFECTS, Effect, draw_effect, effect_from_dict, parse_effect
from simulation.robot import TrueDynamics, simulate_run

ALL_FORMS = [(name, form) for name, spec in EFFECTS.items() for form in spec.forms]
OTHER_FORMS = [(name, form) for name, spec in EFFECTS.items() for form in list(spec.forms)[1:]]


def _motor(effect=None, lag=0.0, t=(0.5,), t_joy=(0.0,), u_joy=((0.8, -0.4),)):
    return TrueDynamics(effect=effect, motor_lag_s=lag).motor_inputs(np.asarray(t, float), t_joy, u_joy)


# --- parsing and truth -----------------------------------------------------------------------

def test_every_family_keeps_its_default_form_first():
    defaults = {"input_delay": "transport", "heading_dependence": "slope", "position_dependence": "disc",
                "time_dependence": "linear", "asymmetry": "gain", "deadband": "hard", "lateral_slip": "coupling"}
    assert {n: s.default_form for n, s in EFFECTS.items()} == defaults
    for name, spec in EFFECTS.items():
        first = spec.forms[spec.default_form]
        assert (first.valid_range, first.moderate, first.unit) == (spec.valid_range, spec.moderate, spec.unit)
        for form, fs in spec.forms.items():
            assert fs.valid_range[0] < fs.moderate < fs.valid_range[1], (name, form)
    assert {f for n, f in OTHER_FORMS} >= {"motor_lag", "bumps", "gradient", "exponential", "late", "early",
                                            "steering_offset", "coupling", "friction", "soft", "hysteresis",
                                            "tanh", "cubic", "speed_stiffness"}


@pytest.mark.parametrize("text, expect", [
    ("input_delay:motor_lag=0.15", Effect("input_delay", 0.15, "motor_lag")),
    ("input_delay=0.15", Effect("input_delay", 0.15, "transport")),
    ("deadband:soft", Effect("deadband", EFFECTS["deadband"].forms["soft"].moderate, "soft")),
    ("heading_dependence=1.5,azimuth_deg=120", Effect("heading_dependence", 1.5, "slope", {"azimuth_deg": 120.0})),
    ("time_dependence:late=0.3,onset_s=40", Effect("time_dependence", 0.3, "late", {"onset_s": 40})),
])
def test_parse_forms_and_parameters(text, expect):
    assert parse_effect(text) == expect


def test_default_form_effects_equal_the_pre_forms_effects():
    assert Effect("input_delay", 0.15) == Effect("input_delay", 0.15, "transport")
    assert Effect("input_delay", 0.15).to_dict() == {"name": "input_delay", "value": 0.15}
    assert Effect("input_delay", 0.15).is_default_form


@pytest.mark.parametrize("text, culprit", [
    ("input_delay:teleport=0.1", "'teleport'"),
    ("deadband:soft=0.1,width=3", "'width'"),
    ("asymmetry:steering_offset=0.3", "asymmetry:steering_offset=0.3"),
    ("time_dependence:late=0.2,onset_s=700", "onset_s=700"),
    ("heading_dependence=1,azimuth_deg", "'azimuth_deg'"),
    ("heading_dependence=1,azimuth_deg=east", "'east'"),
])
def test_bad_forms_and_parameters_are_named(text, culprit):
    with pytest.raises(InputError, match=culprit) as err:
        parse_effect(text)
    assert "\n" not in str(err.value)


def test_seed_draws_geometry_once_and_truth_keeps_it():
    a = parse_effect("position_dependence:bumps=0.4,seed=3")
    assert a == parse_effect("position_dependence:bumps=0.4,seed=3")
    assert a.param("centres_m") != parse_effect("position_dependence:bumps=0.4,seed=4").param("centres_m")
    az = parse_effect("heading_dependence=1.5,seed=3").param("azimuth_deg")
    assert -180.0 <= az <= 180.0 and az != 0.0
    assert draw_effect("position_dependence", "gradient", 0.4, np.random.default_rng(1)).param("azimuth_deg") != 0.0


@pytest.mark.parametrize("name, form", ALL_FORMS)
def test_every_form_round_trips_through_truth_yaml(name, form):
    e = draw_effect(name, form, EFFECTS[name].forms[form].moderate, np.random.default_rng(5))
    doc = yaml.safe_load(yaml.safe_dump(e.to_dict()))
    assert effect_from_dict(doc) == e
    assert ("form" in doc) == (not e.is_default_form)


# --- input side ------------------------------------------------------------------------------

def test_motor_lag_is_a_first_order_step_response():
    tau = 0.15
    t = np.array([-0.1, 0.0, 0.05, 0.15, 0.6])
    u = _motor(Effect("input_delay", tau, "motor_lag"), t=t)
    expect = np.outer(np.where(t >= 0, 1 - np.exp(-np.maximum(t, 0) / tau), 0.0), [0.8, -0.4])
    np.testing.assert_allclose(u, expect, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("tau1, tau2", [(0.1, 0.25), (0.2, 0.2), (0.2, 0.2 + 1e-7)])
def test_two_lags_in_series_step_response(tau1, tau2):
    """A variant's motor lag behind an input_delay:motor_lag effect: the textbook two-lag step
    response ``1 - (t1 e^-t/t1 - t2 e^-t/t2) / (t1 - t2)`` (``1 - (1 + t/t) e^-t/t`` when equal)."""
    t = np.linspace(0.0, 1.5, 31)
    u = _motor(Effect("input_delay", tau2, "motor_lag"), lag=tau1, t=t, u_joy=((1.0, 0.5),))
    if tau1 == tau2:
        y = 1 - (1 + t / tau1) * np.exp(-t / tau1)
    else:
        y = 1 - (tau1 * np.exp(-t / tau1) - tau2 * np.exp(-t / tau2)) / (tau1 - tau2)
    np.testing.assert_allclose(u[:, 0], y, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(u[:, 1], 0.5 * y, rtol=1e-7, atol=1e-9)


def test_lags_on_a_joystick_sequence_match_an_ode_solver_and_the_simulators_memo():
    rng = np.random.default_rng(2)
    t_joy = np.cumsum(rng.uniform(0.03, 0.09, 40))
    u_joy = rng.uniform(-1.2, 1.2, (40, 2))  # beyond the square: saturated before the lags
    tau1, tau2 = 0.12, 0.07
    dyn = TrueDynamics(effect=Effect("input_delay", tau2, "motor_lag"), motor_lag_s=tau1)
    t = np.linspace(0.0, t_joy[-1] + 0.3, 200)
    u = dyn.motor_inputs(t, t_joy, u_joy)

    def held(s):
        i = np.searchsorted(t_joy, s, side="right") - 1
        return np.clip(u_joy[i], -1, 1) if i >= 0 else np.zeros(2)

    # y = [lag1 (2), lag2 (2)], integrated message by message (the input jumps at the messages)
    y, ref, edges = np.zeros(4), [], np.concatenate([[0.0], t_joy, [t[-1] + 1.0]])
    for a, b in zip(edges[:-1], edges[1:]):
        c = held(a)
        sol = solve_ivp(lambda s, v, c=c: np.r_[(c - v[:2]) / tau1, (v[:2] - v[2:]) / tau2], (a, b), y,
                        dense_output=True, rtol=1e-11, atol=1e-13)
        inside = (t >= a) & (t < b)
        ref.append(sol.sol(t[inside]).T[:, 2:])
        y = sol.y[:, -1]
    np.testing.assert_allclose(u, np.concatenate(ref), atol=1e-9)
    # the simulator extends one history through a memo: the same numbers
    memo, parts = InputMemo(), []
    for m in range(1, 41):
        sel = (t >= t_joy[m - 1]) & (t < (t_joy[m] if m < 40 else np.inf))
        parts.append(dyn.motor_inputs(t[sel], t_joy[:m], u_joy[:m], memo))
    np.testing.assert_array_equal(np.concatenate(parts), u[t >= t_joy[0]])


def test_soft_deadband_is_smooth_odd_and_reaches_the_corners():
    v = 0.15
    u = np.array([-1.0, -0.5, -0.05, 0.0, 0.02, 0.5, 1.0])
    got = _motor(Effect("deadband", v, "soft"), t=np.arange(7) + 0.5, t_joy=np.arange(7.0), u_joy=np.c_[u, -u])
    expect = (u - v * np.tanh(u / v)) / (1 - v * math.tanh(1 / v))
    np.testing.assert_allclose(got[:, 0], expect, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(got[:, 1], -expect, rtol=1e-12, atol=1e-15)
    assert got[0, 0] == pytest.approx(-1.0) and got[-1, 0] == pytest.approx(1.0)
    assert got[4, 0] == pytest.approx(0.02 ** 3 / (3 * v * v) / (1 - v * math.tanh(1 / v)), rel=0.02)  # cubic near 0
    assert got[5, 0] == pytest.approx((0.5 - v) / (1 - v), abs=1e-3)  # the hard deadband far from it


def test_hysteresis_deadband_breaks_away_and_releases():
    v, r = 0.2, 0.1  # release_ratio 0.5
    seq = [0.15, 0.25, 0.15, 0.05, 0.15, -0.3, -0.12, -0.08]
    expect = [0.0, 0.15 / 0.9, 0.05 / 0.9, 0.0, 0.0, -0.2 / 0.9, -0.02 / 0.9, 0.0]
    got = _motor(Effect("deadband", v, "hysteresis"), t=np.arange(8) + 0.5, t_joy=np.arange(8.0),
                 u_joy=np.c_[seq, np.zeros(8)])
    np.testing.assert_allclose(got[:, 0], expect, atol=1e-15)
    assert r == v * EFFECTS["deadband"].forms["hysteresis"].params["release_ratio"]


def test_steering_offset_and_coupling():
    got = _motor(Effect("asymmetry", 0.05, "steering_offset"), t=(-1.0, 0.5))
    np.testing.assert_allclose(got, [[0.0, 0.05], [0.8, -0.35]])  # the trim acts on a centred stick
    got = _motor(Effect("asymmetry", 0.1, "coupling"))
    np.testing.assert_allclose(got, [[0.8, -0.4 + 0.08]])


@pytest.mark.parametrize("form, at_300, at_30", [
    ("linear", 1 - 0.3 / 2, 1 - 0.3 * 30 / 600),
    ("exponential", math.sqrt(0.7), 0.7 ** (30 / 600)),
    ("late", 1 - 0.3 * 270 / 570, 1.0),  # onset 30 s: nothing before, 1 - v at 600 s
    ("early", 1 - 0.3 * (1 - math.exp(-5)) / (1 - math.exp(-10)), 1 - 0.3 * (1 - math.exp(-0.5)) / (1 - math.exp(-10))),
])
def test_battery_sag_shapes(form, at_300, at_30):
    e = Effect("time_dependence", 0.3, form)
    t = np.array([0.0, 30.0, 300.0, 600.0])
    got = _motor(e, t=t, u_joy=((1.0, -0.5),))
    np.testing.assert_allclose(got[:, 0], [1.0, at_30, at_300, 0.7], rtol=1e-12)
    np.testing.assert_allclose(got[:, 1], -0.5 * got[:, 0], rtol=1e-12)
    grid = _motor(e, t=np.linspace(0, 900, 400), u_joy=((1.0, 0.0),))[:, 0]
    assert np.all(np.diff(grid) <= 1e-15)


# --- body side -------------------------------------------------------------------------------

@pytest.mark.parametrize("azimuth_deg", [0.0, 120.0, -70.0])
def test_slope_in_any_direction_is_gravity_along_the_floor(azimuth_deg):
    tilt = 2.0
    dyn_e = TrueDynamics(effect=Effect("heading_dependence", tilt, "slope", {"azimuth_deg": azimuth_deg}))
    psi = np.linspace(-3, 3, 13)
    x6 = np.zeros((13, 6))
    x6[:, 2] = psi
    df = dyn_e.accel(x6, [0, 0]) - TrueDynamics().accel(x6, [0, 0])
    th, az = math.radians(tilt), math.radians(azimuth_deg)
    n = np.array([math.sin(th) * math.cos(az), math.sin(th) * math.sin(az), math.cos(th)])  # descends towards az
    g = np.array([0, 0, -9.81])
    g_floor = g - (g @ n) * n
    fwd = np.column_stack([np.cos(psi), np.sin(psi), np.zeros(13)])
    left = np.column_stack([-np.sin(psi), np.cos(psi), np.zeros(13)])
    np.testing.assert_allclose(df[:, 0], fwd @ g_floor, rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(df[:, 1], left @ g_floor, rtol=1e-3, atol=1e-12)
    run = simulate_run(5.0, np.random.default_rng(2), effect=dyn_e.effect, dt=0.004)
    np.testing.assert_allclose(run.z, -math.tan(th) * (run.x * math.cos(az) + run.y * math.sin(az)))


def test_track_friction_difference_by_the_per_track_model():
    """Right track's friction (1 + v/2) c, left's (1 - v/2) c, c fixed by model B's linear damping."""
    v, b = 0.1, 0.29
    x6 = np.array([[3.0, 2.0, 0.3, 0.6, 0.0, 0.4], [3.0, 2.0, 0.3, -0.3, 0.01, -0.8]])
    df = TrueDynamics(effect=Effect("asymmetry", v, "friction")).accel(x6, [0.2, 0.1]) - TrueDynamics().accel(x6, [0.2, 0.1])
    vx, om = x6[:, 3], x6[:, 5]
    c_m = 7.770 / 2  # vx_dot = (F_l + F_r) / m, F = -c v_track: -(2 c / m) vx = -7.770 vx
    cb_i = 6.951 / (2 * b)  # omega_dot = b (F_r - F_l) / I: -(2 c b^2 / I) omega = -6.951 omega
    f_l, f_r = -(1 - v / 2) * (vx - b * om), -(1 + v / 2) * (vx + b * om)
    extra_vx = c_m * (f_l + f_r) + 7.770 * vx
    extra_om = cb_i * (f_r - f_l) + 6.951 * om
    np.testing.assert_allclose(df[:, 0], extra_vx, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(df[:, 2], extra_om, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(df[:, 1], 0.0, atol=1e-14)


def _field(effect: Effect, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The floor field s(x, y) seen through the accelerations: damping added over -v d_vx vx."""
    x6 = np.column_stack([x, y, np.zeros_like(x), np.full_like(x, 0.5), np.zeros_like(x), np.zeros_like(x)])
    df = TrueDynamics(effect=effect).accel(x6, [0.0, 0.0]) - TrueDynamics().accel(x6, [0.0, 0.0])
    return df[:, 0] / (-effect.value * 7.770 * 0.5)


def test_bumps_are_gaussians_peaking_at_one_over_the_area():
    e = parse_effect("position_dependence:bumps=0.4,seed=7")
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0.5, 6.5, 50), rng.uniform(0.5, 5.5, 50)
    hand = sum(w * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sig ** 2))
               for (cx, cy), sig, w in zip(e.param("centres_m"), e.param("widths_m"), e.param("weights")))
    np.testing.assert_allclose(_field(e, x, y), hand, rtol=1e-9)
    area = DrivingArea()
    gx, gy = np.meshgrid(np.linspace(0, 7, 141), np.linspace(0, 6, 121))
    inside = area.ellipse_radius(gx, gy) <= 1.0
    assert 0.98 < _field(e, gx[inside], gy[inside]).max() < 1.0 + 1e-3  # value = peak damping gain


def test_gradient_is_a_smooth_step_across_the_lab():
    e = Effect("position_dependence", 0.4, "gradient", {"azimuth_deg": 90.0, "length_m": 1.0})
    cx, cy = DrivingArea().center_local_m
    s = _field(e, np.array([cx, cx + 5.0, cx, cx]), np.array([cy, cy, cy + 2.0, cy - 2.0]))
    np.testing.assert_allclose(s, [0.5, 0.5, 0.5 * (1 + math.tanh(2.0)), 0.5 * (1 - math.tanh(2.0))], rtol=1e-9)


# --- every form in a run ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def plain_run():
    return simulate_run(25.0, np.random.default_rng(9), start_pose=(4.4, 3.6, 0.7), dt=0.004)


@pytest.mark.parametrize("name, form", OTHER_FORMS)
def test_each_form_changes_the_run_and_its_strongest_keeps_it_sane(name, form, plain_run):
    fs = EFFECTS[name].forms[form]
    params = {"onset_s": 5.0} if form == "late" else {}  # the default onset (30 s) is after this run
    run = simulate_run(25.0, np.random.default_rng(9), effect=Effect(name, fs.moderate, form, params),
                       start_pose=(4.4, 3.6, 0.7), dt=0.004)
    assert np.hypot(run.x - plain_run.x, run.y - plain_run.y).max() > 0.01
    np.testing.assert_array_equal(run.t_joy, plain_run.t_joy)
    strong = simulate_run(30.0, np.random.default_rng(4), effect=Effect(name, fs.valid_range[1], form), dt=0.004)
    assert DrivingArea().contains(strong.x, strong.y).all()
    assert np.degrees(np.abs(strong.psi - strong.psi[0])).max() < 150.0
    assert np.abs(strong.vx).max() < 1.0 and np.abs(strong.omega).max() < 1.3
