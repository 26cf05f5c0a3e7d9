"""Unit tests of the measurement set-up: trigger and clocks, edges, pulses, dropouts, noise, hubs.

Each property is checked against something independent: hand-built geometry, exact integer
arithmetic, brute-force loops, analytic trajectories, statistics of many draws.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from groundfloor.errors import InputError
from simulation.clocks import (
    NS,
    SKIP_EVERY,
    TrackerClock,
    simulate_trigger,
    stamp_tracker,
)
from simulation.hubs import (
    azimuth_from_points,
    baseline_geometry,
    eccentric_offset_body,
    hub_angle,
    hub_commands,
)
from simulation.measurement import (
    AT960,
    LTD800,
    add_point_noise,
    check_fraction,
    in_intervals,
    simulate_dropouts,
    simulate_duty_cycle,
    simulate_lost,
    simulate_spurious,
)
from simulation.tracker_run import Trajectory

LEVER_FRONT = np.array([0.4671355, 0.0655364, 0.5167336])  # thesis table 7.1
LEVER_REAR = np.array([-0.2600713, -0.1627405, 0.6546911])


def test_tracker_clock_round_trip_keeps_nanoseconds():
    """Tracker time and back, with t0 and d ~ 1.7e9 s apart from 0: exact to 1 ns."""
    clock = TrackerClock(k=1 + 16.2395e-6, d_ns=1_671_590_000_123_456_789)
    t0_ns = 1_671_615_000_000_000_000
    t_rel = np.linspace(0.0, 470.0, 1001)
    t_tr = clock.tracker_s_from_rel(t_rel, t0_ns)
    # eq. 5.10 by exact integer-nanosecond arithmetic (independent of the float path)
    t_utc_ns = t0_ns + np.rint(t_rel * NS).astype(np.int64)
    expected = (t_utc_ns - clock.d_ns) / NS / clock.k
    assert np.max(np.abs(t_tr - expected)) < 1e-9
    assert np.max(np.abs(clock.rel_from_tracker_s(t_tr, t0_ns) - t_rel)) < 1e-9
    assert clock.drift_ppm == pytest.approx(16.2395, abs=1e-9)


def test_stamps_are_on_the_clock_resolution_and_within_the_timing_noise():
    rng = np.random.default_rng(0)
    clock = TrackerClock(k=1 - 28.5e-6, d_ns=1_671_600_000_000_000_000)
    t0_ns = 1_671_615_000_000_000_000
    t = np.sort(rng.uniform(0, 100, 20000))
    stamp = stamp_tracker(clock, t, t0_ns, rng, timing_std_s=AT960.timing_std_s, resolution_s=AT960.resolution_s)
    assert np.all(stamp % 100 == 0)  # 0.1 us ticks
    err = clock.rel_from_tracker_s(stamp * 1e-9, t0_ns) - t
    assert abs(err.mean()) < 1e-7 and err.std() == pytest.approx(2e-6, rel=0.05)


def test_trigger_skips_one_slot_in_150_and_runs_at_50_hz():
    rng = np.random.default_rng(3)
    trig = simulate_trigger(0.7, 61.0, 1_671_615_000_000_000_000, rng)
    n_slots = int(round(61.0 / 0.02))
    all_slots = np.arange(n_slots)
    skipped = np.setdiff1d(all_slots, trig.slot)
    assert np.all(np.diff(skipped) == SKIP_EVERY) and len(skipped) in (n_slots // 150, n_slots // 150 + 1)
    dt = np.diff(trig.time_ref_ns) * 1e-9
    gap = dt > 0.035  # the thesis's gap threshold
    assert gap.sum() == len(skipped) - (skipped[0] == 0) - (skipped[-1] == n_slots - 1)
    assert np.median(dt[~gap]) == pytest.approx(0.02, abs=1e-5)
    assert np.all(np.diff(np.flatnonzero(gap)) == SKIP_EVERY - 1)  # one gap every 3 s
    # time_ref is the edge to sub-microsecond, header.stamp a few hundred microseconds later
    edge_ns = 1_671_615_000_000_000_000 + trig.t_rise_rel * NS
    assert np.max(np.abs(trig.time_ref_ns - edge_ns)) < 1.5e3
    assert np.all((trig.t_publish_rel - trig.t_rise_rel > 1e-4) & (trig.t_publish_rel - trig.t_rise_rel < 1e-3))


def test_duty_cycle_lost_and_spurious_statistics():
    rng = np.random.default_rng(5)
    duty = simulate_duty_cycle(200_000, 1.3537e-3, rng)
    assert duty.mean() == pytest.approx(1.3537e-3, abs=1e-6) and duty.std() == pytest.approx(30e-6, rel=0.05)
    lost = simulate_lost(200_000, 0.006, rng)
    assert abs(lost.mean() - 0.006) < 5 * np.sqrt(0.006 / 200_000)
    t_rise = np.arange(100_000) * 0.02
    spur = simulate_spurious(t_rise, 0.003, rng)
    assert abs(spur.size - 300) < 5 * np.sqrt(300)
    assert np.all(np.diff(spur) >= 0) and spur[0] >= t_rise[0] and spur[-1] <= t_rise[-1]


def test_dropouts_do_not_overlap_and_stay_within_limits():
    for seed in range(40):
        rng = np.random.default_rng(seed)
        iv = simulate_dropouts(1.0, 1.0 + 300.0, rng)
        assert len(iv) >= 1
        length = iv[:, 1] - iv[:, 0]
        assert np.all(length > 0) and np.all(length <= 5.0 + 1e-12) and length.sum() <= 0.2 * 300 + 1e-9
        assert np.all(iv[1:, 0] >= iv[:-1, 1])


def test_in_intervals_matches_a_brute_force_loop():
    rng = np.random.default_rng(8)
    iv = simulate_dropouts(0.0, 100.0, rng, per_minute=5.0)
    t = rng.uniform(-2, 102, 5000)
    brute = np.array([any(a <= ti < b for a, b in iv) for ti in t])
    assert np.array_equal(in_intervals(t, iv), brute)
    assert not in_intervals(t, np.zeros((0, 2))).any()


def test_point_noise_follows_table_3_2():
    rng = np.random.default_rng(11)
    p = np.tile([6.0, 0.0, -0.6], (100_000, 1))
    r = np.linalg.norm(p[0])
    for spec in (AT960, LTD800):
        e = add_point_noise(p, spec, rng) - p
        assert e.std(axis=0) == pytest.approx(np.full(3, spec.noise_a_m + spec.noise_b * r), rel=0.02)
    assert 5e-6 < AT960.noise_a_m + AT960.noise_b * 4 < 15e-6 and 5e-6 < LTD800.noise_a_m + LTD800.noise_b * 4 < 15e-6


def test_check_fraction_names_the_culprit():
    with pytest.raises(InputError, match="lost_fraction=1.5"):
        check_fraction("lost_fraction", 1.5)


def test_azimuth_eq_4_6_on_hand_built_geometry():
    """Baseline along +x; the tracker straight left of the prism is 90 deg clockwise: -pi/2."""
    d = 5.0
    x_self = np.array([[0.0, -d, -0.6]])  # prism seen from the tracker at the origin
    assert azimuth_from_points(x_self, x_self + [0.77, 0, 0.1])[0] == pytest.approx(-np.pi / 2)
    # tracker straight ahead along the baseline: 0; behind: pi
    assert azimuth_from_points(np.array([[-d, 0, 0]]), np.array([[-d + 0.77, 0, 0]]))[0] == pytest.approx(0.0)
    assert abs(azimuth_from_points(np.array([[d, 0, 0]]), np.array([[d + 0.77, 0, 0]]))[0]) == pytest.approx(np.pi)


def test_azimuth_is_invariant_to_rotating_the_scene_about_the_vertical():
    rng = np.random.default_rng(2)
    a, b = rng.uniform(-8, 8, (500, 3)), rng.uniform(-8, 8, (500, 3))
    g = 0.83
    Rz = np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
    assert np.allclose(azimuth_from_points(a, b), azimuth_from_points(a @ Rz.T, b @ Rz.T))


def test_eccentricity_gives_eq_5_25_baseline_variation():
    """|front + e_f - rear - e_r| - |front - rear| = r_f' cos(phi_f + Phi_f) + r_r' cos(phi_r + Phi_r)."""
    rng = np.random.default_rng(4)
    phi_f, phi_r = rng.uniform(-np.pi, np.pi, (2, 1000))
    Phi_f, Phi_r, r_f, r_r = 0.4, -2.1, 0.21e-3, 0.12e-3
    beta_f, cos_elev = baseline_geometry(LEVER_FRONT, LEVER_REAR)
    beta_r, _ = baseline_geometry(LEVER_REAR, LEVER_FRONT)
    e_f = eccentric_offset_body(phi_f, r_f, Phi_f, beta_f)
    e_r = eccentric_offset_body(phi_r, r_r, Phi_r, beta_r)
    c = np.linalg.norm(LEVER_FRONT - LEVER_REAR)
    dl = np.linalg.norm(LEVER_FRONT + e_f - LEVER_REAR - e_r, axis=1) - c
    model = cos_elev * (r_f * np.cos(phi_f + Phi_f) + r_r * np.cos(phi_r + Phi_r))
    assert np.max(np.abs(dl - model)) < 1e-7  # second order: r^2 / c
    assert np.allclose(np.linalg.norm(e_f, axis=1), r_f) and np.all(e_f[:, 2] == 0)


def test_hub_commands_use_the_latest_arrived_samples_and_hold():
    t_self = np.array([0.0, 0.1, 0.2])
    x_self = np.array([[0.0, -5, 0], [-5.0, 0, 0], [5.0, 0, 0]])
    other = np.array([[0.77, 0.0, 0.0]])
    phi = hub_commands(np.array([-0.05, 0.05, 0.15, 0.5]), t_self, x_self, np.array([0.0]), other + [[0, -5, 0]])
    assert np.isnan(phi[0])
    assert phi[1] == pytest.approx(azimuth_from_points(x_self[:1], other + [[0, -5, 0]])[0])
    assert phi[3] == pytest.approx(azimuth_from_points(x_self[2:], other + [[0, -5, 0]])[0])
    held = hub_angle(np.array([-1.0, 0.5, 2.0]), np.array([0.0, 1.0]), np.array([0.3, 0.7]))
    assert np.allclose(held, [0.3, 0.3, 0.7])


def test_trajectory_interpolation_is_exact_on_a_circle():
    """Constant speed and yaw rate: the analytic circle, sampled at 2 ms, queried in between."""
    v, w, dt = 1.2, 0.8, 0.002
    t = np.arange(0, 10, dt)
    psi = 0.3 + w * t
    run = SimpleNamespace(t=t, x=3 + v / w * (np.sin(psi) - np.sin(0.3)), y=2 - v / w * (np.cos(psi) - np.cos(0.3)),
                          psi=psi, vx=np.full_like(t, v), vy=0 * t, omega=np.full_like(t, w), z=0 * t,
                          pitch=0 * t, u_motor=np.zeros((t.size, 2)))
    traj = Trajectory(run, z0=-1.25)
    tq = np.random.default_rng(1).uniform(0.1, 9.9, 2000)
    p, psi_q, _ = traj.pose(tq)
    psi_true = 0.3 + w * tq
    assert np.max(np.abs(p[:, 0] - (3 + v / w * (np.sin(psi_true) - np.sin(0.3))))) < 1e-8
    assert np.max(np.abs(psi_q - psi_true)) < 1e-9 and np.allclose(p[:, 2], -1.25)
    # the prism: body origin plus the rotated lever arm
    prism = traj.prism_local(tq, LEVER_FRONT)
    c, s = np.cos(psi_true), np.sin(psi_true)
    assert np.allclose(prism[:, 0] - p[:, 0], c * LEVER_FRONT[0] - s * LEVER_FRONT[1], atol=1e-9)
    assert np.allclose(prism[:, 2], -1.25 + LEVER_FRONT[2])


def test_bulk_serialisation_equals_rosbags_message_by_message():
    """Every message of each bulk-packed topic equals rosbags' own serialize_ros1."""
    from simulation import bags

    ts = bags.typestore()
    rng = np.random.default_rng(9)
    n = 40
    stamp = np.sort(rng.integers(1_671_615_000 * NS, 1_671_616_000 * NS, n))
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]

    def header(i, frame=""):
        return H(seq=i, stamp=T(sec=int(stamp[i] // NS), nanosec=int(stamp[i] % NS)), frame_id=frame)

    xyz, u, pos = rng.normal(size=(n, 3)), rng.uniform(-1, 1, (n, 2)), rng.normal(size=(n, 2))
    u[3] = 0.0
    M = ts.types
    cases = [
        (bags.serialize_point_stamped(stamp, xyz, "ltd800"), "geometry_msgs/msg/PointStamped",
         lambda i: M["geometry_msgs/msg/PointStamped"](header(i, "ltd800"), M["geometry_msgs/msg/Point"](*xyz[i]))),
        (bags.serialize_time_reference(stamp, stamp - 400_000, "gnss_pps"), "sensor_msgs/msg/TimeReference",
         lambda i: M["sensor_msgs/msg/TimeReference"](header(i), T(sec=int((stamp[i] - 400_000) // NS),
                                                                     nanosec=int((stamp[i] - 400_000) % NS)), "gnss_pps")),
        (bags.serialize_joint_state(stamp, ["front", "rear"], pos), "sensor_msgs/msg/JointState",
         lambda i: M["sensor_msgs/msg/JointState"](header(i), ["front", "rear"], pos[i], np.zeros(0), np.zeros(0))),
    ]
    for raw, msgtype, build in cases:
        assert all(raw[i] == bytes(ts.serialize_ros1(build(i), msgtype)) for i in range(n)), msgtype
    joy = bags.serialize_joy(stamp, u)
    for i in range(n):
        m = ts.deserialize_ros1(joy[i], "sensor_msgs/msg/Joy")
        assert m.header.seq == i and m.axes[1] == np.float32(u[i, 0]) and m.axes[0] == np.float32(u[i, 1])
        assert m.buttons[bags.JOY_ENABLE_BUTTON] == (i != 3) and bytes(ts.serialize_ros1(m, "sensor_msgs/msg/Joy")) == joy[i]
