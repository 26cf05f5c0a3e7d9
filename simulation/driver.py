"""A human-like driver with a hand-held controller: joystick stamps and a closed-loop policy.

The driver of the thesis (section 6.3, fig. 6.3 and 6.4) steered the Husky by hand between the
two laser trackers, covering the input square broadly (combined throttle and steering, turning in
place, sharp changes, forward/backward alternation) while keeping the robot in the area between
the trackers and never turning it a full round (line of sight of the prisms). This module mimics
that with two layers:

- a *manoeuvre generator* picking, from a seeded rng, segments of 0.5 to 6 s: ``hold`` (a step to
  a held command), ``sweep`` (a linear ramp to a new command), ``slalom`` (sinusoidal steering at a
  fixed throttle), ``turn`` (turn in place), ``reverse`` and ``stop``;
- a *supervisor* overriding it when a 0.5 s look-ahead of the pose (plus any input latency the
  driver is used to) leaves the soft area, or the heading approaches its limit: it steers back
  towards the centre while driving forwards or backwards, whichever keeps the heading within
  limits, or turns in place back towards the start heading. Each episode draws its own gain
  and speed, as a human never corrects twice the same way.

The output passes a *thumb filter*: when an axis changes sign, the thumb rests in neutral
(|u| < 0.15) for 0.2 to 0.4 s first, as a human releasing the stick does. Thesis model B (eqs.
7.7, 7.9) extrapolates badly when e.g. full forward throttle follows fast reverse turning (it has
spurious attractors far outside fig. 6.3's envelope); with the neutral rest every step between
the model's steady states stays inside the envelope (checked in tests/test_driver.py).

Driving area (local AT960 frame, metres): an ellipse around the midpoint of the trackers
(AT960 at (0, 0), LTD800 at (6.93, 5.73)), semi-axes 3.2 m along the line between the trackers
and 1.8 m across it, minus discs of 1.5 m around each tracker.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TRACKER_AT960_LOCAL_M = (0.0, 0.0)
TRACKER_LTD800_LOCAL_M = (6.93, 5.73)


@dataclass(frozen=True)
class DrivingArea:
    """The allowed region: ellipse between the trackers minus keep-out discs around them."""

    center_local_m: tuple[float, float] = (3.465, 2.865)
    semi_axes_m: tuple[float, float] = (3.2, 1.8)
    axis_angle_rad: float = math.atan2(5.73, 6.93)
    trackers_local_m: tuple[tuple[float, float], ...] = (TRACKER_AT960_LOCAL_M, TRACKER_LTD800_LOCAL_M)
    min_tracker_distance_m: float = 1.5

    def ellipse_radius(self, x, y) -> np.ndarray:
        """Return the normalised elliptic radius of local points (1 on the ellipse boundary)."""
        dx, dy = np.asarray(x) - self.center_local_m[0], np.asarray(y) - self.center_local_m[1]
        c, s = math.cos(self.axis_angle_rad), math.sin(self.axis_angle_rad)
        a, b = self.semi_axes_m
        return np.hypot((c * dx + s * dy) / a, (-s * dx + c * dy) / b)

    def tracker_distance(self, x, y) -> np.ndarray:
        """Return the distance (m) of local points to the nearest tracker."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        return np.min([np.hypot(x - tx, y - ty) for tx, ty in self.trackers_local_m], axis=0)

    def contains(self, x, y) -> np.ndarray:
        """Return True where local points lie inside the ellipse and off the keep-out discs."""
        return (self.ellipse_radius(x, y) <= 1.0) & (
            self.tracker_distance(x, y) >= self.min_tracker_distance_m)


def simulate_joy_stamps(duration_s: float, rng: np.random.Generator, rate_hz: float = 20.0,
                        jitter_std_s: float = 0.006, gap_prob: float = 0.012,
                        gap_s: tuple[float, float] = (0.1, 0.3), min_step_s: float = 0.01) -> np.ndarray:
    """Return increasing joystick message times (s since run start) in ``[0, duration_s)``.

    A Bluetooth joystick on ROS (``joy_node`` with autorepeat) publishes at about ``rate_hz``,
    with scheduling jitter, steps never below ``min_step_s``, and occasional radio dropouts of
    100 to 300 ms.
    """
    n_max = int(duration_s * rate_hz * 1.2) + 10
    step = np.maximum(1.0 / rate_hz + rng.normal(0.0, jitter_std_s, n_max), min_step_s)
    step += np.where(rng.random(n_max) < gap_prob, rng.uniform(*gap_s, n_max), 0.0)
    t = rng.uniform(0.0, 1.0 / rate_hz) + np.concatenate([[0.0], np.cumsum(step[:-1])])
    return t[t < duration_s]


@dataclass(frozen=True)
class DriverParams:
    """Tuning of the human-like driver: look-ahead, soft limits and reaction of the supervisor,
    style of the manoeuvres and the joystick's message clock.

    The defaults are the thesis-like driver; simulator variants (:mod:`simulation.variants`)
    draw gentle drivers (smaller, longer, calmer manoeuvres) and aggressive ones (saturated,
    short, slalom- and turn-heavy manoeuvres) and joysticks publishing at 10 to 50 Hz.
    """

    style: str = "thesis"  # name only: thesis | gentle | aggressive
    amplitude: float = 1.0  # the free manoeuvres' commands are scaled by this
    target_range: float = 1.25  # hold/sweep targets uniform in +-target_range, then clipped to +-1
    duration_scale: float = 1.0  # manoeuvre lengths scaled by this
    kind_probs: tuple = (0.24, 0.22, 0.18, 0.12, 0.16, 0.08)  # of HumanDriver.KINDS
    slalom_period_s: tuple = (1.5, 4.0)
    joy_rate_hz: float = 20.0
    joy_jitter_std_s: float = 0.006
    joy_min_step_s: float = 0.01
    lookahead_s: float = 0.5
    soft_radius: float = 0.92  # supervisor takes over beyond this normalised elliptic radius
    soft_tracker_distance_m: float = 1.85
    home_radius: float = 0.3  # ... and hands back inside this one
    heading_soft_rad: float = math.radians(110.0)  # +-150 deg is the hard limit
    heading_home_rad: float = math.radians(50.0)
    neutral_band: float = 0.15
    neutral_rest_s: tuple[float, float] = (0.2, 0.4)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class HumanDriver:
    """Closed-loop joystick policy: call :meth:`command` at each joystick message time.

    Parameters
    ----------
    rng
        Seeded generator (manoeuvre choice and their parameters).
    psi0
        Initial heading (rad); the unwrapped heading is kept within +-150 deg of it.
    area, params
        Driving area and tuning.
    latency_s
        Input latency the driver has got used to: added to the supervisor's look-ahead.
    """

    KINDS = ("hold", "sweep", "slalom", "turn", "reverse", "stop")

    def __init__(self, rng: np.random.Generator, psi0: float, area: DrivingArea | None = None,
                 params: DriverParams | None = None, latency_s: float = 0.0):
        self.rng = rng
        self.psi0 = float(psi0)
        self.area = area or DrivingArea()
        self.p = params or DriverParams()
        self.lookahead_s = self.p.lookahead_s + latency_s  # a human learns a laggy robot
        self.mode = "free"  # free | return | unwind
        self.t_end = -1.0
        self.plan = None
        self.u_prev = np.zeros(2)
        self.last_sign = np.zeros(2)
        self.zero_since = np.zeros(2)
        self.rest = np.full(2, 0.3)
        self.style = (1.6, 0.75, 0.6)  # per supervisor episode: turn gain, speed, unwind rate

    # -- manoeuvres ---------------------------------------------------------------------------
    def _new_manoeuvre(self, t: float) -> None:
        rng, p = self.rng, self.p
        ds, tr = p.duration_scale, p.target_range
        kind = self.KINDS[rng.choice(len(self.KINDS), p=p.kind_probs)]
        dur = float(rng.uniform(1.0 * ds, 6.0 * ds))
        u_now = self.u_prev.copy()
        if kind == "hold":
            target = np.clip(rng.uniform(-tr, tr, 2), -1, 1)
            plan = ("const", target)
            dur = float(rng.uniform(0.8 * ds, 4.0 * ds))
        elif kind == "sweep":
            target = np.clip(rng.uniform(-tr, tr, 2), -1, 1)
            plan = ("ramp", u_now, target)
        elif kind == "slalom":
            plan = ("slalom", float(rng.choice([-1, 1]) * rng.uniform(0.2, 1.0)),
                    float(rng.uniform(0.3, 1.0)), float(rng.uniform(*p.slalom_period_s)), float(rng.uniform(0, 6.3)))
        elif kind == "turn":
            plan = ("const", np.array([rng.uniform(-0.1, 0.1), rng.choice([-1, 1]) * rng.uniform(0.3, 1.0)]))
            dur = float(rng.uniform(1.0 * ds, 3.0 * ds))
        elif kind == "reverse":
            plan = ("const", np.array([-rng.uniform(0.3, 1.0), rng.uniform(-0.8, 0.8)]))
            dur = float(rng.uniform(1.0 * ds, 4.0 * ds))
        else:
            plan = ("const", np.zeros(2))
            dur = float(rng.uniform(0.4 * ds, 1.5 * ds))
        self.plan, self.t_start, self.t_end = plan, t, t + dur

    def _planned(self, t: float) -> np.ndarray:
        plan = self.plan
        if plan[0] == "const":
            return plan[1]
        s = (t - self.t_start) / max(self.t_end - self.t_start, 1e-9)
        if plan[0] == "ramp":
            return plan[1] + min(max(s, 0.0), 1.0) * (plan[2] - plan[1])
        _, u1, amp, period, phase = plan
        return np.array([u1, amp * math.sin(2.0 * math.pi * (t - self.t_start) / period + phase)])

    # -- supervisor ---------------------------------------------------------------------------
    def _return_command(self, x: float, y: float, psi: float) -> np.ndarray:
        cx, cy = self.area.center_local_m
        bearing = math.atan2(cy - y, cx - x)
        best = None
        for direction in (1.0, -1.0):  # forwards: nose to the centre; backwards: tail to it
            d_psi = _wrap(bearing + (0.0 if direction > 0 else math.pi) - psi)
            ok = abs(psi + d_psi - self.psi0) <= math.radians(130.0)
            key = (not ok, abs(d_psi))
            if best is None or key < best[0]:
                best = (key, direction, d_psi)
        _, direction, d_psi = best
        gain, speed, _ = self.style
        u2 = float(np.clip(gain * d_psi, -0.9, 0.9))
        if abs(d_psi) > math.radians(35.0) and abs(u2) < 0.5:
            u2 = math.copysign(0.5, u2)
        # drive while turning (a pure turn in place would let a slope or slip carry it out)
        dist = float(self.area.ellipse_radius(x, y))
        return np.array([direction * min(speed, 0.3 + 0.6 * dist) * max(math.cos(d_psi), 0.0), u2])

    def command(self, t: float, x: float, y: float, psi: float, vx: float, vy: float,
                omega: float) -> tuple[float, float]:
        """Return the joystick command ``(u1, u2)`` the driver gives at time ``t`` for this state."""
        p = self.p
        c, s = math.cos(psi), math.sin(psi)
        xa = x + self.lookahead_s * (c * vx - s * vy)
        ya = y + self.lookahead_s * (s * vx + c * vy)
        d_head = psi - self.psi0
        d_head_ahead = d_head + 0.8 * omega
        if self.mode == "free":
            if abs(d_head_ahead) > p.heading_soft_rad:
                self.mode = "unwind"
            elif (self.area.ellipse_radius(xa, ya) > p.soft_radius
                  or self.area.tracker_distance(xa, ya) < p.soft_tracker_distance_m):
                self.mode = "return"
            if self.mode != "free":  # a human does not correct the same way twice
                self.style = (float(self.rng.uniform(1.0, 2.5)), float(self.rng.uniform(0.45, 0.9)),
                              float(self.rng.uniform(0.4, 0.9)))
        if self.mode == "unwind":
            if abs(d_head) < p.heading_home_rad:
                self.mode = "free"
                self.t_end = -1.0
            else:
                u = np.array([0.0, -math.copysign(self.style[2], d_head)])
        if self.mode == "return":
            if self.area.ellipse_radius(x, y) < p.home_radius:
                self.mode = "free"
                self.t_end = -1.0
            else:
                u = self._return_command(x, y, psi)
        if self.mode == "free":
            if t >= self.t_end:
                self._new_manoeuvre(t)
            u = self._planned(t)
            u = np.clip(u * p.amplitude if p.amplitude != 1.0 else u, -1.0, 1.0)
        return self._thumb(t, np.asarray(u, float))

    def _thumb(self, t: float, u: np.ndarray) -> tuple[float, float]:
        """Return ``u`` after the neutral rest a human thumb makes when an axis changes sign."""
        band = self.p.neutral_band
        out = u.copy()
        for i in range(2):
            if abs(u[i]) > band:
                sign = math.copysign(1.0, u[i])
                if self.last_sign[i] != 0.0 and sign != self.last_sign[i]:
                    if abs(self.u_prev[i]) > band:  # first message of the flip: rest starts now
                        self.zero_since[i] = t
                        self.rest[i] = self.rng.uniform(*self.p.neutral_rest_s)
                    if t - self.zero_since[i] < self.rest[i]:
                        out[i] = 0.0
                        continue
                self.last_sign[i] = sign
            elif abs(self.u_prev[i]) > band:
                self.zero_since[i] = t
                self.rest[i] = self.rng.uniform(*self.p.neutral_rest_s)
        self.u_prev = out
        return float(out[0]), float(out[1])
