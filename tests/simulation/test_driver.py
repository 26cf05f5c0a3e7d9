"""Tests of the human-like driver: joystick clock, coverage, constraints, supervisor, thumb."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulation.driver import DrivingArea, HumanDriver, simulate_joy_stamps
from simulation.robot import RobotParams, TrueDynamics, simulate_run

AREA = DrivingArea()


@pytest.fixture(scope="module")
def runs():
    """Three 100 s runs of the plain robot (seeds 21 to 23)."""
    return [simulate_run(100.0, np.random.default_rng(s)) for s in (21, 22, 23)]


def test_joystick_stamps_look_like_a_bluetooth_joy_node():
    t = simulate_joy_stamps(600.0, np.random.default_rng(0))
    dt = np.diff(t)
    assert t[0] >= 0 and t[-1] < 600.0 and np.all(dt > 0)
    assert np.median(dt) == pytest.approx(0.05, abs=0.003)  # 20 Hz
    assert 0.003 < np.std(dt[dt < 0.09]) < 0.01  # jitter
    gaps = dt[dt > 0.13]
    assert 30 < gaps.size < 250 and gaps.max() < 0.4  # ~1 % of messages, 100-300 ms late


def test_area_geometry():
    c = np.array(AREA.center_local_m)
    ax = np.array([math.cos(AREA.axis_angle_rad), math.sin(AREA.axis_angle_rad)])
    across = np.array([-ax[1], ax[0]])
    pts = np.array([c, c + 2.9 * ax, c - 2.9 * ax, c + 3.1 * ax, c + 1.7 * across,
                    c - 1.9 * across, (0.0, 0.0), (6.93, 5.73)])
    np.testing.assert_array_equal(AREA.contains(pts[:, 0], pts[:, 1]),
                                  [True, True, True, False, True, False, False, False])
    assert np.hypot(*(c + 3.1 * ax - (6.93, 5.73))) < 1.5  # excluded by the keep-out disc


def test_runs_stay_inside_area_and_heading_limits(runs):
    for r in runs:
        assert AREA.contains(r.x, r.y).all()
        assert np.degrees(np.abs(r.psi - r.psi[0])).max() < 150.0
        # the driver uses the area, not only its middle
        assert AREA.ellipse_radius(r.x, r.y).max() > 0.6


def test_inputs_cover_the_square_like_fig_6_3(runs):
    u = np.concatenate([r.u_joy for r in runs])
    hist, _, _ = np.histogram2d(u[:, 0], u[:, 1], bins=5, range=[[-1, 1], [-1, 1]])
    assert (hist > 0).sum() >= 24  # of 25 cells
    assert (hist > 0.005 * len(u)).sum() >= 20
    assert np.mean(u[:, 0] > 0.15) > 0.2 and np.mean(u[:, 0] < -0.15) > 0.2  # forward and back
    assert np.mean((np.abs(u[:, 0]) < 0.1) & (np.abs(u[:, 1]) > 0.3)) > 0.03  # turning in place
    assert np.mean((np.abs(u[:, 0]) > 0.5) & (np.abs(u[:, 1]) > 0.5)) > 0.03  # combined
    v = np.concatenate([r.vx for r in runs])
    assert np.mean(v > 0.5) > 0.03 and np.mean(v < -0.5) > 0.03


def test_sign_flips_pass_through_a_neutral_rest(runs):
    """Every change of sign of an axis rests at |u| <= 0.15 for about 0.2 s or more first."""
    n_flips = 0
    for r in runs:
        for i in range(2):
            u, t = r.u_joy[:, i], r.t_joy
            big = np.flatnonzero(np.abs(u) > 0.15)
            flips = big[1:][np.sign(u[big[1:]]) != np.sign(u[big[:-1]])]
            prev = big[:-1][np.sign(u[big[1:]]) != np.sign(u[big[:-1]])]
            # time from the last big message of the old sign to the first of the new
            rest = t[flips] - t[prev + 1]
            n_flips += flips.size
            assert np.all(rest >= 0.2 - 1e-9)
    assert n_flips > 20


def test_neutral_rest_keeps_model_b_inside_its_envelope():
    """Steps between model B steady states stay below the speed limiter with the thumb's rest
    and leave the envelope without it (why the driver rests in neutral)."""
    dyn, p = TrueDynamics(), RobotParams()
    g = np.linspace(-1, 1, 7)
    u_ss = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    x = np.zeros((len(u_ss), 6))
    for _ in range(1500):
        x[:, 3:] += 0.004 * dyn.accel(x, u_ss)
    i, j = np.meshgrid(np.arange(len(u_ss)), np.arange(len(u_ss)), indexing="ij")
    u_old, u_new, x0 = u_ss[i.ravel()], u_ss[j.ravel()], x[i.ravel()]
    flip = (u_old * u_new) < 0
    peak = {}
    for rest_s in (0.0, 0.2):
        xs = x0.copy()
        top = np.zeros((len(xs), 2))
        for k in range(1000):  # 4 s at 4 ms
            u = np.where(flip & (k * 0.004 < rest_s), 0.0, u_new)
            xs[:, 3:] += 0.004 * dyn.accel(xs, u)
            track = np.abs(xs[:, 3]) + p.track_half_width_m * np.abs(xs[:, 5])
            top = np.maximum(top, np.column_stack([track, np.abs(xs[:, 5])]))
        peak[rest_s] = top.max(axis=0)
    assert peak[0.2][0] < p.guard_track_speed_m_s and peak[0.2][1] < p.guard_omega_rad_s
    assert peak[0.0][0] > p.guard_track_speed_m_s or peak[0.0][1] > p.guard_omega_rad_s


def test_supervisor_brings_the_robot_back_and_unwinds_the_heading():
    c = np.array(AREA.center_local_m)
    ax = np.array([math.cos(AREA.axis_angle_rad), math.sin(AREA.axis_angle_rad)])
    # near the LTD800 end, driving outwards at 0.6 m/s, heading along the axis
    drv = HumanDriver(np.random.default_rng(0), psi0=AREA.axis_angle_rad)
    x, y = c + 2.6 * ax
    u1, u2 = drv.command(10.0, x, y, AREA.axis_angle_rad, 0.6, 0.0, 0.0)
    assert drv.mode == "return"
    assert u1 <= 0.0  # stops or backs towards the centre, never drives on
    # heading 125 deg from its start and still turning left: the driver turns it back
    drv = HumanDriver(np.random.default_rng(0), psi0=0.0)
    u1, u2 = drv.command(10.0, *c, math.radians(125.0), 0.0, 0.0, 0.3)
    assert drv.mode == "unwind" and u2 < 0.0


def test_same_rng_same_commands():
    cmds = []
    for _ in range(2):
        drv = HumanDriver(np.random.default_rng(5), psi0=0.3)
        cmds.append([drv.command(0.05 * k, 3.4, 2.9, 0.3, 0.2, 0.0, 0.1) for k in range(400)])
    assert cmds[0] == cmds[1]
    assert len(set(cmds[0])) > 50


def test_plots_of_fig_6_3_and_6_4(runs, tmp_path):
    from simulation.figures import plot_driving_path, plot_input_density

    fig = plot_input_density(runs, tmp_path / "fig_6_3.png")
    counts = fig.axes[0].collections[0].get_array()
    assert np.nansum(counts) == sum(len(r.u_joy) for r in runs)  # every message in the square
    assert (tmp_path / "fig_6_3.png").stat().st_size > 10_000
    fig = plot_driving_path(runs[0], path=tmp_path / "fig_6_4.png")
    xy = fig.axes[0].lines[-2].get_xydata()
    np.testing.assert_array_equal(xy, np.column_stack([runs[0].x, runs[0].y]))
