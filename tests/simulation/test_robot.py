"""Tests of the simulated Husky: model B verbatim, Jacobians, integrator, physics of a run."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from simulation.driver import DrivingArea
from simulation.effects import EFFECTS, Effect
from simulation.robot import TrueDynamics, pitch_from_accel, simulate_run
from simulation.robot_params import RobotParams, exponents_from_name
from tests.support.robot_synth import random_states

ALL_EFFECTS = [None] + [Effect(n, s.moderate) for n, s in EFFECTS.items()]


@pytest.fixture(scope="module")
def run():
    """A 150 s run of the plain robot (seed 7)."""
    return simulate_run(150.0, np.random.default_rng(7))


# --- model B is the thesis's ---------------------------------------------------------------

def _thesis_equation(text: str, number: str) -> dict[str, float]:
    """Parse ``{feature: coefficient}`` of a thesis equation like (7.7) from its LaTeX."""
    line = next(ln for ln in text.splitlines() if f"\\quad ({number})" in ln)
    body = line.split("=", 1)[1].split("\\end{aligned}")[0].replace("&", " ").replace("\\\\", " ")
    body = body.replace("\\omega", "omega").replace("v_x", "vx").replace("v_y", "vy")
    body = body.replace("u_1", "u1").replace("u_2", "u2")
    out = {}
    for sign, coef, mono in re.findall(r"([+-])\s*(\d+\.\d+)\s*((?:(?:vx|vy|omega|u1|u2)(?:\^\d)?\s*)+)",
                                       " + " + body.strip()):
        out[exponents_from_name(mono.strip())] = float(sign + coef)
    return out


def test_model_b_coefficients_are_the_thesis_equations(shared_dir):
    """Eqs. 7.7 and 7.9 parsed from the thesis text equal the simulator's term tables."""
    text = (shared_dir / "thesis" / "000_5587118689ad256f.txt").read_text()
    terms = TrueDynamics().true_terms()
    for key, eq in (("vx", "7.7"), ("omega", "7.9")):
        thesis = _thesis_equation(text, eq)
        ours = {exponents_from_name(n): c for n, c in terms[key].items()}
        assert len(thesis) == (13 if key == "vx" else 17)
        assert ours == thesis


def test_true_terms_reproduce_f_through_pysindy_features():
    """pysindy's PolynomialLibrary features times true_terms() equal f (no effect, no limiter)."""
    import pysindy as ps

    rng = np.random.default_rng(3)
    x6 = random_states(rng, 400)
    u = rng.uniform(-1, 1, (400, 2))
    lib = ps.PolynomialLibrary(degree=3).fit(np.zeros((2, 5)))
    theta = lib.transform(np.column_stack([x6[:, 3:], u]))
    names = lib.get_feature_names(["vx", "vy", "omega", "u1", "u2"])
    dyn = TrueDynamics()
    f = dyn.accel(x6, u, 0.0)
    for i, key in enumerate(("vx", "vy", "omega")):
        xi = np.array([dyn.true_terms()[key].get(n, 0.0) for n in names])
        assert set(dyn.true_terms()[key]) <= set(names)
        np.testing.assert_allclose(np.asarray(theta) @ xi, f[:, i], rtol=1e-12, atol=1e-12)


def test_model_b_steady_states_match_table_3_1():
    """Constant inputs over the square settle, the fastest at 0.81 m/s <= 1.0 m/s (table 3.1)."""
    dyn = TrueDynamics()
    g = np.linspace(-1, 1, 9)
    u = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    x6 = np.zeros((len(u), 6))
    for _ in range(5000):  # 10 s of explicit Euler, 2 ms (slow near the fold at u1 = +-1)
        x6[:, 3:] += 0.002 * dyn.accel(x6, u)
    assert np.abs(dyn.accel(x6, u)).max() < 1e-5  # settled
    assert 0.75 < np.abs(x6[:, 3]).max() <= RobotParams().max_speed_m_s
    assert np.all(np.sign(x6[:, 3]) == np.sign(np.round(u[:, 0], 9)))  # throttle sign -> direction
    assert np.all(np.sign(x6[:, 5]) == np.sign(np.round(u[:, 1], 9)))  # steering left -> omega > 0
    # lateral law: outward drift vx omega / k_y in turns
    np.testing.assert_allclose(x6[:, 4], -x6[:, 3] * x6[:, 5] / 15.0, atol=1e-6)


def test_speed_limiter_bounds_states_model_b_would_blow_up():
    """Far outside the envelope (fast reverse right turn, full forward left) stays bounded."""
    dyn = TrueDynamics()
    x6 = np.array([[0, 0, 0, -0.3, 0, -1.0]], float)
    u = np.array([[1.0, 1.0]])
    for _ in range(3000):
        x6[:, 3:] += 0.002 * dyn.accel(x6, u)
    assert np.abs(x6[0, 3]) < 1.5 and np.abs(x6[0, 5]) < 1.8


# --- Jacobians -------------------------------------------------------------------------------

@pytest.mark.parametrize("effect", ALL_EFFECTS, ids=lambda e: e.name if e else "none")
def test_jacobians_match_central_differences(effect):
    rng = np.random.default_rng(11)
    x6 = random_states(rng, 60, track_max=1.3, w_max=1.6)  # includes the limiter's range
    if effect is not None and effect.name == "position_dependence":  # around the patch edge
        c = np.array(EFFECTS["position_dependence"].fixed["patch_center_local_m"])
        ang = rng.uniform(0, 2 * np.pi, 60)
        x6[:, :2] = c + rng.uniform(0.3, 1.8, 60)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    u = rng.uniform(-1, 1, (60, 2))
    dyn = TrueDynamics(effect=effect)
    h = 1e-6
    J_num_x = np.stack([(dyn.accel(x6 + h * e, u) - dyn.accel(x6 - h * e, u)) / (2 * h) for e in np.eye(6)], -1)
    J_num_u = np.stack([(dyn.accel(x6, u + h * e) - dyn.accel(x6, u - h * e)) / (2 * h) for e in np.eye(2)], -1)
    _, J_x, J_u = dyn.accel_and_jacobians(x6, u, 0.0)
    np.testing.assert_allclose(J_x, J_num_x, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(J_u, J_num_u, rtol=1e-6, atol=1e-6)
    assert J_x.shape == (60, 3, 6) and J_u.shape == (60, 3, 2)


def test_accel_and_jacobians_broadcast_over_leading_axes():
    dyn = TrueDynamics()
    rng = np.random.default_rng(0)
    x6 = random_states(rng, 12).reshape(3, 4, 6)
    u = np.array([0.3, -0.2])
    assert dyn.accel(x6, u).shape == (3, 4, 3)
    assert dyn.accel_and_jacobians(x6, u)[1].shape == (3, 4, 3, 6)
    np.testing.assert_allclose(dyn.accel(x6, u)[1, 2], dyn.accel(x6[1, 2], u))
    assert dyn.accel(np.zeros(6), np.zeros(2)).shape == (3,)


def test_pitch_is_second_order_response_to_acceleration():
    """A braking step of -1 m/s^2 settles at +0.5 deg (nose down), overshooting (zeta = 0.5)."""
    p = RobotParams()
    ax = np.r_[np.zeros(100), -np.ones(2000)]
    pitch = pitch_from_accel(ax, 0.002, p)
    assert pitch[99] == 0.0
    np.testing.assert_allclose(pitch[-1], math.radians(0.5), rtol=1e-6)
    assert 1.1 < pitch.max() / math.radians(0.5) < 1.25  # overshoot exp(-pi zeta / sqrt(1-zeta^2)) = 16 %


# --- a simulated run -------------------------------------------------------------------------

def test_run_physics_is_sane(run):
    area = DrivingArea()
    assert np.abs(run.vx).max() <= RobotParams().max_speed_m_s + 0.02
    p = RobotParams()  # limiters idle: the run stays in model B's envelope
    assert (np.abs(run.vx) + p.track_half_width_m * np.abs(run.omega)).max() < p.guard_track_speed_m_s
    assert np.abs(run.omega).max() < RobotParams().guard_omega_rad_s
    assert 0.5 < np.abs(run.vx).max() and 0.005 < np.abs(run.vy).max() < 0.06
    assert np.abs(run.ax).max() < 8.0
    assert np.degrees(np.abs(run.psi - run.psi[0]).max()) < 150.0
    assert area.contains(run.x, run.y).all()
    assert 0.2 < np.degrees(np.abs(run.pitch).max()) < 3.0
    # at low frequency pitch = -k_p a_x (nose dips when braking): regress 0.5 s means
    k = np.ones(250) / 250
    p_lo, a_lo = np.convolve(run.pitch, k, "valid"), np.convolve(run.ax, k, "valid")
    slope = np.polyfit(-a_lo, p_lo, 1)[0]
    assert slope == pytest.approx(RobotParams().pitch_per_accel_rad, rel=0.15)
    assert np.corrcoef(p_lo, -a_lo)[0, 1] > 0.9
    np.testing.assert_array_equal(run.z, 0.0)  # level floor, pitch about the origin
    assert np.all(np.abs(run.u_motor) <= 1.0)


def test_run_obeys_eq_5_75_kinematics_and_grid(run):
    dt = 0.002
    np.testing.assert_allclose(np.diff(run.t), dt, atol=1e-12)
    mid = lambda a: 0.5 * (a[1:] + a[:-1])  # noqa: E731
    c, s = np.cos(mid(run.psi)), np.sin(mid(run.psi))
    vx, vy = mid(run.vx), mid(run.vy)
    np.testing.assert_allclose(np.diff(run.x) / dt, vx * c - vy * s, atol=2e-4)
    np.testing.assert_allclose(np.diff(run.y) / dt, vx * s + vy * c, atol=2e-4)
    np.testing.assert_allclose(np.diff(run.psi) / dt, mid(run.omega), atol=2e-4)


def test_run_velocity_follows_f_plus_small_noise(run):
    """Finite-difference accelerations match f on the motor inputs up to the OU process noise."""
    dyn = TrueDynamics()
    x6 = np.column_stack([run.x, run.y, run.psi, run.vx, run.vy, run.omega])
    a_fd = np.diff(x6[:, 3:], axis=0) / 0.002
    resid = a_fd - dyn.accel(0.5 * (x6[1:] + x6[:-1]), run.u_motor[:-1])
    std = np.asarray(RobotParams().accel_noise_std)
    np.testing.assert_allclose(resid.std(axis=0), std, rtol=0.25)
    assert np.all(np.abs(resid.mean(axis=0)) < 0.2 * std)


def test_motor_inputs_are_zero_order_hold_of_joystick(run):
    dyn = TrueDynamics()
    idx = np.searchsorted(run.t_joy, run.t, side="right") - 1
    expect = np.where((idx >= 0)[:, None], run.u_joy[np.maximum(idx, 0)], 0.0)
    np.testing.assert_array_equal(run.u_motor, expect)
    np.testing.assert_array_equal(dyn.motor_inputs(run.t, run.t_joy, run.u_joy), expect)


def test_same_seed_same_run_other_seed_other_run():
    a = simulate_run(8.0, np.random.default_rng(42))
    b = simulate_run(8.0, np.random.default_rng(42))
    c = simulate_run(8.0, np.random.default_rng(43))
    for name in ("t", "x", "y", "psi", "vx", "vy", "omega", "pitch", "z", "ax", "u_motor", "t_joy", "u_joy"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.x, c.x)


def test_start_pose_is_honoured():
    r = simulate_run(2.0, np.random.default_rng(1), start_pose=(3.0, 2.0, 0.5), dt=0.004)
    assert (r.x[0], r.y[0], r.psi[0]) == (3.0, 2.0, 0.5)
    assert r.t.size == 501 and r.t[-1] == pytest.approx(2.0)


@pytest.mark.parametrize("kwargs, culprit", [
    ({"duration_s": -5.0}, "duration_s=-5.0"),
    ({"duration_s": 2.0, "dt": 0.5}, "dt=0.5"),
    ({"duration_s": 2.0, "effect": "input_delay=0.1"}, "effect='input_delay=0.1'"),
])
def test_simulate_run_bad_arguments_are_named(kwargs, culprit):
    from groundfloor.errors import InputError

    with pytest.raises(InputError, match=re.escape(culprit)):
        simulate_run(rng=np.random.default_rng(0), **kwargs)
