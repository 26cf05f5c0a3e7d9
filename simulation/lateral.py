"""Lateral laws of the simulated robot: how the sideways velocity ``vy`` answers a turn.

Thesis eq. 7.8 says ``vy_dot = 0``; a skid-steered body does slip outwards in turns. Every law
here is the rigid-body lateral equation ``vy_dot + c_y vx omega = F_y / m`` (``c_y = 1`` for a
rigid body, perturbed in variants: the instantaneous centre of rotation of a skid-steered
vehicle is not at the body origin) with a different lateral tyre force ``F_y / m``:

``linear`` (the simulator's law until variants existed, :mod:`simulation.robot`)
    ``F_y / m = -k_y vy``: steady drift ``vy = -c_y vx omega / k_y``.
``tanh``
    A saturating tyre: ``F_y / m = -a tanh(k_y vy / a)``, the same slope ``k_y`` at zero slip
    but bounded by ``a = sat_ratio c_y DEMAND_M_S2``. ``DEMAND_M_S2`` (0.4 m/s^2) bounds the
    centripetal demand ``|vx omega|`` at model B's steady states (0.38 m/s^2), so with
    ``sat_ratio > 1`` a steady drift ``vy = -(a / k_y) atanh(c_y vx omega / a)`` exists over the
    whole envelope, growing faster than linearly towards its edge.
``cubic``
    A hardening tyre: ``F_y / m = -k_y vy (1 + (vy / vy_ref)^2)``: the drift grows more slowly
    than linearly once it reaches ``vy_ref``.
``speed_stiffness``
    A cornering stiffness that falls with speed, as the slip angle ``vy / |vx|`` of a tyre
    suggests: ``F_y / m = -k_y vy / sqrt(1 + (vx / v_ref)^2)``, bounded at standstill and about
    ``k_y v_ref / |vx|`` when fast (the bicycle model's ``C / (m vx)``).

A slip gain ``g`` (the ``lateral_slip`` effect, :mod:`simulation.effects`) multiplies the
centripetal coupling ``c_y``; for ``tanh`` the bound ``a`` scales with it, so that the drift is
exactly ``g`` times larger for every law whose force is linear in the demand (``linear``,
``tanh``) and grows less than ``g``-fold for the others.

:func:`lateral_source` writes the law as Python source for :mod:`simulation.rk4_codegen`;
:func:`lateral_accel_and_jacobian` evaluates it with its Jacobian on numpy arrays for
:class:`simulation.robot.TrueDynamics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from groundfloor.errors import InputError

DEMAND_M_S2 = 0.4  # bound on |vx omega| at model B's steady states (0.38 m/s^2)

#: form -> (name of its shape parameter, unit, range of variants' draws, default, one-line doc)
LATERAL_FORMS: dict[str, tuple[str | None, str, tuple[float, float] | None, float, str]] = {
    "linear": (None, "", None, 0.0, "linear tyre force -k_y vy"),
    "tanh": ("sat_ratio", "", (1.3, 2.5), 1.6,
             "saturating tyre force -a tanh(k_y vy / a), a = sat_ratio c_y 0.4 m/s^2"),
    "cubic": ("vy_ref_m_s", "m/s", (0.01, 0.04), 0.02,
              "hardening tyre force -k_y vy (1 + (vy / vy_ref)^2)"),
    "speed_stiffness": ("v_ref_m_s", "m/s", (0.3, 1.0), 0.5,
                        "cornering stiffness falling with speed: -k_y vy / sqrt(1 + (vx / v_ref)^2)"),
}


@dataclass(frozen=True)
class LateralLaw:
    """One lateral law: a form of ``LATERAL_FORMS`` and its shape parameter (unused by ``linear``)."""

    form: str = "linear"
    shape: float = 0.0

    def __post_init__(self):
        if self.form not in LATERAL_FORMS:
            raise InputError(f"lateral law {self.form!r}: unknown (known: {', '.join(LATERAL_FORMS)})")
        if self.form != "linear" and not (math.isfinite(self.shape) and self.shape > 0):
            raise InputError(f"lateral law {self.form}: {LATERAL_FORMS[self.form][0]}={self.shape!r} must be > 0")

    @classmethod
    def default(cls, form: str) -> LateralLaw:
        """Return the law of ``form`` with its default shape."""
        if form not in LATERAL_FORMS:
            raise InputError(f"lateral law {form!r}: unknown (known: {', '.join(LATERAL_FORMS)})")
        return cls(form, LATERAL_FORMS[form][3])

    @property
    def polynomial(self) -> bool:
        """True when the law is a polynomial in ``vx, vy, omega`` (its terms are exact)."""
        return self.form in ("linear", "cubic")

    def to_dict(self) -> dict:
        """Return the law as plain values for truth/ (``{form, <shape name>: value}``)."""
        name = LATERAL_FORMS[self.form][0]
        return {"form": self.form} | ({name: float(self.shape)} if name else {})

    @classmethod
    def from_dict(cls, doc: dict) -> LateralLaw:
        """Return the law written by :meth:`to_dict`."""
        name = LATERAL_FORMS.get(doc.get("form"), (None,))[0]
        return cls(doc["form"], float(doc[name]) if name else 0.0)


def lateral_source(law: LateralLaw, k_y: float, c_y: float, vx: str, vy: str, om: str) -> str:
    """Return a Python expression of ``vy_dot`` for the generated code (names ``vx, vy, om``).

    ``c_y`` already holds any slip gain. The expression uses only ``tanh`` and ``sqrt``, which
    the generated code binds to :mod:`math` or numpy.
    """
    centripetal = f"{c_y!r}*{vx}*{om}"
    if law.form == "linear":
        return f"-{k_y!r}*{vy} - {centripetal}"
    if law.form == "tanh":
        a = law.shape * c_y * DEMAND_M_S2
        return f"-{a!r}*tanh({k_y / a!r}*{vy}) - {centripetal}"
    if law.form == "cubic":
        return f"-{k_y!r}*{vy}*(1.0 + {1.0 / law.shape ** 2!r}*{vy}*{vy}) - {centripetal}"
    return f"-{k_y!r}*{vy}/sqrt(1.0 + {1.0 / law.shape ** 2!r}*{vx}*{vx}) - {centripetal}"


def lateral_accel_and_jacobian(law: LateralLaw, k_y: float, c_y: float, vx, vy, om
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Return ``vy_dot`` and its derivatives ``[d/dvx, d/dvy, d/domega]`` (last axis) on arrays."""
    vx, vy, om = np.broadcast_arrays(*(np.asarray(v, float) for v in (vx, vy, om)))
    if law.form == "tanh":
        a = law.shape * c_y * DEMAND_M_S2
        th = np.tanh(k_y / a * vy)
        force, d_vx, d_vy = -a * th, 0.0 * vx, -k_y * (1.0 - th * th)
    elif law.form == "cubic":
        r = 1.0 / law.shape ** 2
        force, d_vx, d_vy = -k_y * vy * (1.0 + r * vy * vy), 0.0 * vx, -k_y * (1.0 + 3.0 * r * vy * vy)
    elif law.form == "speed_stiffness":
        r = 1.0 / law.shape ** 2
        root = np.sqrt(1.0 + r * vx * vx)
        force, d_vx, d_vy = -k_y * vy / root, k_y * vy * r * vx / root ** 3, -k_y / root
    else:
        force, d_vx, d_vy = -k_y * vy, 0.0 * vx, np.full_like(vy, -k_y)
    a_y = force - c_y * vx * om
    return a_y, np.stack([d_vx - c_y * om, d_vy, -c_y * vx], axis=-1)


def lateral_terms(law: LateralLaw, k_y: float, c_y: float) -> dict[str, float]:
    """Return ``{feature: coefficient}`` of ``vy_dot``: exact for polynomial laws, else the
    third-order Taylor expansion about ``vy = 0, vx = 0`` (pysindy feature names)."""
    if law.form == "linear":
        return {"vy": -k_y, "vx omega": -c_y}
    if law.form == "cubic":
        return {"vy": -k_y, "vx omega": -c_y, "vy^3": -k_y / law.shape ** 2}
    if law.form == "tanh":  # -a tanh(k vy / a) = -k vy + k^3 vy^3 / (3 a^2) - ...
        a = law.shape * c_y * DEMAND_M_S2
        return {"vy": -k_y, "vx omega": -c_y, "vy^3": k_y ** 3 / (3.0 * a * a)}
    return {"vy": -k_y, "vx omega": -c_y, "vx^2 vy": 0.5 * k_y / law.shape ** 2}
