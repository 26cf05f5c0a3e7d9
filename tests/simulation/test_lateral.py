"""Lateral laws against hand computations: values, steady drifts by root finding, Jacobians,
Taylor terms, and the lateral_slip forms acting through them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from simulation.effects import Effect
from simulation.lateral import LATERAL_FORMS, LateralLaw, lateral_accel_and_jacobian, lateral_terms
from simulation.robot import TrueDynamics

K, C = 15.0, 1.0
VX, VY, OM = 0.5, 0.01, 0.6
# vy_dot at (vx, vy, omega) = (0.5, 0.01, 0.6), k_y = 15, c_y = 1, worked out by hand from the laws
# of simulation.lateral's docstring; centripetal part -0.5 * 0.6 = -0.3 in every law
HAND = {
    LateralLaw("linear"): -0.15 - 0.3,
    LateralLaw("tanh", 1.6): -0.64 * math.tanh(0.15 / 0.64) - 0.3,  # a = 1.6 * 1 * 0.4 m/s^2
    LateralLaw("cubic", 0.02): -0.15 * (1 + 0.25) - 0.3,  # (0.01 / 0.02)^2 = 0.25
    LateralLaw("speed_stiffness", 0.5): -0.15 / math.sqrt(2.0) - 0.3,  # (0.5 / 0.5)^2 = 1
}


def _x6(vx, vy, om):
    return np.array([3.0, 2.5, 0.4, vx, vy, om])


@pytest.mark.parametrize("law", list(HAND), ids=lambda law: law.form)
def test_law_value_by_hand(law):
    a, _ = lateral_accel_and_jacobian(law, K, C, VX, VY, OM)
    assert float(a) == pytest.approx(HAND[law], rel=1e-12)
    # the generated code of the true dynamics (another implementation) gives the same vy_dot
    assert TrueDynamics(lateral=law).accel(_x6(VX, VY, OM), [0.3, 0.2])[1] == pytest.approx(HAND[law], rel=1e-12)


@pytest.mark.parametrize("law", list(HAND), ids=lambda law: law.form)
def test_steady_drift_solves_the_law(law):
    """The drift where vy_dot = 0, found by bracketing, against each law's closed form."""
    for vx, om in ((0.5, 0.6), (0.8, 0.45), (-0.3, 1.0)):
        def a_y(vy, vx=vx, om=om):
            return float(lateral_accel_and_jacobian(law, K, C, vx, vy, om)[0])
        vy = brentq(a_y, -0.5, 0.5, xtol=1e-15)
        demand = C * vx * om
        if law.form == "linear":
            expect = -demand / K
        elif law.form == "tanh":
            a = law.shape * C * 0.4
            expect = -(a / K) * math.atanh(demand / a)
        elif law.form == "speed_stiffness":
            expect = -demand * math.sqrt(1 + (vx / law.shape) ** 2) / K
        else:  # cubic: K vy + K / vy_ref^2 vy^3 + demand = 0, its one real root
            roots = np.roots([K / law.shape ** 2, 0.0, K, demand])
            expect = float(roots[np.abs(roots.imag) < 1e-12].real[0])
        assert vy == pytest.approx(expect, rel=1e-9, abs=1e-13), (law.form, vx, om)


@pytest.mark.parametrize("law", list(HAND), ids=lambda law: law.form)
def test_law_jacobian_matches_central_differences(law):
    rng = np.random.default_rng(1)
    vx, vy, om = rng.uniform(-0.9, 0.9, 40), rng.uniform(-0.06, 0.06, 40), rng.uniform(-1.2, 1.2, 40)
    _, J = lateral_accel_and_jacobian(law, K, C, vx, vy, om)
    h = 1e-6
    for col, (dvx, dvy, dom) in enumerate(np.eye(3)):
        num = (lateral_accel_and_jacobian(law, K, C, vx + h * dvx, vy + h * dvy, om + h * dom)[0]
               - lateral_accel_and_jacobian(law, K, C, vx - h * dvx, vy - h * dvy, om - h * dom)[0]) / (2 * h)
        np.testing.assert_allclose(J[:, col], num, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("law", list(HAND), ids=lambda law: law.form)
def test_taylor_terms_are_the_laws_derivatives_at_rest(law):
    terms = lateral_terms(law, K, C)
    h = 1e-3

    def f(vx, vy):
        return float(lateral_accel_and_jacobian(law, K, C, vx, vy, 0.0)[0])

    assert terms["vy"] == pytest.approx((f(0, 1e-7) - f(0, -1e-7)) / 2e-7, rel=1e-6)
    assert terms["vx omega"] == -C
    d3 = (f(0, 2 * h) - 2 * f(0, h) + 2 * f(0, -h) - f(0, -2 * h)) / (2 * h ** 3)  # f''' in vy
    assert terms.get("vy^3", 0.0) == pytest.approx(d3 / 6.0, rel=2e-3, abs=1e-9)
    d_vx2_vy = (f(h, 1e-6) - 2 * f(0, 1e-6) + f(-h, 1e-6)) / h ** 2 / 1e-6  # d^3 / dvx^2 dvy
    assert terms.get("vx^2 vy", 0.0) == pytest.approx(d_vx2_vy / 2.0, rel=2e-3, abs=1e-6)


@pytest.mark.parametrize("form", [f for f in LATERAL_FORMS])
def test_lateral_slip_forms_replace_the_law_and_scale_the_coupling(form):
    """lateral_slip:FORM=g: the law of that form (default shape) with coupling g c_y; for the laws
    whose drift is linear in the demand (linear, tanh) the drift is exactly g times larger."""
    g = 4.0
    law = LateralLaw.default(form)
    slip = TrueDynamics(effect=Effect("lateral_slip", g, form))
    for vx, om in ((0.5, 0.3), (0.6, -0.2)):
        vy = brentq(lambda v, vx=vx, om=om: float(lateral_accel_and_jacobian(law, K, g * C, vx, v, om)[0]),
                    -0.9, 0.9, xtol=1e-15)
        # the true dynamics' vy equation vanishes there (the polynomial has no other vy terms)
        assert slip.accel(_x6(vx, vy, om), [0.0, 0.0])[1] == pytest.approx(0.0, abs=1e-12)
        base = brentq(lambda v, vx=vx, om=om: float(lateral_accel_and_jacobian(law, K, C, vx, v, om)[0]),
                      -0.5, 0.5, xtol=1e-15)
        if form in ("linear", "tanh"):
            assert vy == pytest.approx(g * base, rel=1e-9)
        else:
            assert abs(vy) > abs(base)


def test_bad_law_is_named():
    from groundfloor.errors import InputError

    with pytest.raises(InputError, match="'quadratic'"):
        LateralLaw("quadratic")
    with pytest.raises(InputError, match="vy_ref_m_s=0.0"):
        LateralLaw("cubic", 0.0)
