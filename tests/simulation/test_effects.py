"""Tests of the effects catalogue: parsing, bad inputs, and each mechanism against its physics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from groundfloor.errors import InputError
from simulation.effects import EFFECTS, Effect, parse_effect
from simulation.robot import TrueDynamics, simulate_run

FAMILIES = ("input_delay", "heading_dependence", "position_dependence", "time_dependence",
            "asymmetry", "deadband", "lateral_slip")


def test_catalogue_lists_the_interface_families_with_sane_specs():
    assert tuple(EFFECTS) == FAMILIES
    for name, spec in EFFECTS.items():
        lo, hi = spec.valid_range
        assert 0 < lo < spec.moderate < hi, name
        assert spec.unit and spec.doc and spec.estimate


@pytest.mark.parametrize("text, name, value", [
    ("input_delay=0.15", "input_delay", 0.15),
    (" heading_dependence = 2.5 ", "heading_dependence", 2.5),
    ("deadband", "deadband", EFFECTS["deadband"].moderate),
])
def test_parse_effect(text, name, value):
    assert parse_effect(text) == Effect(name, value)


def test_unknown_effect_name_is_named():
    with pytest.raises(InputError, match="'wheel_wobble'"):
        parse_effect("wheel_wobble=0.3")
    with pytest.raises(InputError, match="'wheel_wobble'"):
        Effect("wheel_wobble", 0.3)


@pytest.mark.parametrize("text", ["input_delay=0.9", "asymmetry=-0.1", "lateral_slip=1.0"])
def test_out_of_range_value_names_effect_and_range(text):
    name, value = text.split("=")
    lo, hi = EFFECTS[name].valid_range
    with pytest.raises(InputError, match=f"{name}={value}.*\\[{lo}, {hi}\\]"):
        parse_effect(text)


@pytest.mark.parametrize("text", ["input_delay=0.1=2", "=0.3", "input_delay=abc", "input_delay=nan"])
def test_malformed_effect_text_is_quoted(text):
    with pytest.raises(InputError) as err:
        parse_effect(text)
    msg = str(err.value)
    assert "\n" not in msg
    assert repr(text) in msg or repr(text.split("=", 1)[1]) in msg


# --- input-side mechanisms -------------------------------------------------------------------

T_JOY = np.array([0.0, 1.0, 2.0, 3.0])
U_JOY = np.array([[0.1, -0.1], [0.6, 0.0], [-0.3, 0.9], [1.0, 1.0]])


def test_input_delay_shifts_the_hold():
    t = np.linspace(0, 4, 401)
    d = 0.15
    shifted = TrueDynamics(effect=Effect("input_delay", d)).motor_inputs(t, T_JOY, U_JOY)
    plain = TrueDynamics().motor_inputs(t - d, T_JOY, U_JOY)
    np.testing.assert_array_equal(shifted, plain)
    assert np.all(shifted[t < d] == 0.0)


def test_deadband_zeroes_small_and_rescales_large_inputs():
    v = 0.15
    u = TrueDynamics(effect=Effect("deadband", v)).motor_inputs([0.5, 1.5, 2.5, 3.5], T_JOY, U_JOY)
    expect = [[0, 0], [(0.6 - v) / (1 - v), 0], [-(0.3 - v) / (1 - v), (0.9 - v) / (1 - v)], [1, 1]]
    np.testing.assert_allclose(u, expect)


def test_asymmetry_scales_left_and_right_tracks():
    v = 0.2
    u = TrueDynamics(effect=Effect("asymmetry", v)).motor_inputs([1.5, 2.5], T_JOY, U_JOY)
    # left/right track commands l = u1 - u2, r = u1 + u2 scaled by 1 -/+ v/2
    for (u1, u2), (m1, m2) in zip(U_JOY[1:3], u):
        left, right = (u1 - u2) * (1 - v / 2), (u1 + u2) * (1 + v / 2)
        assert (m1, m2) == pytest.approx(((left + right) / 2, (right - left) / 2))


def test_battery_sag_loses_value_per_ten_minutes():
    v = 0.25
    dyn = TrueDynamics(effect=Effect("time_dependence", v))
    u = dyn.motor_inputs([0.5, 600.0], [0.0], [[0.8, -0.4]])
    np.testing.assert_allclose(u, [[0.8 * (1 - v * 0.5 / 600), -0.4 * (1 - v * 0.5 / 600)],
                                   [0.8 * (1 - v), -0.4 * (1 - v)]])


# --- body-side mechanisms --------------------------------------------------------------------

def test_heading_dependence_is_gravity_along_a_tilted_floor():
    """f difference equals g projected on the body axes of a floor tilted about local y."""
    tilt = 2.0
    dyn_e, dyn = TrueDynamics(effect=Effect("heading_dependence", tilt)), TrueDynamics()
    psi = np.linspace(-3, 3, 13)
    x6 = np.zeros((13, 6))
    x6[:, 2] = psi
    df = dyn_e.accel(x6, [0, 0]) - dyn.accel(x6, [0, 0])
    th = math.radians(tilt)
    # floor normal tilted so that the floor descends towards local +x; gravity in the floor plane
    n = np.array([math.sin(th), 0.0, math.cos(th)])
    g = np.array([0, 0, -9.81])
    g_floor = g - (g @ n) * n
    fwd = np.column_stack([np.cos(psi), np.sin(psi), np.zeros(13)])  # body axes (small-tilt)
    left = np.column_stack([-np.sin(psi), np.cos(psi), np.zeros(13)])
    np.testing.assert_allclose(df[:, 0], fwd @ g_floor, rtol=1e-3)
    np.testing.assert_allclose(df[:, 1], left @ g_floor, rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(df[:, 2], 0.0)


def test_position_dependence_damps_inside_the_patch_only():
    v = 0.4
    fx = EFFECTS["position_dependence"].fixed
    c, r = np.array(fx["patch_center_local_m"]), fx["patch_radius_m"]
    dyn_e, dyn = TrueDynamics(effect=Effect("position_dependence", v)), TrueDynamics()
    pts = np.array([c, c + [r, 0], c + [r + 1.0, 0], c + [0, r - 1.0]])
    x6 = np.column_stack([pts, np.zeros(4), np.full(4, 0.5), np.zeros(4), np.full(4, 0.4)])
    df = dyn_e.accel(x6, [0.5, 0.2]) - dyn.accel(x6, [0.5, 0.2])
    share = df[:, 0] / (-v * 7.770 * 0.5)
    np.testing.assert_allclose(share, [1.0, 0.5, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(df[:, 2] / (-v * 6.951 * 0.4), share, atol=1e-6)


def test_lateral_slip_multiplies_the_steady_sideways_drift():
    v = 4.0
    for effect, gain in ((None, 1.0), (Effect("lateral_slip", v), v)):
        dyn = TrueDynamics(effect=effect)
        vy_ss = -gain * 0.6 * 0.5 / 15.0  # -gain vx omega / k_y
        assert dyn.accel([0, 0, 0, 0.6, vy_ss, 0.5], [0.6, 0.4])[1] == pytest.approx(0.0, abs=1e-12)


# --- every effect changes a run, visibly but moderately -----------------------------------

@pytest.fixture(scope="module")
def plain_run():
    return simulate_run(25.0, np.random.default_rng(9), start_pose=(4.4, 3.6, 0.7))


@pytest.mark.parametrize("name", FAMILIES)
def test_each_effect_changes_the_run(name, plain_run):
    """Same seed, effect on: the trajectory departs from the plain one (patch start inside)."""
    run = simulate_run(25.0, np.random.default_rng(9), effect=Effect(name, EFFECTS[name].moderate),
                       start_pose=(4.4, 3.6, 0.7))
    gap = np.hypot(run.x - plain_run.x, run.y - plain_run.y)
    assert gap.max() > 0.01
    np.testing.assert_array_equal(run.t_joy, plain_run.t_joy)  # same joystick clock


def test_heading_effect_tilts_pitch_and_floor_height():
    tilt = 2.0
    run = simulate_run(10.0, np.random.default_rng(2), effect=Effect("heading_dependence", tilt))
    np.testing.assert_allclose(run.z, -math.tan(math.radians(tilt)) * run.x)
    plain = simulate_run(10.0, np.random.default_rng(2))
    extra = np.radians(tilt) * np.cos(run.psi)
    assert np.abs(run.pitch - extra).max() < 0.04  # the rest is the suspension's few tenths deg
    assert np.abs(np.mean(run.pitch - plain.pitch) - np.mean(extra)) < 0.01


@pytest.mark.parametrize("name", FAMILIES)
def test_strongest_effect_keeps_the_run_sane(name):
    """At the top of its range every effect still gives a bounded run inside the area."""
    from simulation.driver import DrivingArea
    from simulation.robot import RobotParams

    run = simulate_run(60.0, np.random.default_rng(4), effect=Effect(name, EFFECTS[name].valid_range[1]))
    p = RobotParams()
    assert DrivingArea().contains(run.x, run.y).all()
    assert np.degrees(np.abs(run.psi - run.psi[0])).max() < 150.0
    assert np.abs(run.vx).max() < p.max_speed_m_s and np.abs(run.omega).max() < p.guard_omega_rad_s + 0.1
