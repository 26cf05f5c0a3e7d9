"""Catalogue of the dynamics effects the simulator can switch on: families, each in several forms.

Every effect is off by default. A campaign holds at most one; its family names are those of the
``diagnose`` JSON in INTERFACES.md. Each family has a *default form*, the one mechanism the
simulator had before forms existed (the diagnosis families were written from it; its values and
output are unchanged), and alternative forms, mechanisms of the same family that the diagnosis
was not written from (issue 15). Each is small enough that a SINDy model fitted without it still
drives, and plainly visible in 5 s open-loop predictions at its *moderate* magnitude (thesis
section 5.3.8). Where a mechanism acts:

- *input side* (:mod:`simulation.actuator`, :meth:`simulation.robot.TrueDynamics.motor_inputs`):
  ``input_delay``, ``deadband``, ``time_dependence`` and the input forms of ``asymmetry``. They
  change what the motors see; the body dynamics are untouched.
- *body side* (:mod:`simulation.body_effects`, :meth:`simulation.robot.TrueDynamics.accel`):
  ``heading_dependence``, ``position_dependence``, ``lateral_slip`` and ``asymmetry:friction``.

Mechanisms (``v`` is the effect's ``value``; ``u = [u1, u2]`` the joystick input, ``u_m`` what the
motors see, saturated to [-1, 1]; default form first):

``input_delay``
    ``transport``: ``u_m(t) = u_zoh(t - v)``, ``v`` in s (Bluetooth, ROS transport).
    ``motor_lag``: a first-order actuator lag of time constant ``v`` s on the held input,
    ``tau u_m' = u_zoh - u_m`` (integrated exactly, :mod:`simulation.actuator`).
``heading_dependence``
    ``slope``: the floor is a plane tilted by ``v`` degrees, downhill towards the local azimuth
    ``azimuth_deg`` (parameter, default 0 = local +x; drawn uniformly with ``seed``). Gravity
    along the floor in the body frame, ``d = psi - azimuth``::

        vx_dot += g sin(tilt) cos(d)        vy_dot -= g sin(tilt) sin(d)

    The body pitches with the floor (``tilt cos(d)``) and the floor falls by ``tan(tilt)`` per
    metre downhill.
``position_dependence``
    The linear damping of model B grows by ``v s(x, y)`` where the floor is rougher::

        vx_dot -= v s(x, y) d_vx vx        omega_dot -= v s(x, y) d_omega omega

    with ``d_vx``, ``d_omega`` the robot's ``-vx`` and ``-omega`` coefficients (7.770 and 6.951
    for model B). ``disc``: ``s`` is a disc (a carpet) of centre ``patch_center_local_m`` and
    radius ``patch_radius_m`` with a logistic edge, 10-90 % over ``patch_edge_m``. ``bumps``: a
    sum of three Gaussian bumps ``w_i exp(-|p - c_i|^2 / (2 sigma_i^2))`` over the driving area
    (``centres_m``, ``widths_m``, ``weights``; drawn with ``seed``). ``gradient``: a smooth step
    across the lab, ``s = (1 + tanh(((p - centre) . n) / length_m)) / 2`` with ``n`` pointing
    to the local azimuth ``azimuth_deg`` (drawn with ``seed``).
``time_dependence``
    Battery sag: the inputs are multiplied by a gain ``g(t)`` falling monotonically from 1 at
    the run start to ``1 - v`` at 600 s (``v`` = fractional loss per 10 minutes). ``linear``:
    ``g = max(1 - v t / 600, 0)``. ``exponential``: ``g = (1 - v)^(t / 600)``. ``late``: no
    loss until ``onset_s``, then linear to ``1 - v`` at 600 s. ``early``: most of the loss at
    the start, ``g = 1 - v (1 - exp(-t / tau_s)) / (1 - exp(-600 / tau_s))``.
``asymmetry``
    ``gain``: track commands ``l = u1 - u2``, ``r = u1 + u2`` scaled by ``1 -/+ v/2``, hence
    ``u1_m = u1 + v/2 u2``, ``u2_m = u2 + v/2 u1``. ``steering_offset``: a joystick trim
    ``u2_m = u2 + v``. ``coupling``: throttle leaks into steering, ``u2_m = u2 + v u1``.
    ``friction`` (body side): the right track's rolling friction is ``1 + v/2`` and the left's
    ``1 - v/2`` times the mean, which adds ``vx_dot -= v (d_vx b / 2) omega`` and
    ``omega_dot -= v d_omega / (2 b) vx`` (``b`` half the track width): a yaw towards the
    rougher side proportional to speed.
``deadband``
    ``hard``: per axis ``u_m = sign(u) max(|u| - v, 0) / (1 - v)``. ``soft``: a smooth
    deadband ``u_m = (u - v tanh(u / v)) / (1 - v tanh(1 / v))`` (cubic near zero, the hard one
    far from it). ``hysteresis``: stiction, per axis the motor breaks away when ``|u| >= v`` and
    stops when ``|u|`` falls to ``r = release_ratio v``; while moving ``u_m = sign(u) (|u| - r)
    / (1 - r)``.
``lateral_slip``
    ``coupling``: the centripetal coupling ``c_y`` of the robot's own lateral law
    (:mod:`simulation.lateral`) is multiplied by ``v``, so the sideways drift in turns is ``v``
    times larger. ``linear``, ``tanh``, ``cubic``, ``speed_stiffness``: the robot's lateral law
    is replaced by that form (shape parameter as in :data:`simulation.lateral.LATERAL_FORMS`),
    then its coupling multiplied by ``v``.

Effects are written ``NAME[:FORM][=VALUE][,KEY=VALUE...]`` (:func:`parse_effect`), e.g.
``input_delay:motor_lag=0.15`` or ``heading_dependence=1.5,azimuth_deg=120``; truth/ records
the form and every parameter (drawn ones resolved) of a non-default form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from groundfloor.errors import InputError
from simulation.lateral import LATERAL_FORMS

# Centre of the driving area (midpoint between the trackers) and its long-axis direction; the
# patch sits on the long axis, 1.4 m from the centre towards the LTD800 (see simulation.driver).
_AREA_CENTER = (3.465, 2.865)
_AXIS = math.atan2(5.73, 6.93)
PATCH_CENTER_LOCAL_M = (
    round(_AREA_CENTER[0] + 1.4 * math.cos(_AXIS), 3),
    round(_AREA_CENTER[1] + 1.4 * math.sin(_AXIS), 3),
)
N_BUMPS = 3


@dataclass(frozen=True)
class FormSpec:
    """One mechanism of a family: unit and range of its value, parameters with their defaults."""

    unit: str
    doc: str
    valid_range: tuple[float, float]
    moderate: float
    estimate: str
    params: dict = field(default_factory=dict)  # extra parameters -> default (None: drawn with seed)


@dataclass(frozen=True)
class EffectSpec:
    """What one effect family does in its default form, and its forms (the default first)."""

    unit: str  # unit of Effect.value (default form)
    doc: str  # one-line physical mechanism (default form)
    valid_range: tuple[float, float]  # accepted values (inclusive, default form)
    moderate: float  # clearly visible but moderate magnitude (default form)
    estimate: str  # the parameter(s) a diagnosis should estimate
    fixed: dict = field(default_factory=dict)  # fixed geometry of the default form (SI, radians)
    forms: dict = field(default_factory=dict)  # form name -> FormSpec; the first is the default

    @property
    def default_form(self) -> str:
        """Name of the default form (the simulator's mechanism before forms existed)."""
        return next(iter(self.forms))


def _family(unit, doc, valid_range, moderate, estimate, default_form, fixed=None, default_params=None,
            **others) -> EffectSpec:
    """Return an EffectSpec whose default form repeats the family's own fields."""
    forms = {default_form: FormSpec(unit, doc, valid_range, moderate, estimate, default_params or {})} | others
    return EffectSpec(unit, doc, valid_range, moderate, estimate, fixed or {}, forms)


_SLIP = ((1.5, 10.0), 4.0)
_DECAY = ((0.05, 0.6), 0.25)
EFFECTS: dict[str, EffectSpec] = {
    "input_delay": _family(
        "s", "motors see the joystick input delayed by value", (0.02, 0.5), 0.15,
        "delay_s: joystick-to-motor latency in s", "transport",
        motor_lag=FormSpec("s", "first-order actuator lag of time constant value", (0.02, 0.5), 0.15,
                           "tau_s: actuator time constant in s")),
    "heading_dependence": _family(
        "deg", "floor tilted by value degrees, downhill towards local +x: gravity along the body axes",
        (0.2, 5.0), 1.5,
        "tilt_deg and psi_down_rad: floor slope and downhill azimuth in the local frame", "slope",
        {"psi_down_rad": 0.0, "g_m_s2": 9.81}, {"azimuth_deg": 0.0}),
    "position_dependence": _family(
        "fraction", "linear damping of vx and omega grows by value inside a floor patch",
        (0.1, 0.8), 0.4,
        "patch centre (local m), radius (m) and damping fraction", "disc",
        {"patch_center_local_m": PATCH_CENTER_LOCAL_M, "patch_radius_m": 1.2, "patch_edge_m": 0.2},
        bumps=FormSpec("fraction", "damping grows by value times a sum of three Gaussian bumps",
                       (0.1, 0.8), 0.4, "field s(x, y) and damping fraction",
                       {"centres_m": None, "widths_m": None, "weights": None}),
        gradient=FormSpec("fraction", "damping grows by value across a smooth step over the lab",
                          (0.1, 0.8), 0.4, "step direction, width and damping fraction",
                          {"azimuth_deg": None, "length_m": 1.0})),
    "time_dependence": _family(
        "1/(10 min)", "battery sag: input gain 1 - value * t / 600 s since the run start", *_DECAY,
        "decay_per_10min: fractional loss of input gain per 10 minutes", "linear",
        exponential=FormSpec("1/(10 min)", "input gain (1 - value)^(t / 600 s)", *_DECAY,
                             "decay_per_10min"),
        late=FormSpec("1/(10 min)", "input gain 1 until onset_s, then linear to 1 - value at 600 s",
                      *_DECAY, "decay_per_10min and onset_s", {"onset_s": 30.0}),
        early=FormSpec("1/(10 min)", "input gain falls to 1 - value at 600 s, mostly within tau_s",
                       *_DECAY, "decay_per_10min and tau_s", {"tau_s": 60.0})),
    "asymmetry": _family(
        "fraction", "left/right track commands scaled by 1 -/+ value/2", (0.03, 0.4), 0.15,
        "imbalance: u1_m = u1 + imbalance/2 u2, u2_m = u2 + imbalance/2 u1", "gain",
        steering_offset=FormSpec("input units", "joystick trim: u2_m = u2 + value", (0.01, 0.2), 0.05,
                                 "offset: steering bias in input units"),
        coupling=FormSpec("u2 per u1", "throttle leaks into steering: u2_m = u2 + value u1",
                          (0.015, 0.2), 0.08, "coupling: steering per unit throttle"),
        friction=FormSpec("fraction", "right/left track friction 1 +/- value/2 times the mean",
                          (0.01, 0.15), 0.05, "friction imbalance fraction")),
    "deadband": _family(
        "input units", "motor deadband: |u| below value gives zero, above rescaled to [0, 1]",
        (0.03, 0.4), 0.15, "threshold: deadband in input units", "hard",
        soft=FormSpec("input units", "smooth deadband (u - v tanh(u / v)) rescaled to [0, 1]",
                      (0.03, 0.4), 0.15, "threshold: width of the smooth deadband"),
        hysteresis=FormSpec("input units", "stiction: breaks away at |u| >= value, stops at "
                            "release_ratio * value", (0.03, 0.4), 0.15,
                            "threshold and release_ratio", {"release_ratio": 0.5})),
    "lateral_slip": _family(
        "factor", "centripetal lateral slip coupling multiplied by value", *_SLIP,
        "slip_gain: multiplier of the vx*omega coupling in the lateral equation", "coupling",
        **{form: FormSpec("factor", f"lateral law replaced by {form} ({doc}), coupling times value", *_SLIP,
                          "slip_gain and the lateral law", {shape: default} if shape else {})
           for form, (shape, _, _, default, doc) in LATERAL_FORMS.items()}),
}
_DRAWN = {"bumps", "gradient", "slope"}  # forms with parameters that ``seed`` draws


@dataclass(frozen=True)
class Effect:
    """One switched-on effect: a family of ``EFFECTS``, its magnitude, form and form parameters.

    ``form`` empty means the family's default form; ``params`` holds only parameters that were
    given or drawn (``((key, value), ...)`` sorted, values floats or tuples), the others take
    the form's defaults (:meth:`param`). A ``seed`` among them draws the form's unset geometry
    (azimuths, bumps) once, here, so the effect carries every number it acts with.
    """

    name: str
    value: float
    form: str = ""
    params: tuple = ()

    def __post_init__(self):
        check_effect(self.name, self.value, self.form)
        object.__setattr__(self, "form", self.form or EFFECTS[self.name].default_form)
        given = dict(self.params.items() if isinstance(self.params, dict) else self.params)
        object.__setattr__(self, "params", _resolve_params(self.name, self.form, given))

    @property
    def spec(self) -> EffectSpec:
        """The catalogue entry of this effect's family."""
        return EFFECTS[self.name]

    @property
    def form_spec(self) -> FormSpec:
        """The catalogue entry of this effect's form."""
        return EFFECTS[self.name].forms[self.form]

    @property
    def is_default_form(self) -> bool:
        """True for the family's default form with no parameter set (the pre-forms mechanism)."""
        return self.form == self.spec.default_form and not self.params

    def param(self, key: str):
        """Return the form parameter ``key``: as given or drawn, else the form's default."""
        return dict(self.params).get(key, self.form_spec.params.get(key))

    def to_dict(self) -> dict:
        """Return ``{name, value}`` plus ``form`` and ``params`` for non-default forms (truth/)."""
        out = {"name": self.name, "value": float(self.value)}
        if not self.is_default_form:
            out |= {"form": self.form, "params": {k: _plain(v) for k, v in self.params}}
        return out

    def label(self) -> str:
        """Return the effect as ``NAME[:FORM]=VALUE`` (the form only when not the default)."""
        form = "" if self.form == self.spec.default_form else f":{self.form}"
        return f"{self.name}{form}={self.value:g}"


def _plain(v):
    return [_plain(x) for x in v] if isinstance(v, (tuple, list)) else float(v)


def _frozen(v):
    return tuple(_frozen(x) for x in v) if isinstance(v, (tuple, list, np.ndarray)) else float(v)


def _resolve_params(name: str, form: str, given: dict) -> tuple:
    """Return the sorted parameter tuple of a form: given ones checked, drawn ones drawn."""
    known = EFFECTS[name].forms[form].params
    allowed = set(known) | ({"seed"} if form in _DRAWN else set())
    for key in given:
        if key not in allowed:
            raise InputError(f"effect {name}:{form}: unknown parameter {key!r} "
                             f"(known: {', '.join(sorted(allowed)) or 'none'})")
    out = {k: _frozen(v) for k, v in given.items()}
    for key, v in out.items():
        if not all(math.isfinite(x) for x in np.ravel(v)):
            raise InputError(f"effect {name}:{form}: parameter {key}={v!r} is not finite")
    if "seed" in out:
        rng = np.random.default_rng(int(out["seed"]))
        if form == "bumps" and "centres_m" not in out:
            out |= draw_bumps(rng)
        elif form in ("gradient", "slope") and "azimuth_deg" not in out:
            out["azimuth_deg"] = float(rng.uniform(-180.0, 180.0))
    if form == "bumps" and "centres_m" not in out:
        out |= draw_bumps(np.random.default_rng(0))
    if form == "gradient" and "azimuth_deg" not in out:
        out["azimuth_deg"] = 0.0
    for key in ("length_m", "onset_s", "tau_s", "release_ratio") + tuple(s for s, *_ in LATERAL_FORMS.values() if s):
        if key in out and not out[key] > 0:
            raise InputError(f"effect {name}:{form}: parameter {key}={out[key]!r} must be > 0")
    if form == "late" and not out.get("onset_s", 30.0) < 600.0:
        raise InputError(f"effect {name}:{form}: onset_s={out['onset_s']!r} must be below 600 s")
    if form == "hysteresis" and not out.get("release_ratio", 0.5) < 1.0:
        raise InputError(f"effect {name}:{form}: release_ratio={out['release_ratio']!r} must be below 1")
    return tuple(sorted(out.items()))


def draw_bumps(rng: np.random.Generator) -> dict:
    """Return ``{centres_m, widths_m, weights}`` of ``N_BUMPS`` Gaussian bumps in the driving area.

    Centres uniform in the inner 80 % of the driving ellipse (:class:`simulation.driver.
    DrivingArea`'s semi-axes 3.2 m and 1.8 m), widths 0.5-1.2 m, relative weights 0.3-1, scaled
    so that the field's peak over the ellipse is 1: the effect's value is then the largest
    damping increase, as for the disc.
    """
    c, s = math.cos(_AXIS), math.sin(_AXIS)

    def to_local(e1, e2):
        return _AREA_CENTER[0] + c * e1 - s * e2, _AREA_CENTER[1] + s * e1 + c * e2

    r = np.sqrt(rng.uniform(0.0, 0.8 ** 2, N_BUMPS))
    ang = rng.uniform(-math.pi, math.pi, N_BUMPS)
    cx, cy = to_local(3.2 * r * np.cos(ang), 1.8 * r * np.sin(ang))
    widths = rng.uniform(0.5, 1.2, N_BUMPS)
    weights = rng.uniform(0.3, 1.0, N_BUMPS)
    g1, g2 = np.meshgrid(np.linspace(-1, 1, 81), np.linspace(-1, 1, 81))
    inside = np.hypot(g1, g2) <= 1.0
    gx, gy = to_local(3.2 * g1[inside], 1.8 * g2[inside])
    field = sum(w * np.exp(-((gx - x) ** 2 + (gy - y) ** 2) / (2 * sig ** 2))
                for x, y, sig, w in zip(cx, cy, widths, weights))
    weights = weights / field.max()
    return {"centres_m": _frozen(np.round(np.column_stack([cx, cy]), 4)), "widths_m": _frozen(np.round(widths, 4)),
            "weights": _frozen(np.round(weights, 4))}


def check_effect(name: str, value: float, form: str = "") -> None:
    """Raise InputError unless ``name`` (and ``form``) are known and ``value`` lies in the range."""
    if name not in EFFECTS:
        raise InputError(f"effect {name!r}: unknown (known: {', '.join(EFFECTS)})")
    forms = EFFECTS[name].forms
    if form and form not in forms:
        raise InputError(f"effect {name}: form {form!r} unknown (known: {', '.join(forms)})")
    spec = forms[form or EFFECTS[name].default_form]
    lo, hi = spec.valid_range
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (lo <= value <= hi):
        label = f"{name}:{form}" if form else name
        raise InputError(f"effect {label}={value!r}: value outside [{lo}, {hi}] {spec.unit}")


def parse_effect(text: str) -> Effect:
    """Return the Effect described by ``"NAME[:FORM][=VALUE][,KEY=VALUE...]"``.

    Without ``=VALUE`` the form's moderate value is used.

    Raises
    ------
    InputError
        Malformed text, unknown name, form or parameter, or a value out of range; the message
        names it.
    """
    if not isinstance(text, str):
        raise InputError(f"effect {text!r}: expected NAME[:FORM]=VALUE, e.g. input_delay=0.15")
    head, *rest = text.split(",")
    if head.count("=") > 1 or not head.split("=")[0].strip():
        raise InputError(f"effect {text!r}: expected NAME[:FORM]=VALUE, e.g. input_delay=0.15")
    label, eq, raw = (s.strip() for s in head.partition("="))
    name, _, form = (s.strip() for s in label.partition(":"))
    if name not in EFFECTS:
        raise InputError(f"effect {name!r}: unknown (known: {', '.join(EFFECTS)})")
    forms = EFFECTS[name].forms
    if form and form not in forms:
        raise InputError(f"effect {name}: form {form!r} unknown (known: {', '.join(forms)})")
    params = {}
    for item in rest:
        key, eq_p, raw_p = (s.strip() for s in item.partition("="))
        if not eq_p or not key:
            raise InputError(f"effect {text!r}: parameter {item!r} is not KEY=VALUE")
        params[key] = _number(text, raw_p)
    value = forms[form or EFFECTS[name].default_form].moderate if not eq else _number(f"{label}={raw}", raw)
    return Effect(name, value, form, params)


def _number(where: str, raw: str) -> float:
    try:
        value = float(raw)
    except ValueError:
        raise InputError(f"effect {where!r}: {raw!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"effect {where!r}: {raw!r} is not finite")
    return value


def effect_from_dict(doc: dict) -> Effect:
    """Return the Effect written by :meth:`Effect.to_dict` (truth/)."""
    return Effect(doc["name"], doc["value"], doc.get("form", ""), doc.get("params") or {})


def draw_effect(name: str, form: str, value: float, rng: np.random.Generator) -> Effect:
    """Return an Effect of ``form`` whose drawn geometry (azimuths, bumps) comes from ``rng``."""
    return Effect(name, value, form, {"seed": float(rng.integers(2**31))} if form in _DRAWN else {})
