"""The per-track friction difference (asymmetry) and the nonlinear lateral laws (lateral_slip), issue 15 item 1.

References: the forces of two tracks with different rolling resistance, written out here from the
track speeds ``vx -/+ b omega`` (not from the family's columns); central differences for the
Jacobians; and the simulator (robot parameters of table 6.3, its own tyre laws) for the signs a
saturating, a hardening and a speed-softened tyre must give the fitted law.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from groundfloor.errors import InputError
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel
from simulation.effects import Effect
from simulation.robot_params import RobotParams
from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose.data import model_split
from sindy_ekf.diagnose.design import equation_weights, null_prediction
from sindy_ekf.diagnose.extend import ExtendedModel
from sindy_ekf.diagnose.families import mechanism_spec
from sindy_ekf.diagnose.fitting import score_family
from sindy_ekf.diagnose.rank import RankedCause, unresolved
from sindy_ekf.diagnose.scoring import score_mechanisms
from tests.support.diagnose_synth import fit_reference_with_lateral_law

FRICTION = mechanism_spec("asymmetry", "track_friction")


def _damped_model(d_vx: float, d_om: float) -> SindyModel:
    lib = make_library("poly3")
    coef = np.zeros((3, lib.n_features))
    names = list(lib.feature_names)
    coef[0, names.index("vx")], coef[0, names.index("u1")] = -d_vx, d_vx
    coef[1, names.index("vy")] = -5.0
    coef[2, names.index("omega")], coef[2, names.index("u2")] = -d_om, d_om
    return SindyModel(library=lib, coef=coef, hyperparameters={"tau": 1.0})


@pytest.mark.parametrize("f", [0.12, -0.07])
def test_track_friction_from_the_forces_of_two_tracks(f):
    """Each track resists in proportion to its own speed, the right one (1 + f/2), the left (1 - f/2)
    times the mean; with f = 0 the forces are the model's damping. The columns fitted to the extra
    accelerations give back f and the half track b."""
    d_vx, d_om, b = 4.0, 3.0, 0.29
    rng = np.random.default_rng(3)
    x6 = rng.normal(size=(200, 6))
    vx, om = x6[:, 3], x6[:, 5]
    left, right = vx - b * om, vx + b * om

    def accel(f_):
        ax = -d_vx / 2 * ((1 - f_ / 2) * left + (1 + f_ / 2) * right)
        aw = -d_om / (2 * b) * ((1 + f_ / 2) * right - (1 - f_ / 2) * left)
        return np.stack([ax, np.zeros_like(ax), aw], -1)

    np.testing.assert_allclose(accel(0.0)[:, 0], -d_vx * vx)  # without a difference: the model's damping
    np.testing.assert_allclose(accel(0.0)[:, 2], -d_om * om)
    extra = accel(f) - accel(0.0)
    cols = FRICTION.columns(x6, np.zeros((200, 2)), np.zeros(200), np.zeros((1, 0)))[0]  # (N, 3, 2)
    beta = np.linalg.lstsq(cols.reshape(-1, 2), extra.reshape(-1), rcond=None)[0]
    est = FRICTION.estimate(np.zeros(0), beta, _damped_model(d_vx, d_om))
    assert est["friction_difference"] == pytest.approx(f, rel=1e-9)
    assert est["half_track_m"] == pytest.approx(b, rel=1e-9)
    assert est["mechanism"] == "track_friction"


def test_track_friction_of_inconsistent_signs_is_no_friction_difference():
    """Both columns carry the sign of -f (a speed loss in turns and a yaw toward the rougher side):
    opposite signs are no friction difference of any size."""
    est = FRICTION.estimate(np.zeros(0), np.array([0.1, -0.2]), _damped_model(4.0, 3.0))
    assert np.isnan(est["friction_difference"]) and np.isnan(est["half_track_m"])
    assert est["yaw_per_speed_1_m_s"] == -0.2


@pytest.mark.parametrize("family,mechanism", [("asymmetry", "track_friction"), ("lateral_slip", "saturating"),
                                              ("lateral_slip", "speed_dependent")])
def test_columns_by_hand_and_jacobians_by_central_differences(family, mechanism):
    spec = mechanism_spec(family, mechanism)
    rng = np.random.default_rng(5)
    x6, u = rng.normal(size=(9, 6)), rng.normal(size=(9, 2))
    cols, jac = spec.columns(x6, u, np.zeros(9), np.zeros((1, 0)), with_jacobian=True)
    vx, vy, om = x6[:, 3], x6[:, 4], x6[:, 5]
    want = np.zeros((9, 3, spec.n_columns))
    if mechanism == "track_friction":
        want[:, 0, 0], want[:, 2, 1] = om, vx
    else:
        want[:, 1, 0], want[:, 1, 1] = vx * om, vy
        want[:, 1, 2] = (vx * om) ** 3 if mechanism == "saturating" else vx ** 3 * om
    np.testing.assert_allclose(cols[0], want)
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-6
        num = (spec.columns(x6 + d, u, np.zeros(9), np.zeros((1, 0)))
               - spec.columns(x6 - d, u, np.zeros(9), np.zeros((1, 0)))) / 2e-6
        np.testing.assert_allclose(num[0], jac[0, ..., k], atol=1e-5)


def test_only_the_linear_lateral_law_is_a_sindy_model(tmp_path):
    model = _damped_model(4.0, 3.0)
    ext = ExtendedModel.added(model, "lateral_slip", np.zeros(0), np.array([-0.5, -1.0, 2.0]),
                              {"mechanism": "saturating"})
    with pytest.raises(InputError, match="not expressible"):
        ext.as_sindy()
    back = ExtendedModel.load(ext.to_json(tmp_path / "ext.json"))
    x6 = np.array([[0, 0, 0, 0.6, 0.02, 0.5]])
    np.testing.assert_allclose(back.accel(x6, np.zeros(2)), ext.accel(x6, np.zeros(2)))
    # the cubic term is in the lateral equation only: (0.6 * 0.5)^3 * 2 on top of the linear law
    lin = ExtendedModel.added(model, "lateral_slip", np.zeros(0), np.array([-0.5, -1.0]), {})
    diff = ext.accel(x6, np.zeros(2)) - lin.accel(x6, np.zeros(2))
    np.testing.assert_allclose(diff, [[0.0, 2.0 * 0.3 ** 3, 0.0]], atol=1e-12)


def test_an_additive_mechanism_is_never_unresolved_by_its_law_keys():
    """lateral_slip's ``coupling`` is the law's coupling, not an input mechanism's parameter that is
    zero without it: a small one within its spread is no reason to drop the cause."""
    est = {"coupling": -0.04, "damping_1_s": 0.45, "mechanism": "saturating"}
    score = type("S", (), {"estimate": est, "estimate_std": {"coupling": 0.1}})()
    assert unresolved(RankedCause("lateral_slip", 0.3, 0.1, True, score, ""), 0.04) == ""
    asym = type("S", (), {"estimate": {"coupling": 0.01, "mechanism": "throttle_to_turn_coupling"},
                          "estimate_std": {"coupling": 0.02}})()
    assert "not resolved" in unresolved(RankedCause("asymmetry", 0.3, 0.1, True, asym, ""), 0.04)


@pytest.fixture(scope="module")
def lab_model():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_reference_with_lateral_law(n_runs=4, run_s=45.0, rate_hz=25.0)


def _splits(model, effect):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        train, test, a, b = simulate_states_campaign(31337, effect, run_s=45.0, rate_hz=25.0)
        tr = model_split(model, train, a, 2.0, what="train runs")
        te = model_split(model, test, b, 2.0, what="test runs")
    return tr, te, equation_weights(model, tr), {"train": null_prediction(model, tr), "test": null_prediction(model, te)}


def test_the_simulators_track_friction_is_chosen_and_measured(lab_model):
    """The simulator's right track drags 8 % more: of the asymmetry's mechanisms the train runs pick
    the track friction, which measures the difference and the robot's half track (table 6.3) within
    10 %; on the same campaign without it the friction is no gain on the test runs."""
    tr, te, w, bp = _splits(lab_model, Effect("asymmetry", 0.08, form="friction"))
    s = score_mechanisms("asymmetry", lab_model, tr, te, w, bp, uncertainty=False)
    assert s.estimate["mechanism"] == "track_friction"
    assert s.estimate["friction_difference"] == pytest.approx(0.08, rel=0.1)
    assert s.estimate["half_track_m"] == pytest.approx(RobotParams().track_half_width_m, rel=0.1)
    assert s.gain > 0.3
    tr, te, w, bp = _splits(lab_model, None)
    assert score_family(FRICTION, lab_model, tr, te, w, bp, uncertainty=False).gain < 0.01


@pytest.mark.parametrize("form,mechanism,sign", [("tanh", "saturating", 1), ("cubic", "saturating", -1),
                                                 ("speed_stiffness", "speed_dependent", 1)])
def test_the_simulators_tyre_laws_give_the_nonlinear_drift_its_sign(lab_model, form, mechanism, sign):
    """A saturating tyre (tanh) drifts faster than linearly with the demand vx omega, a hardening one
    (cubic) slower, and a cornering stiffness falling with speed drifts more per unit demand when
    fast: the nonlinear part of the fitted law adds to the linear drift, opposes it, adds to it."""
    tr, te, w, bp = _splits(lab_model, Effect("lateral_slip", 4.0, form=form))
    s = score_family(mechanism_spec("lateral_slip", mechanism), lab_model, tr, te, w, bp, uncertainty=False,
                     refit=False)
    assert np.sign(s.estimate["nonlinear_share"]) == sign
    assert abs(s.estimate["nonlinear_share"]) > 0.2
