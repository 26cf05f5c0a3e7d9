"""One simulated run as the instruments recorded it: true trajectory -> messages of both bags.

Time line of a run (``t_rel``, s after ``t0``): the robot simulation starts at 0 and the
robot's bag records from then on; the trigger starts ``lead`` later and runs for the run's
duration (table 6.4); the robot simulation goes on for ``TAIL_S`` after the last pulse so that
the AT960's falling edges and the last joystick messages are covered.

Latencies (bag time = receive time, UTC): trigger messages 0.2-1 ms after publishing, tracker
measurements 1-5 ms after the measured instant (server), hub commands 1-3 ms after
publishing, joystick 0.1-0.5 ms after its stamp, each topic received in publishing order. With
``RunSetup.receive_jitter_s`` every message gets its own latency instead (independent
generators, a recorder merging connections): two messages closer than the spread of the
latencies (a spurious AT960 pulse a few ms from a real one) are then received, and stored,
out of stamp order, as the data contract allows. The hub node sees a tracker measurement
3-12 ms after it was taken, publishes at ``HUB_RATE_HZ`` and a command moves the hub
``HUB_DELAY_S`` later.

``RunSetup.clock_reset`` restarts one tracker's clock during the run (a controller reboot): from
that instant its stamps come from a clock that read 1 s at the reset, a backward jump of hours.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from simulation import bags
from simulation.clocks import (
    NS,
    TRIGGER_PERIOD_S,
    TrackerClock,
    simulate_trigger,
    stamp_tracker,
)
from simulation.hubs import (
    baseline_geometry,
    eccentric_offset_body,
    hub_angle,
    hub_commands,
)
from simulation.measurement import (
    DUTY_JITTER_STD_S,
    in_intervals,
    simulate_dropouts,
    simulate_duty_cycle,
    simulate_lost,
    simulate_spurious,
)
from simulation.robot import simulate_run
from simulation.truth import RunTruth, TrueStates
from simulation.variant import Variant

TRIGGER_DEAD_TIME_S = 1e-3  # a tracker's trigger input registers no second edge within 1 ms

TAIL_S = 0.5
HUB_RATE_HZ = 15.0
HUB_DELAY_S = 0.03


@dataclass(frozen=True)
class RunSetup:
    """The true parameters of one run chosen by the campaign."""

    name: str
    split: str
    duration_s: float
    t0_ns: int  # UTC ns of the run's simulation start
    clocks: dict  # "at960"/"ltd800" -> TrackerClock
    at960_duty_mean_s: float
    lost_fraction: float
    spurious_fraction: float
    hub_radius_m: dict  # front/rear -> physical eccentricity radius
    hub_phase_rad: dict  # front/rear -> Phi of eq. 5.25
    lever_arms_m: dict  # front/rear -> (3,) body frame
    R_at960_ltd800: np.ndarray
    t_at960_ltd800: np.ndarray
    body_origin_z_m: float
    ntp_offset_s: float
    effect: object = None
    receive_jitter_s: tuple[float, float] | None = None  # (lo, hi) latency of every message
    clock_reset: tuple[str, float] | None = None  # (tracker, fraction of the trigger span)
    variant: Variant = field(default_factory=Variant)  # robot, driver and tracker noise


class Trajectory:
    """Interpolates a true run at arbitrary times: cubic Hermite for x, y, psi, linear else.

    The Hermite slopes are the exact derivatives (eq. 5.75 kinematics and omega), so positions
    between the 2 ms integration steps are accurate to well below a micrometre.
    """

    def __init__(self, run, z0: float):
        t = np.asarray(run.t, float)
        c, s = np.cos(run.psi), np.sin(run.psi)
        self.t = t
        self.run = run
        self.z0 = z0
        self._x = CubicHermiteSpline(t, run.x, run.vx * c - run.vy * s)
        self._y = CubicHermiteSpline(t, run.y, run.vx * s + run.vy * c)
        self._psi = CubicHermiteSpline(t, run.psi, run.omega)

    def lin(self, name: str, t: np.ndarray) -> np.ndarray:
        """Return field ``name`` of the true run linearly interpolated at ``t``."""
        return np.interp(t, self.t, np.asarray(getattr(self.run, name), float))

    def pose(self, t: np.ndarray):
        """Return ``(p_origin_local (n, 3), psi, pitch)`` at ``t``."""
        p = np.column_stack([self._x(t), self._y(t), self.z0 + self.lin("z", t)])
        return p, self._psi(t), self.lin("pitch", t)

    def prism_local(self, t: np.ndarray, lever_body: np.ndarray, offset_body: np.ndarray | None = None) -> np.ndarray:
        """Return (n, 3) prism positions in the local frame: ``p + Rz(psi) Ry(pitch) (lever + offset)``."""
        p, psi, pitch = self.pose(t)
        v = np.broadcast_to(lever_body, p.shape).copy()
        if offset_body is not None:
            v += offset_body
        cp, sp = np.cos(pitch), np.sin(pitch)
        vx, vz = cp * v[:, 0] + sp * v[:, 2], -sp * v[:, 0] + cp * v[:, 2]
        cy, sy = np.cos(psi), np.sin(psi)
        return p + np.column_stack([cy * vx - sy * v[:, 1], sy * vx + cy * v[:, 1], vz])

    def states_at(self, t: np.ndarray) -> dict:
        """Return the true states at ``t`` (inputs as the motors saw them: last value held)."""
        p, psi, pitch = self.pose(t)
        i = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1)
        u = np.asarray(self.run.u_motor, float)[i]
        return dict(x=p[:, 0], y=p[:, 1], z=p[:, 2], psi=psi, pitch=pitch, vx=self.lin("vx", t),
                    vy=self.lin("vy", t), omega=self.lin("omega", t), u1=u[:, 0], u2=u[:, 1])


def _monotonic(t: np.ndarray) -> np.ndarray:
    return np.maximum.accumulate(t) if len(t) else t


def _ns(t0_ns: int, t_rel: np.ndarray) -> np.ndarray:
    return np.int64(t0_ns) + np.rint(np.asarray(t_rel) * NS).astype(np.int64)


def count_reordered(stamp_ns: np.ndarray, t_receive_ns: np.ndarray) -> int:
    """Return how many messages of a topic are stored right after one with a later stamp.

    Stored order is receive order (ties in message order, as :func:`simulation.bags.write_bag`
    writes them); only backward steps shorter than half a trigger period count (data contract:
    a longer one is a clock reset).
    """
    order = np.argsort(np.asarray(t_receive_ns), kind="stable")
    step = np.diff(np.asarray(stamp_ns, dtype=np.int64)[order])
    return int(np.sum((step < 0) & (step > -0.5 * TRIGGER_PERIOD_S * NS)))


def _reset_clock(setup: RunSetup, t_first: float, t_last: float) -> tuple[str, float, TrackerClock] | None:
    """Return ``(tracker, t_reset_rel, clock after)`` of the run's clock reset, or None."""
    if setup.clock_reset is None:
        return None
    tracker, fraction = setup.clock_reset
    t_reset = t_first + fraction * (t_last - t_first)
    # the restarted clock reads 1 s at the reset, so that no stamp noise makes one negative
    d_ns = int(setup.t0_ns) + round(t_reset * NS) - NS
    return tracker, t_reset, TrackerClock(k=setup.clocks[tracker].k, d_ns=d_ns)


def _utc_intervals(t0_ns: int, intervals: np.ndarray) -> list:
    """Run-relative intervals (s) as UTC seconds (float, for truth.yaml)."""
    return (np.asarray(intervals) + t0_ns * 1e-9).tolist()


def simulate_tracker_run(setup: RunSetup, rng: np.random.Generator):
    """Return ``(husky_topics, server_topics, RunTruth)`` of one simulated run.

    Implements the measurement chain of thesis chapter 4 on a trajectory of
    ``simulation.robot.simulate_run``; see the module docstrings of
    :mod:`simulation.clocks`, :mod:`simulation.measurement` and :mod:`simulation.hubs`.
    """
    rng_robot, rng_meas = rng.spawn(2)
    lead = float(rng_meas.uniform(0.5, 1.5))
    true = simulate_run(lead + setup.duration_s + TAIL_S, rng_robot, effect=setup.effect, variant=setup.variant)
    at960, ltd800 = setup.variant.trackers()["at960"], setup.variant.trackers()["ltd800"]
    traj = Trajectory(true, setup.body_origin_z_m)
    trig = simulate_trigger(lead, setup.duration_s, setup.t0_ns, rng_meas)
    t_first, t_last = trig.t_rise_rel[0], trig.t_rise_rel[-1]
    R, t_vec = setup.R_at960_ltd800, setup.t_at960_ltd800
    lever = setup.lever_arms_m

    # --- which instants each tracker measures (edges, lost/spurious pulses, dropouts)
    n = trig.slot.size
    duty = simulate_duty_cycle(n, setup.at960_duty_mean_s, rng_meas)
    lost = simulate_lost(n, setup.lost_fraction, rng_meas)
    t_spur = simulate_spurious(trig.t_rise_rel, setup.spurious_fraction, rng_meas)
    drop = {k: simulate_dropouts(t_first, t_last, rng_meas) for k in ("at960", "ltd800")}
    in_drop_ltd = in_intervals(trig.t_rise_rel, drop["ltd800"])
    t_ltd = trig.t_rise_rel[~in_drop_ltd]  # LTD800: rising edge
    t_fall = trig.t_rise_rel + duty  # AT960: falling edge
    in_drop_at = in_intervals(t_fall, drop["at960"])
    # a trigger input has a dead time: a spurious pulse on top of a real one is not a second
    # measurement (and stamp noise could otherwise put the two out of order)
    k = np.clip(np.searchsorted(t_fall, t_spur), 1, t_fall.size - 1)
    near = np.minimum(np.abs(t_spur - t_fall[k - 1]), np.abs(t_spur - t_fall[k])) < TRIGGER_DEAD_TIME_S
    spur_ok = ~in_intervals(t_spur, drop["at960"]) & ~near
    t_at = np.concatenate([t_fall[~lost & ~in_drop_at], t_spur[spur_ok]])
    is_spur = np.concatenate([np.zeros((~lost & ~in_drop_at).sum(), bool), np.ones(spur_ok.sum(), bool)])
    order = np.argsort(t_at, kind="stable")
    t_at, is_spur = t_at[order], is_spur[order]

    # --- tracker stamps (own clocks) and noise draws (fixed across the hub iterations)
    stamp_ltd = stamp_tracker(setup.clocks["ltd800"], t_ltd, setup.t0_ns, rng_meas,
                              timing_std_s=ltd800.timing_std_s, resolution_s=ltd800.resolution_s)
    stamp_at = stamp_tracker(setup.clocks["at960"], t_at, setup.t0_ns, rng_meas,
                             timing_std_s=at960.timing_std_s, resolution_s=at960.resolution_s)
    reset = _reset_clock(setup, t_first, t_last)
    if reset is not None:
        # the same instants on the restarted clock: stamps shifted back by whole clock ticks
        tracker, t_reset, clock = reset
        stamp, t_ev, spec = (stamp_at, t_at, at960) if tracker == "at960" else (stamp_ltd, t_ltd, ltd800)
        tick_ns = round(spec.resolution_s * NS)
        shift_ns = round((clock.d_ns - setup.clocks[tracker].d_ns) / clock.k / tick_ns) * tick_ns
        stamp[t_ev >= t_reset] -= shift_ns
    z_ltd, z_at = rng_meas.normal(size=(t_ltd.size, 3)), rng_meas.normal(size=(t_at.size, 3))
    arrive_ltd = _monotonic(t_ltd + rng_meas.uniform(3e-3, 12e-3, t_ltd.size))
    arrive_at = _monotonic(t_at + rng_meas.uniform(3e-3, 12e-3, t_at.size))
    t_hub = t_first + np.arange(0.0, t_last - t_first, 1.0 / HUB_RATE_HZ)
    t_hub = _monotonic(t_hub + rng_meas.normal(0.0, 2e-3, t_hub.size))
    beta = {"front": baseline_geometry(lever["front"], lever["rear"])[0],
            "rear": baseline_geometry(lever["rear"], lever["front"])[0]}

    def measure(cmd):
        """Tracker points given hub commands (None: no eccentricity yet)."""
        out = {}
        for prism, tracker, t_ev, z, spec in (("front", "ltd800", t_ltd, z_ltd, ltd800),
                                              ("rear", "at960", t_at, z_at, at960)):
            off = None
            if cmd is not None:
                phi = hub_angle(t_ev, cmd["t"] + HUB_DELAY_S, cmd[prism])
                off = eccentric_offset_body(phi, setup.hub_radius_m[prism], setup.hub_phase_rad[prism], beta[prism])
            p_local = traj.prism_local(t_ev, lever[prism], off)
            p = p_local if tracker == "at960" else (p_local - t_vec) @ R  # R^T (x_at960 - t)
            rng_m = np.linalg.norm(p, axis=1, keepdims=True)
            out[tracker] = p + z * (spec.noise_a_m + spec.noise_b * rng_m)
        return out

    def commands(meas):
        """Hub commands from the measurements that reached the node (eqs. 4.1-4.6)."""
        ltd_in_at = meas["ltd800"] @ R.T + t_vec
        at_in_ltd = (meas["at960"] - t_vec) @ R
        front = hub_commands(t_hub, arrive_ltd, meas["ltd800"], arrive_at, at_in_ltd)
        rear = hub_commands(t_hub, arrive_at, meas["at960"], arrive_ltd, ltd_in_at)
        ok = np.isfinite(front) & np.isfinite(rear)
        return {"t": t_hub[ok], "front": front[ok], "rear": rear[ok]}

    # the eccentricity (0.2 mm) changes the azimuths by ~3e-4 rad: two fixed-point passes make
    # the published commands consistent with the published points to ~1e-7 rad
    cmd = commands(measure(None))
    cmd = commands(measure(cmd))
    meas = measure(cmd)

    # --- messages
    t0 = setup.t0_ns

    def received(t_rel: np.ndarray, latency_s: tuple[float, float]) -> np.ndarray:
        """Bag times (UTC ns): in publishing order, or each with its own latency (jitter)."""
        if setup.receive_jitter_s is None:
            return _ns(t0, _monotonic(t_rel + rng_meas.uniform(*latency_s, t_rel.size)))
        return _ns(t0, t_rel + rng_meas.uniform(*setup.receive_jitter_s, t_rel.size))

    server = [
        bags.TopicData("/rpi/trigger", "sensor_msgs/msg/TimeReference", "/rpi_trigger",
                       received(trig.t_publish_rel, (2e-4, 1e-3)),
                       bags.serialize_time_reference(_ns(t0, trig.t_publish_rel), trig.time_ref_ns, "gnss_pps")),
        bags.TopicData("/at960/measurement", "geometry_msgs/msg/PointStamped", "/at960_server",
                       received(t_at, (1e-3, 5e-3)),
                       bags.serialize_point_stamped(stamp_at, meas["at960"], "at960")),
        bags.TopicData("/ltd800/measurement", "geometry_msgs/msg/PointStamped", "/ltd800_server",
                       received(t_ltd, (1e-3, 5e-3)),
                       bags.serialize_point_stamped(stamp_ltd, meas["ltd800"], "ltd800")),
        bags.TopicData("/turning_hub/azimuth", "sensor_msgs/msg/JointState", "/turning_hub",
                       received(cmd["t"], (1e-3, 3e-3)),
                       bags.serialize_joint_state(_ns(t0, cmd["t"]), ["front", "rear"],
                                                  np.column_stack([cmd["front"], cmd["rear"]]))),
    ]
    t_joy = np.asarray(true.t_joy, float)
    u_joy = np.asarray(true.u_joy, float)
    stamp_joy = _monotonic(t_joy + setup.ntp_offset_s + rng_meas.normal(0.0, 30e-6, t_joy.size))
    husky = [bags.TopicData("/joy_teleop/joy", "sensor_msgs/msg/Joy", "/joy_teleop/joy_node",
                            received(stamp_joy, (1e-4, 5e-4)), bags.serialize_joy(_ns(t0, stamp_joy), u_joy))]
    stamps_ns = {"/rpi/trigger": trig.time_ref_ns, "/at960/measurement": stamp_at,
                 "/ltd800/measurement": stamp_ltd, "/turning_hub/azimuth": _ns(t0, cmd["t"]),
                 "/joy_teleop/joy": _ns(t0, stamp_joy)}
    reordered = {t.topic: count_reordered(stamps_ns[t.topic], t.t_receive_ns) for t in server + husky}

    # --- truth
    st = traj.states_at(trig.t_rise_rel)
    states = TrueStates(t_utc_ns=_ns(t0, trig.t_rise_rel), t_rel=trig.t_rise_rel, at960_duty_s=duty, **st)
    registered = ~lost & ~in_drop_at
    clocks = {k: {"k": c.k, "d_ns": int(c.d_ns), "d_s": c.d_ns * 1e-9, "drift_ppm": c.drift_ppm}
              for k, c in setup.clocks.items()}
    run_truth = RunTruth(
        name=setup.name, split=setup.split, t0_utc_ns=int(t0), duration_s=float(setup.duration_s),
        n_slots=int(round(setup.duration_s / TRIGGER_PERIOD_S)), n_trigger=int(n), skip_phase=trig.skip_phase, clocks=clocks,
        at960={"offset_s": float(duty[registered].mean()), "duty_mean_s": float(setup.at960_duty_mean_s),
               "duty_jitter_std_s": DUTY_JITTER_STD_S, "lost_fraction": float(setup.lost_fraction),
               "spurious_fraction": float(setup.spurious_fraction), "n_lost": int((lost & ~in_drop_at).sum()),
               "n_spurious": int(spur_ok.sum()), "n_dropout_pulses": int(in_drop_at.sum()),
               "n_messages": int(t_at.size), "dropouts_utc": _utc_intervals(t0, drop["at960"])},
        ltd800={"n_dropout_pulses": int(in_drop_ltd.sum()), "n_messages": int(t_ltd.size),
                "dropouts_utc": _utc_intervals(t0, drop["ltd800"])},
        hubs={"front": {"phase_rad": float(setup.hub_phase_rad["front"])},
              "rear": {"phase_rad": float(setup.hub_phase_rad["rear"])}, "n_messages": int(cmd["t"].size)},
        joy={"ntp_offset_s": float(setup.ntp_offset_s), "n_messages": int(t_joy.size)},
        states=states,
        bags={"receive_jitter_s": None if setup.receive_jitter_s is None else list(setup.receive_jitter_s),
              "reordered": reordered},
        clock_reset=None if reset is None else _reset_truth(reset, t0, stamps_ns, server),
    )
    return husky, server, run_truth


def _reset_truth(reset, t0_ns: int, stamps_ns: dict, server: list) -> dict:
    """Return the truth of a clock reset: when, the clock after it, where it is in the bag."""
    tracker, t_reset, clock = reset
    topic = f"/{tracker}/measurement"
    data = next(t for t in server if t.topic == topic)
    stamp = np.asarray(stamps_ns[topic])[np.argsort(data.t_receive_ns, kind="stable")]
    i = int(np.argmin(np.diff(stamp))) + 1  # the reset is the one large backward step
    return {"tracker": tracker, "topic": topic, "t_utc_ns": int(t0_ns) + round(t_reset * NS),
            "message": i, "jump_s": float((stamp[i] - stamp[i - 1]) * 1e-9),
            "clock_after": {"k": clock.k, "d_ns": int(clock.d_ns), "d_s": clock.d_ns * 1e-9,
                            "drift_ppm": clock.drift_ppm}}
