"""Integral SINDy (eqs. 5.53 to 5.59) and the LSQ adjustment (eq. 5.79): recovery of a known
sparse model on several seeds, the integral matrix against analytic integrals, the compressed
STLSQ against pysindy on the full matrix, and every kind of bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.adjust import (
    adjust_coefficients,
    subsample_low_acceleration,
    subsampling_effect,
)
from identification.sindy.library import make_library, parse_term
from identification.sindy.model import model_from_terms
from identification.sindy.regression import (
    IllConditionedWarning,
    fit_sindy,
    fit_stlsq,
    integral_problem,
)
from tests.support.sindy_synth import SPARSE_TERMS, simulate_states


@pytest.fixture(scope="module")
def runs_by_seed():
    """Three independent data sets (3 runs x 50 s each), simulated together."""
    runs = simulate_states(50.0, range(20, 29))
    return [runs[3 * i: 3 * i + 3] for i in range(3)]


def test_recovers_known_sparse_terms_and_coefficients_on_several_seeds(runs_by_seed):
    truth = model_from_terms(SPARSE_TERMS)
    for runs in runs_by_seed:
        model = fit_sindy(runs, "poly3", tau=2.0, alpha=0.05, threshold=0.2)
        np.testing.assert_array_equal(model.coef != 0, truth.coef != 0)  # exactly the true terms
        active = truth.coef != 0
        rel = np.abs(model.coef[active] - truth.coef[active]) / np.abs(truth.coef[active])
        assert rel.max() < 0.10, rel


def test_compressed_problem_gives_pysindy_coefficients_of_the_full_matrix(runs_by_seed):
    problem = integral_problem(runs_by_seed[0], "poly3", tau=3.0)
    r, c = problem.compressed()
    assert r.shape[0] < problem.n_windows / 10
    for alpha, threshold in [(1.0, 0.25), (30.0, 1.0)]:
        full = fit_stlsq(problem.theta_int, problem.delta_x, threshold, alpha)
        np.testing.assert_allclose(fit_stlsq(r, c, threshold, alpha), full, atol=1e-9)


def test_integral_matrix_matches_analytic_integrals():
    t = np.arange(0, 20, 0.02)
    st = BodyStates(t=t, vx=np.sin(t), vy=0.1 * np.cos(t), omega=0.3 * t / 20, u1=np.cos(2 * t), u2=np.sin(t) ** 2,
                    x=t, y=t, yaw=t)
    problem = integral_problem([st], "poly2", tau=2.0)
    lib = problem.library
    t0 = problem.t_start
    j_vx = lib.atoms.index(parse_term("vx"))
    j_vx_u1 = lib.atoms.index(parse_term("vx u1"))
    # int sin = cos(t0) - cos(t1); int sin(t) cos(2t) = [cos t / 2 - cos 3t / 6]
    t1 = t0 + 2.0
    np.testing.assert_allclose(problem.theta_int[:, j_vx], np.cos(t0) - np.cos(t1), atol=2e-4)
    prim = lambda s: np.cos(s) / 2 - np.cos(3 * s) / 6  # noqa: E731
    np.testing.assert_allclose(problem.theta_int[:, j_vx_u1], prim(t1) - prim(t0), atol=5e-4)
    np.testing.assert_allclose(problem.delta_x[:, 0], np.sin(t1) - np.sin(t0), atol=1e-12)
    assert problem.n_windows == len(t) - 100  # every sample starts a window that fits in the run


def test_windows_never_cross_a_data_gap():
    t = np.concatenate([np.arange(0, 10, 0.02), np.arange(12, 22, 0.02)])
    z = np.sin(t)
    st = BodyStates(t=t, vx=z, vy=z, omega=z, u1=np.cos(t), u2=np.cos(3 * t), x=z, y=z, yaw=z)
    problem = integral_problem([st], "poly1", tau=1.0)
    crosses = (problem.t_start < 10) & (problem.t_start + 1.0 > 10)
    assert not crosses.any() and problem.n_windows == 2 * (500 - 50)


def _short(states: BodyStates, n: int) -> BodyStates:
    return BodyStates(**{f.name: getattr(states, f.name)[:n] for f in dataclasses.fields(states)})


def test_fewer_windows_than_features_is_an_error_naming_tau(runs_by_seed):
    short = _short(runs_by_seed[0][0], 140)  # 2.8 s: 40 windows of 2 s for 56 features
    with pytest.raises(InputError, match=r"tau=2 s: only 40 integration windows in runs r1 .*56 features"):
        integral_problem([short], "poly3", tau=2.0, names=["r1"])


def test_constant_input_is_unidentifiable(runs_by_seed):
    st = dataclasses.replace(runs_by_seed[0][0], u2=np.full(len(runs_by_seed[0][0].t), 0.3))
    with pytest.raises(InputError, match="input u2: constant"):
        integral_problem([st], "poly3", tau=2.0, names=["r1"])


def test_times_not_increasing_name_the_run(runs_by_seed):
    st = runs_by_seed[0][1]
    t = st.t.copy()
    t[10] = t[9]
    with pytest.raises(InputError, match="run run_b: times are not strictly increasing"):
        integral_problem([runs_by_seed[0][0], dataclasses.replace(st, t=t)], "poly3", tau=2.0, names=["run_a", "run_b"])


def test_missing_values_name_run_and_column(runs_by_seed):
    u1 = runs_by_seed[0][1].u1.copy()
    u1[5:9] = np.nan
    st = dataclasses.replace(runs_by_seed[0][1], u1=u1)
    with pytest.raises(InputError, match="run run_b: column u1 has 4 missing"):
        integral_problem([runs_by_seed[0][0], st], "poly3", tau=2.0, names=["run_a", "run_b"])


def test_ill_conditioned_regression_reports_its_condition_number(runs_by_seed):
    st = runs_by_seed[0][0]
    collinear = dataclasses.replace(st, vy=0.5 * st.u1)  # vy and u1 columns identical up to scale
    with pytest.warns(IllConditionedWarning, match=r"condition number \d"):
        model = fit_sindy([collinear], "poly1", tau=2.0, alpha=0.0, threshold=0.0, names=["r1"])
    assert model.training["condition_number"] > 1e8


def test_adjustment_reproduces_the_generating_coefficients_and_thesis_correlations(runs_by_seed):
    runs = runs_by_seed[1]
    truth = model_from_terms(SPARSE_TERMS)
    problem = integral_problem(runs, "poly3", tau=2.0)
    adj = adjust_coefficients(truth, problem)
    expected = np.concatenate([[SPARSE_TERMS[eq][t] for t in SPARSE_TERMS[eq]] for eq in ("vx", "vy", "omega")])
    order = [(eq, n) for eq in ("vx", "vy", "omega") for n in make_library("poly3").feature_names
             if n in SPARSE_TERMS[eq]]
    assert list(adj.terms) == order
    got = dict(zip(adj.terms, adj.coef))
    exp = {(eq, n): c for eq in SPARSE_TERMS for n, c in SPARSE_TERMS[eq].items()}
    assert all(abs(got[k] - exp[k]) < 0.05 * abs(exp[k]) for k in exp), (got, expected)
    # no correlation across equations (functional model 5.79 is block-diagonal)
    eq_of = np.array([t[0] for t in adj.terms])
    assert np.all(adj.corr[eq_of[:, None] != eq_of[None, :]] == 0)
    # thesis table 7.7: friction and input terms of one equation strongly anti-correlated
    rho = {frozenset((a, b)): r for r, a, b in adj.strongest_correlations(15)}
    assert rho[frozenset(("vx: vx", "vx: u1"))] < -0.7
    assert rho[frozenset(("omega: omega", "omega: u2"))] < -0.7
    # empirical check of the covariance: coefficient std shrinks like 1/sqrt(n) when data halve
    half = adjust_coefficients(truth, problem, rows=np.arange(problem.n_windows) % 2 == 0)
    np.testing.assert_allclose(half.coef_std / adj.coef_std, np.sqrt(2), rtol=0.2)


def test_low_acceleration_subsampling_keeps_high_acceleration_windows(runs_by_seed):
    problem = integral_problem(runs_by_seed[2], "poly3", tau=2.0)
    mask = subsample_low_acceleration(problem, keep_fraction=0.1, quantile=0.5, seed=1)
    assert 0.5 < mask.mean() < 0.6
    effect = subsampling_effect(model_from_terms(SPARSE_TERMS), problem, keep_fraction=0.1, seed=1)
    assert effect["after"]["n_windows"] == mask.sum()
    assert 0 < effect["after"]["max_abs_corr"] <= 1 and 0 < effect["before"]["max_abs_corr"] <= 1


def test_defaults_are_poly3_tau_3_s_alpha_10_threshold_0_25_unnormalised(runs_by_seed):
    runs = runs_by_seed[0]
    default = fit_sindy(runs)
    explicit = fit_sindy(runs, "poly3", tau=3.0, alpha=10.0, threshold=0.25, normalize=False)
    np.testing.assert_array_equal(default.coef, explicit.coef)
    assert default.training["n_windows"] == integral_problem(runs, "poly3", 3.0).n_windows
    # the defaults decide the fit: other values of each give other coefficients
    for kw in ({"tau": 2.0}, {"alpha": 20.0}, {"threshold": 0.5}, {"normalize": True}):
        other = fit_sindy(runs, **{"tau": 3.0, "alpha": 10.0, "threshold": 0.25, **kw})
        assert not np.array_equal(other.coef, default.coef), kw
