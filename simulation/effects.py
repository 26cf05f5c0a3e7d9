"""Catalogue of the dynamics effects the simulator can switch on: one physical mechanism per family.

Every effect is off by default. A campaign holds at most one; its family names are those of the
``diagnose`` JSON in INTERFACES.md. Each mechanism is small enough that a SINDy model fitted
without it still drives, but large enough at the *moderate* magnitude to be plainly visible in
5 s open-loop predictions (thesis section 5.3.8). Where a mechanism acts:

- *input side* (:meth:`simulation.robot.TrueDynamics.motor_inputs`): ``input_delay``,
  ``deadband``, ``asymmetry``, ``time_dependence``. They change what the motors see; the body
  dynamics ``f`` are untouched.
- *body dynamics* (:meth:`simulation.robot.TrueDynamics.f`): ``heading_dependence``,
  ``position_dependence``, ``lateral_slip``.

Mechanisms (``v`` is the effect's ``value``; ``u = [u1, u2]`` the joystick input, ``u_m`` what the
motors see, saturated to [-1, 1] last):

``input_delay``
    Joystick-to-motor latency (Bluetooth, ROS transport, motor controller):
    ``u_m(t) = u_zoh(t - v)`` with ``v`` in s. Parameter to estimate: the delay in s.
``heading_dependence``
    The floor is a plane tilted by ``v`` degrees, downhill towards local azimuth
    ``psi_down_rad = 0`` (local +x). Gravity along the floor, in the body frame::

        vx_dot += g sin(tilt) cos(psi - psi_down)
        vy_dot -= g sin(tilt) sin(psi - psi_down)

    The body also pitches with the floor (``tilt cos(psi - psi_down)``, nose down when heading
    downhill) and the floor height falls by ``tan(tilt)`` per metre downhill. Parameters to
    estimate: tilt (deg) and downhill azimuth (rad).
``position_dependence``
    A floor patch of higher rolling resistance (e.g. a carpet): a disc of centre
    ``patch_center_local_m`` and radius ``patch_radius_m`` in the driving area, with a smooth
    (logistic, 10-90 % over ``patch_edge_m``) edge. Inside, the linear damping of model B grows by
    the fraction ``v``::

        vx_dot    -= v s(x, y) 7.770 vx
        omega_dot -= v s(x, y) 6.951 omega

    so the robot is slower there. Parameters to estimate: patch centre, radius, damping fraction.
``time_dependence``
    Battery sag: the control authority decays linearly with time since the run start,
    ``u_m = u (1 - v t / 600 s)`` (``v`` = fractional loss per 10 minutes). Parameter to estimate:
    the decay rate per 10 min.
``asymmetry``
    Left/right motor imbalance: track commands ``l = u1 - u2``, ``r = u1 + u2`` are scaled by
    ``1 - v/2`` and ``1 + v/2``, hence ``u1_m = u1 + v/2 u2`` and ``u2_m = u2 + v/2 u1``: a yaw
    rate bias proportional to throttle and a speed change with the sign of steering. Parameter
    to estimate: the imbalance fraction.
``deadband``
    Motor-controller deadband (static friction, controller threshold): per axis
    ``u_m = sign(u) max(|u| - v, 0) / (1 - v)``, the standard rescaled deadband. Parameter to
    estimate: the threshold in input units.
``lateral_slip``
    Lower lateral grip (worn or slippery tyres): the centripetal coupling of the lateral law
    ``vy_dot = -k_y vy - c_y vx omega`` (see :mod:`simulation.robot`) is multiplied by ``v``, so
    the sideways drift in turns is ``v`` times larger. Parameter to estimate: the slip gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from groundfloor.errors import InputError

# Centre of the driving area (midpoint between the trackers) and its long-axis direction; the
# patch sits on the long axis, 1.4 m from the centre towards the LTD800 (see simulation.driver).
_AREA_CENTER = (3.465, 2.865)
_AXIS = math.atan2(5.73, 6.93)
PATCH_CENTER_LOCAL_M = (
    round(_AREA_CENTER[0] + 1.4 * math.cos(_AXIS), 3),
    round(_AREA_CENTER[1] + 1.4 * math.sin(_AXIS), 3),
)


@dataclass(frozen=True)
class EffectSpec:
    """What one effect family does, the unit and range of its value and what to estimate."""

    unit: str  # unit of Effect.value
    doc: str  # one-line physical mechanism
    valid_range: tuple[float, float]  # accepted values (inclusive)
    moderate: float  # clearly visible but moderate magnitude
    estimate: str  # the parameter(s) a diagnosis should estimate
    fixed: dict = field(default_factory=dict)  # fixed geometry of the mechanism (SI, radians)


EFFECTS: dict[str, EffectSpec] = {
    "input_delay": EffectSpec(
        "s", "motors see the joystick input delayed by value", (0.02, 0.5), 0.15,
        "delay_s: joystick-to-motor latency in s"),
    "heading_dependence": EffectSpec(
        "deg", "floor tilted by value degrees, downhill towards local +x: gravity along the body axes",
        (0.2, 5.0), 1.5,
        "tilt_deg and psi_down_rad: floor slope and downhill azimuth in the local frame",
        {"psi_down_rad": 0.0, "g_m_s2": 9.81}),
    "position_dependence": EffectSpec(
        "fraction", "linear damping of vx and omega grows by value inside a floor patch",
        (0.1, 0.8), 0.4,
        "patch centre (local m), radius (m) and damping fraction",
        {"patch_center_local_m": PATCH_CENTER_LOCAL_M, "patch_radius_m": 1.2, "patch_edge_m": 0.2}),
    "time_dependence": EffectSpec(
        "1/(10 min)", "battery sag: input gain 1 - value * t / 600 s since the run start",
        (0.05, 0.6), 0.25,
        "decay_per_10min: fractional loss of input gain per 10 minutes"),
    "asymmetry": EffectSpec(
        "fraction", "left/right track commands scaled by 1 -/+ value/2", (0.03, 0.4), 0.15,
        "imbalance: u1_m = u1 + imbalance/2 u2, u2_m = u2 + imbalance/2 u1"),
    "deadband": EffectSpec(
        "input units", "motor deadband: |u| below value gives zero, above rescaled to [0, 1]",
        (0.03, 0.4), 0.15,
        "threshold: deadband in input units"),
    "lateral_slip": EffectSpec(
        "factor", "centripetal lateral slip coupling multiplied by value", (1.5, 10.0), 4.0,
        "slip_gain: multiplier of the vx*omega coupling in the lateral equation"),
}


@dataclass(frozen=True)
class Effect:
    """One switched-on effect: a family name of ``EFFECTS`` and its magnitude in the family's unit."""

    name: str
    value: float

    def __post_init__(self):
        check_effect(self.name, self.value)

    @property
    def spec(self) -> EffectSpec:
        """The catalogue entry of this effect's family."""
        return EFFECTS[self.name]


def check_effect(name: str, value: float) -> None:
    """Raise InputError unless ``name`` is a known family and ``value`` lies in its range."""
    if name not in EFFECTS:
        raise InputError(f"effect {name!r}: unknown (known: {', '.join(EFFECTS)})")
    lo, hi = EFFECTS[name].valid_range
    if not isinstance(value, (int, float)) or not (lo <= value <= hi):
        raise InputError(
            f"effect {name}={value!r}: value outside [{lo}, {hi}] {EFFECTS[name].unit}")


def parse_effect(text: str) -> Effect:
    """Return the Effect described by ``"NAME=VALUE"`` (``"NAME"`` alone means the moderate value).

    Raises
    ------
    InputError
        Malformed text, unknown name or a value outside the family's range; the message names it.
    """
    if not isinstance(text, str) or text.count("=") > 1 or not text.split("=")[0].strip():
        raise InputError(f"effect {text!r}: expected NAME=VALUE, e.g. input_delay=0.15")
    name, _, raw = (s.strip() for s in text.partition("="))
    if name not in EFFECTS:
        raise InputError(f"effect {name!r}: unknown (known: {', '.join(EFFECTS)})")
    if not _:
        return Effect(name, EFFECTS[name].moderate)
    try:
        value = float(raw)
    except ValueError:
        raise InputError(f"effect {name}={raw!r}: value is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"effect {name}={raw!r}: value is not finite")
    return Effect(name, value)
