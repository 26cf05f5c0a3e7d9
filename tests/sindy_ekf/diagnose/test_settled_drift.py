"""The lateral law's drift read from a model's whole ``vy`` equation (:mod:`sindy_ekf.diagnose.lateral`).

References computed here independently of the module: the settled root of a cubic lateral law by
``numpy.roots`` sample by sample, and slip gains from drifts written by hand (a two-term law settles at
``-c / k vx omega``).
"""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.types import BodyStates
from identification.sindy.model import model_from_terms
from sindy_ekf.diagnose.data import split_from_states
from sindy_ekf.diagnose.extend import ExtendedModel
from sindy_ekf.diagnose.fitting import FamilyScore
from sindy_ekf.diagnose.lateral import settled_vy, vy_row, with_settled_drift

K, C = -15.0, -1.0  # the model's lateral law vy' = K vy + C vx omega: it settles at -C / K = -0.0667 s x vx omega
DATA_DRIFT = -0.2  # the campaign's: vy = -0.2 s x vx omega, 3 x the model's


def law(cubic: float = 0.0):
    """A model whose vy equation is the two-term law (plus ``cubic vy^3``), poly3, unit forward and yaw lags."""
    vy = {"vy": K, "vx omega": C} | ({"vy^3": cubic} if cubic else {})
    return model_from_terms({"vx": {"vx": -2.0, "u1": 2.0}, "vy": vy, "omega": {"omega": -3.0, "u2": 3.0}}, "poly3")


def turning_runs(n_runs: int = 3, run_s: float = 40.0, rate_hz: float = 25.0, spread: float = 0.0) -> list[BodyStates]:
    """Runs whose measured vy is exactly ``DATA_DRIFT vx omega`` (run ``r`` times ``1 + spread (r - 1)``;
    poses unused by the drift)."""
    out = []
    for r in range(n_runs):
        t = np.arange(0.0, run_s, 1.0 / rate_hz)
        vx = 0.5 + 0.3 * np.sin(0.4 * t + r)
        om = 0.7 * np.sin(0.25 * t + 2.0 * r)
        z = np.zeros_like(t)
        vy = DATA_DRIFT * (1 + spread * (r - 1)) * vx * om
        out.append(BodyStates(t=t, vx=vx, vy=vy, omega=om, u1=vx, u2=om, x=z, y=z, yaw=z))
    return out


def test_the_settled_lateral_velocity_of_a_cubic_law_is_its_stable_root():
    model = law(cubic=-2000.0)
    q = np.linspace(-0.6, 0.6, 13)  # vx omega
    x6 = np.zeros((len(q), 6))
    x6[:, 3], x6[:, 5] = 0.6, q / 0.6
    vy, ok = settled_vy(lambda x, v: vy_row(model.f_and_jacobians(x[:, 3:], v), 1), x6, np.zeros((len(q), 2)))
    # -2000 vy^3 - 15 vy - q = 0 has one real root (the cubic is monotone): numpy's companion matrix
    ref = [float(np.real(r[np.abs(np.imag(r)) < 1e-9][0])) for r in (np.roots([-2000.0, 0.0, K, C * v]) for v in q)]
    assert ok.all() and vy == pytest.approx(ref, abs=1e-9)
    # -15 (-0.03452) - 0.6 - 2000 (-0.03452)^3 = 0.5178 - 0.6 + 0.0823 = 0.0001: less than the two-term
    # law's -0.04 (it hardens)
    assert vy[-1] == pytest.approx(-0.03452, abs=1e-5)


def test_the_slip_gain_is_the_datas_drift_over_the_models_and_the_extension_its_own():
    model = law()
    runs = turning_runs()
    split = split_from_states(runs, ["a", "b", "c"], 2.0)
    # the linear mechanism adds -3 vx omega to the lateral equation: the extension settles at -4 / -15
    beta = np.array([-3.0, 0.0])
    score = FamilyScore("lateral_slip", np.zeros(0), beta, 0.5, {}, 0.5,
                        {"model_has_lateral_law": True, "slip_gain": -99.0, "drift_s": -99.0})
    out = with_settled_drift(score, model, split)
    est = out.estimate
    assert est["slip_from"] == "settled"
    assert est["drift_s"] == pytest.approx(DATA_DRIFT, rel=1e-9)
    assert est["slip_gain"] == pytest.approx(DATA_DRIFT / (-C / K), rel=1e-6)  # 3.0: the data's
    assert est["law_slip_gain"] == pytest.approx(4.0, rel=1e-6)  # the law as fitted settles at -4 / -15
    # anchored: the coupling that settles at the data's drift, -K DATA_DRIFT = -3 in all, -2 beside the model's -1
    assert est["drift_anchored"] is True
    assert out.beta == pytest.approx([-2.0, 0.0], abs=1e-6)
    # these runs' vy follows vx omega without any lag: the fastest settling the scale may give, 50 1/s, so the
    # equation's coefficients are 50 / 15 times the anchored law's (the drift they settle at the same)
    assert est["settling_scale"] == pytest.approx(50.0 / 15.0) and est["settling_time_s"] == pytest.approx(0.02)
    assert est["coupling"] == pytest.approx(-3.0 * 50 / 15, abs=1e-6) and est["damping_1_s"] == pytest.approx(50.0)
    assert est["extension_slip_gain"] == pytest.approx(3.0, rel=1e-4)
    # the extension's other equations are shielded from its own drift
    ext = ExtendedModel.added(model, "lateral_slip", np.zeros(0), out.beta, est)
    assert ext.vy_scale == pytest.approx(3.0, rel=1e-4)
    # a model without a lateral law has no drift to compare with: the score is left as it was
    bare = FamilyScore("lateral_slip", np.zeros(0), beta, 0.5, {}, 0.5, {"model_has_lateral_law": False})
    assert with_settled_drift(bare, model, split) is bare


def test_the_slip_gains_uncertainty_is_the_spread_of_the_runs_drifts():
    model, beta = law(), np.array([-3.0, 0.0])
    score = FamilyScore("lateral_slip", np.zeros(0), beta, 0.5, {}, 0.5, {"model_has_lateral_law": True})
    same = with_settled_drift(score, model, split_from_states(turning_runs(), list("abc"), 2.0))
    assert same.estimate_std["slip_gain"] == pytest.approx(0.0, abs=1e-9)  # every run drifts alike
    # runs drifting 0.9, 1.0 and 1.1 x: the slip gain near 3 with a jackknife spread of the order of 0.3 / sqrt(3)
    apart = with_settled_drift(score, model, split_from_states(turning_runs(spread=0.1), list("abc"), 2.0))
    assert apart.estimate["slip_gain"] == pytest.approx(3.0, rel=0.05)
    assert 0.05 < apart.estimate_std["slip_gain"] < 0.5
    # the law, anchored on all runs, is the same in every jackknife: a two-term law settles at one drift
    assert apart.estimate_std["extension_slip_gain"] == pytest.approx(0.0, abs=1e-9)


def test_a_nonlinear_law_is_anchored_at_the_datas_drift_where_its_damping_is_kept():
    """A saturating law (the cubic in the demand) whose fitted damping is a third of the model's, as the noise
    on vy shrinks it, and whose cubic cancels most of its coupling in the turns: its own settled drift is far
    from the data's. Anchored, the settled roots (by hand: the equation is linear in vy) give the data's drift,
    and the law's damping and cubic are as fitted."""
    model = law()
    runs = turning_runs()
    split = split_from_states(runs, ["a", "b", "c"], 2.0)
    beta = np.array([-0.5, 10.0, 5.0])  # total damping -5 1/s, coupling -1.5, cubic +5
    score = FamilyScore("lateral_slip", np.zeros(0), beta, 0.5, {}, 0.5,
                        {"model_has_lateral_law": True, "mechanism": "saturating"})
    out = with_settled_drift(score, model, split)
    assert out.estimate["drift_anchored"] is True and out.beta[1:] == pytest.approx(beta[1:])
    c = C + out.beta[0]
    q = np.concatenate([r.vx * r.omega for r in runs])
    turn = np.abs(q) > np.quantile(np.abs(q), 0.5)
    # (K + 10) vy + c q + 5 q^3 = 0: the drift's slope on q over the turns
    vy = -(c * q + 5.0 * q ** 3) / (K + 10.0)
    assert float(vy[turn] @ q[turn] / (q[turn] @ q[turn])) == pytest.approx(DATA_DRIFT, rel=1e-3)
    assert out.estimate["extension_slip_gain"] == pytest.approx(3.0, rel=1e-3)
    assert abs(out.estimate["law_slip_gain"] - 3.0) > 1.0


def test_a_law_that_cannot_settle_at_the_datas_drift_is_kept_as_fitted_and_said_not_anchored():
    """A model whose lateral equation softens (``+800 vy^3``) folds at ``|vy| = sqrt(5 / 800) = 0.079 m/s``
    (where ``-15 vy + 800 vy^3`` stops growing): the data's ``vy = -0.2 vx omega`` lies beyond the fold on 45 %
    of the turns (below, by hand), and every coupling that moves the settled drift toward it pushes more turns
    past the fold. No anchoring is found: the law keeps its fitted coupling, ``drift_anchored`` says so, and the
    extension settles at the law's own drift."""
    model = model_from_terms({"vx": {"vx": -2.0, "u1": 2.0}, "vy": {"vy": K, "vx omega": C, "vy^3": 800.0},
                              "omega": {"omega": -3.0, "u2": 3.0}}, "poly3")
    runs = turning_runs()
    q = np.concatenate([r.vx * r.omega for r in runs])
    turn = np.abs(q) > np.quantile(np.abs(q), 0.5)
    assert 0.4 < np.mean(-DATA_DRIFT * np.abs(q[turn]) > np.sqrt(5.0 / 800.0)) < 0.5
    beta = np.array([-0.5, 0.0])
    score = FamilyScore("lateral_slip", np.zeros(0), beta, 0.5, {}, 0.5, {"model_has_lateral_law": True})
    out = with_settled_drift(score, model, split_from_states(runs, ["a", "b", "c"], 2.0))
    est = out.estimate
    assert est["drift_anchored"] is False and out.beta == pytest.approx(beta, abs=0.0)
    assert est["extension_slip_gain"] == pytest.approx(est["law_slip_gain"], rel=1e-9)
    assert est["slip_gain"] > 2.5 and est["law_slip_gain"] < 2.0  # the data drift 3 x, the law as fitted far less


def lagging_runs(k_true: float, n_runs: int = 3, run_s: float = 40.0, rate_hz: float = 25.0) -> list[BodyStates]:
    """Runs whose vy follows ``DATA_DRIFT vx omega`` through a first-order lag of rate ``k_true`` (1/s),
    integrated by scipy's adaptive Runge-Kutta at a tolerance far below the sampling (independent of the
    module's exponential Euler)."""
    from scipy.integrate import solve_ivp

    out = []
    for r in range(n_runs):
        def vx(t, r=r):
            return 0.5 + 0.3 * np.sin(0.4 * t + r)

        def om(t, r=r):
            return 0.7 * np.sin(0.9 * t + 2.0 * r)

        t = np.arange(0.0, run_s, 1.0 / rate_hz)
        sol = solve_ivp(lambda s, y: -k_true * (y - DATA_DRIFT * vx(s) * om(s)), (0.0, t[-1]), [0.0],
                        t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853")
        z = np.zeros_like(t)
        out.append(BodyStates(t=t, vx=vx(t), vy=sol.y[0], omega=om(t), u1=vx(t), u2=om(t), x=z, y=z, yaw=z))
    return out


def test_the_settling_scale_is_the_output_error_time_scale_of_the_measured_lateral_velocity():
    """The model's lateral law settles at 15 1/s; the runs' vy lags vx omega at 5 1/s. Output error on vy picks
    the scale 1/3 (the candidate rates hold 5 1/s exactly; one grid step is 12 %), the drift stays anchored,
    and the extension's vy equation is the anchored law times the scale, term by term, also through its file."""
    model, runs = law(), lagging_runs(5.0)
    split = split_from_states(runs, ["a", "b", "c"], 2.0)
    score = FamilyScore("lateral_slip", np.zeros(0), np.array([-3.0, 0.0]), 0.5, {}, 0.5,
                        {"model_has_lateral_law": True})
    out = with_settled_drift(score, model, split)
    est = out.estimate
    assert est["settling_scale"] == pytest.approx(1.0 / 3.0, rel=0.13)
    assert est["settling_time_s"] == pytest.approx(0.2, rel=0.13)
    scale = est["settling_scale"]
    c = C + out.beta[0]  # the anchored coupling
    assert est["damping_1_s"] == pytest.approx(15.0 * scale) and est["coupling"] == pytest.approx(c * scale)
    ext = ExtendedModel.added(model, "lateral_slip", np.zeros(0), out.beta, est)
    assert ext.vy_rate == pytest.approx(scale)
    # by hand: vy' = scale (K vy + (C + beta0) vx omega); the forward and yaw equations as the model's
    x6 = np.array([[0.0, 0.0, 0.0, 0.6, 0.03, 0.4], [0.0, 0.0, 0.0, -0.2, -0.01, 0.9]])
    u = np.array([[0.5, 0.2], [-0.1, 0.8]])
    want = np.column_stack([-2.0 * x6[:, 3] + 2.0 * u[:, 0],
                            scale * (K * x6[:, 4] + c * x6[:, 3] * x6[:, 5]),
                            -3.0 * x6[:, 5] + 3.0 * u[:, 1]])
    assert ext.accel(x6, u)[:, 1] == pytest.approx(want[:, 1], abs=1e-12)
    a, J_x, _ = ext.accel_and_jacobians(x6, u)
    assert J_x[:, 1, 4] == pytest.approx(scale * K) and J_x[:, 1, 3] == pytest.approx(scale * c * x6[:, 5])


def test_the_settling_scale_survives_the_extensions_file(tmp_path):
    model = law()
    ext = ExtendedModel.added(model, "lateral_slip", np.zeros(0), np.array([-2.0, 0.0]),
                              {"slip_from": "settled", "extension_slip_gain": 1.0, "settling_scale": 0.4})
    back = ExtendedModel.load(ext.to_json(tmp_path / "ext.json"))
    x6, u = np.array([[0.0, 0.0, 0.0, 0.6, 0.03, 0.4]]), np.array([[0.5, 0.2]])
    assert back.vy_rate == pytest.approx(0.4) and back.accel(x6, u) == pytest.approx(ext.accel(x6, u), abs=1e-15)
    assert back.accel(x6, u)[0, 1] == pytest.approx(0.4 * (K * 0.03 + (C - 2.0) * 0.6 * 0.4))
    # a plain SINDy model again: the lateral row of coefficients times the scale
    assert ext.as_sindy().f(x6[:, 3:], u) == pytest.approx(ext.accel(x6, u), abs=1e-12)


def test_the_lateral_law_is_the_one_whose_lateral_velocity_matches_the_train_runs_best():
    """Runs whose vy follows a saturating drift, ``-0.2 q + 0.6 q^3`` (``q = vx omega``), through a lag of 10 1/s
    (integrated by scipy): of the family's laws the saturating one is kept, the one of the three whose lateral
    velocity, anchored and integrated along the train runs, misses the measured one least; the linear law
    cannot bend with the turns and misses more."""
    from scipy.integrate import solve_ivp

    from sindy_ekf.diagnose import scoring

    def run(r: int, run_s: float = 40.0) -> BodyStates:
        def vx(t):
            return 0.5 + 0.3 * np.sin(0.4 * t + r)

        def om(t):
            return 0.9 * np.sin(0.9 * t + 2.0 * r)

        t = np.arange(0.0, run_s, 0.04)
        drift = lambda s: -0.2 * vx(s) * om(s) + 0.6 * (vx(s) * om(s)) ** 3  # noqa: E731
        sol = solve_ivp(lambda s, y: -10.0 * (y - drift(s)), (0.0, t[-1]), [0.0], t_eval=t, rtol=1e-10, atol=1e-12)
        z = np.zeros_like(t)
        return BodyStates(t=t, vx=vx(t), vy=sol.y[0], omega=om(t), u1=vx(t), u2=om(t), x=z, y=z, yaw=z)

    model = law()
    tr = split_from_states([run(r) for r in range(3)], ["a", "b", "c"], 2.0)
    te = split_from_states([run(3)], ["d"], 2.0)
    weights = np.ones(3)
    base = {"train": scoring.null_prediction(model, tr), "test": scoring.null_prediction(model, te)}
    kept = scoring.lateral_law(model, tr, te, weights, base, uncertainty=False)
    assert kept.estimate["mechanism"] == "saturating"
    linear = with_settled_drift(scoring.score_family(scoring.MECHANISMS["lateral_slip"][0], model, tr, te, weights,
                                                     base, uncertainty=False), model, tr)
    assert kept.estimate["vy_rms_m_s"] < 0.8 * linear.estimate["vy_rms_m_s"]
