"""Body-side effect mechanisms: source lines for the generated dynamics and their Jacobians.

The mechanisms are stated in :mod:`simulation.effects` (heading slope, floor fields, track
friction, lateral slip). Each is written twice, as the two consumers need it:
:func:`body_source` gives Python source lines that :mod:`simulation.rk4_codegen` puts into the
generated accelerations (floats in the RK4 loop, numpy arrays for
:meth:`simulation.robot.TrueDynamics.accel`); :func:`add_body_jacobians` adds their analytic
derivatives for :meth:`simulation.robot.TrueDynamics.accel_and_jacobians` (checked against
central differences in the tests). :func:`effective_lateral` says which lateral law and slip
gain a robot with an effect has.
"""

from __future__ import annotations

import math

import numpy as np

from simulation.effects import _AREA_CENTER, EFFECTS, Effect
from simulation.lateral import LATERAL_FORMS, LateralLaw
from simulation.robot_params import RobotParams


def effective_lateral(law: LateralLaw, effect: Effect | None) -> tuple[LateralLaw, float]:
    """Return the lateral law in force and the slip gain on its coupling (1 without slip)."""
    if effect is None or effect.name != "lateral_slip":
        return law, 1.0
    if effect.form == "coupling":
        return law, float(effect.value)
    shape = LATERAL_FORMS[effect.form][0]
    return LateralLaw(effect.form, float(effect.param(shape)) if shape else 0.0), float(effect.value)


def slope(effect: Effect | None) -> tuple[float, float] | None:
    """Return ``(tilt_rad, downhill azimuth_rad)`` of a heading_dependence floor, else None."""
    if effect is None or effect.name != "heading_dependence":
        return None
    return math.radians(effect.value), math.radians(effect.param("azimuth_deg"))


def _damping(params: RobotParams) -> tuple[float, float]:
    """Return model B's linear damping ``(d_vx, d_omega)``: minus the ``vx`` and ``omega`` coefficients."""
    return -dict(params.terms_vx)["vx"], -dict(params.terms_omega)["omega"]


def body_source(params: RobotParams, effect: Effect | None, law: LateralLaw, sv: tuple, indent: str
                ) -> list[str]:
    """Return source lines adding the effect's body mechanism to ``ax, ay, aw``.

    ``sv`` names the states ``(x, y, psi, vx, vy, om)``; only ``tanh, sqrt, cos, sin, exp``
    are used (bound to :mod:`math` or numpy by the caller). A non-linear lateral law is not
    here: it replaces the polynomial ``vy`` equation (:func:`simulation.lateral.lateral_source`).
    """
    x, y, psi, vx, _, om = sv
    name, form = (effect.name, effect.form) if effect is not None else (None, None)
    lines = []
    if name == "heading_dependence":
        a_g = params.g_m_s2 * math.sin(math.radians(effect.value))
        pd = math.radians(effect.param("azimuth_deg"))
        lines += [f"{indent}ax = ax + {a_g!r}*cos({psi} - {pd!r})",
                  f"{indent}ay = ay - {a_g!r}*sin({psi} - {pd!r})"]
    elif name == "position_dependence":
        lines.append(f"{indent}s_ = {_field_source(effect, x, y)}")
        d_vx, d_om = _damping(params)
        lines += [f"{indent}ax = ax - {effect.value * d_vx!r}*s_*{vx}",
                  f"{indent}aw = aw - {effect.value * d_om!r}*s_*{om}"]
    elif (name, form) == ("asymmetry", "friction"):
        d_vx, d_om = _damping(params)
        b = params.track_half_width_m
        lines += [f"{indent}ax = ax - {effect.value * d_vx * b / 2.0!r}*{om}",
                  f"{indent}aw = aw - {effect.value * d_om / (2.0 * b)!r}*{vx}"]
    elif name == "lateral_slip":
        law_eff, gain = effective_lateral(law, effect)
        if law_eff.form == "linear":  # the polynomial holds the law: add the extra coupling
            lines.append(f"{indent}ay = ay - {(gain - 1.0) * params.lateral_coupling!r}*{vx}*{om}")
    return lines


def _field_source(effect: Effect, x: str, y: str) -> str:
    """Return an expression of the floor field ``s(x, y)`` in [0, 1] (bumps may overlap above 1)."""
    if effect.form == "disc":
        fx = EFFECTS["position_dependence"].fixed
        (cx, cy), r = fx["patch_center_local_m"], fx["patch_radius_m"]
        half_scale = fx["patch_edge_m"] / (2.0 * math.log(9.0))
        return f"0.5*(1.0 + tanh(({r!r} - sqrt(({x} - {cx!r})**2 + ({y} - {cy!r})**2 + 1e-12))/{half_scale!r}))"
    if effect.form == "bumps":
        return " + ".join(f"{w!r}*exp(-(({x} - {cx!r})**2 + ({y} - {cy!r})**2)*{0.5 / sig ** 2!r})"
                          for (cx, cy), sig, w in zip(effect.param("centres_m"), effect.param("widths_m"),
                                                      effect.param("weights")))
    az = math.radians(effect.param("azimuth_deg"))
    nx, ny, ell = math.cos(az), math.sin(az), effect.param("length_m")
    cx, cy = _AREA_CENTER
    return f"0.5*(1.0 + tanh((({x} - {cx!r})*{nx!r} + ({y} - {cy!r})*{ny!r})/{ell!r}))"


def field_and_gradient(effect: Effect, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the floor field ``s`` of a position_dependence effect and ``ds/dx``, ``ds/dy``."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if effect.form == "disc":
        fx = EFFECTS["position_dependence"].fixed
        (cx, cy), r = fx["patch_center_local_m"], fx["patch_radius_m"]
        h = fx["patch_edge_m"] / (2.0 * math.log(9.0))
        dx, dy = x - cx, y - cy
        d = np.sqrt(dx * dx + dy * dy + 1e-12)
        th = np.tanh((r - d) / h)
        ds_dd = -0.5 * (1.0 - th * th) / h
        return 0.5 * (1.0 + th), ds_dd * dx / d, ds_dd * dy / d
    if effect.form == "bumps":
        s, sx, sy = 0.0 * x, 0.0 * x, 0.0 * x
        for (cx, cy), sig, w in zip(effect.param("centres_m"), effect.param("widths_m"), effect.param("weights")):
            e = w * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) * (0.5 / sig ** 2))
            s, sx, sy = s + e, sx - e * (x - cx) / sig ** 2, sy - e * (y - cy) / sig ** 2
        return s, sx, sy
    az = math.radians(effect.param("azimuth_deg"))
    nx, ny, ell = math.cos(az), math.sin(az), effect.param("length_m")
    th = np.tanh(((x - _AREA_CENTER[0]) * nx + (y - _AREA_CENTER[1]) * ny) / ell)
    ds = 0.5 * (1.0 - th * th) / ell
    return 0.5 * (1.0 + th), ds * nx, ds * ny


def add_body_jacobians(params: RobotParams, effect: Effect | None, law: LateralLaw, x6: np.ndarray,
                       J_x: np.ndarray) -> None:
    """Add the derivatives of the effect's body mechanism to ``J_x (..., 3, 6)`` in place."""
    if effect is None:
        return
    vx, om = x6[..., 3], x6[..., 5]
    if effect.name == "heading_dependence":
        a_g = params.g_m_s2 * math.sin(math.radians(effect.value))
        d = x6[..., 2] - math.radians(effect.param("azimuth_deg"))
        J_x[..., 0, 2] += -a_g * np.sin(d)
        J_x[..., 1, 2] += -a_g * np.cos(d)
    elif effect.name == "position_dependence":
        s, s_x, s_y = field_and_gradient(effect, x6[..., 0], x6[..., 1])
        d_vx, d_om = _damping(params)
        for row, k, state in ((0, effect.value * d_vx, vx), (2, effect.value * d_om, om)):
            J_x[..., row, 0] -= k * state * s_x
            J_x[..., row, 1] -= k * state * s_y
        J_x[..., 0, 3] -= effect.value * d_vx * s
        J_x[..., 2, 5] -= effect.value * d_om * s
    elif (effect.name, effect.form) == ("asymmetry", "friction"):
        d_vx, d_om = _damping(params)
        b = params.track_half_width_m
        J_x[..., 0, 5] -= effect.value * d_vx * b / 2.0
        J_x[..., 2, 3] -= effect.value * d_om / (2.0 * b)
    elif effect.name == "lateral_slip":
        law_eff, gain = effective_lateral(law, effect)
        if law_eff.form == "linear":
            k = (gain - 1.0) * params.lateral_coupling
            J_x[..., 1, 3] -= k * om
            J_x[..., 1, 5] -= k * vx
