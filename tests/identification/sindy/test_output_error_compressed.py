"""The compressed least-squares problem of output_error.compressed against the problem it stands
for: the identities that make a trust-region method take the same steps, checked on tall random
Jacobians (well-conditioned, nearly collinear, with a zero column), and one output-error fit
against scipy's least squares on the full residuals; and an overflow inside scipy's step stays there."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from identification.sindy.model import SindyModel, model_from_terms
from identification.sindy.output_error import (
    HEADING_WEIGHT_M,
    SindyStructure,
    compressed,
    fit_output_error,
    pose_residuals,
    rollout_with_sensitivities,
)
from identification.sindy.reference import reference
from tests.support.runaway import spoilt_rollout
from tests.support.sindy_synth import SPARSE_TERMS, simulate_trajectory_runs, sparse_f


def _jacobians():
    rng = np.random.default_rng(3)
    m, n = 2000, 12
    well = rng.normal(size=(m, n)) * np.logspace(-3, 3, n)  # columns of very different scales
    collinear = well.copy()
    collinear[:, 5] = collinear[:, 4] * 2.0 + 1e-9 * rng.normal(size=m)  # Cholesky cannot resolve it
    near = well.copy()
    near[:, 5] = near[:, 4] * 2.0 + 1e-7 * np.abs(near[:, 4]).max() * rng.normal(size=m)  # it can, imprecisely
    zero = well.copy()
    zero[:, 7] = 0.0  # a parameter without sensitivity (a diverged window's zeroed rows, a dead feature)
    return ({"well-conditioned": well, "nearly collinear": collinear, "collinear to 1e-7": near, "zero column": zero},
            rng.normal(size=m))


@pytest.mark.parametrize("case", ["well-conditioned", "nearly collinear", "collinear to 1e-7", "zero column"])
def test_the_compressed_problem_has_the_same_cost_gradient_and_gauss_newton_matrix(case):
    Js, r = _jacobians()
    J = Js[case]
    r_c, J_c = compressed(r, J)
    n = J.shape[1]
    assert r_c.shape == (n + 1,) and J_c.shape == (n + 1, n)
    assert np.dot(r_c, r_c) == pytest.approx(np.dot(r, r), rel=1e-10)
    np.testing.assert_allclose(J_c.T @ r_c, J.T @ r, rtol=0, atol=1e-8 * np.abs(J.T @ r).max())
    # the Gram matrix column by column, relative to each column pair's scale
    G, G_c = J.T @ J, J_c.T @ J_c
    d = np.sqrt(np.outer(np.diag(G), np.diag(G))) + 1e-300
    np.testing.assert_allclose(G_c / d, G / d, rtol=0, atol=1e-9)
    assert np.all(J_c[n] == 0.0)  # the orthogonal remainder has no slope where it is taken
    # the residual Gauss-Newton cannot remove and its step in unit-column coordinates (as trf's
    # x_scale="jac"), where squaring the condition number (a Gram matrix's Cholesky factor) would show
    rest = np.linalg.norm(r - J @ np.linalg.lstsq(J, r, rcond=None)[0])
    assert r_c[n] == pytest.approx(rest, rel=1e-6)
    D = np.where(np.linalg.norm(J, axis=0) > 0, np.linalg.norm(J, axis=0), 1.0)
    step, step_c = (np.linalg.lstsq(a / D, b, rcond=None)[0] for a, b in ((J, r), (J_c, r_c)))
    assert np.linalg.norm(step_c - step) <= 1e-5 * np.linalg.norm(step)


@pytest.fixture(scope="module")
def problem():
    ref = reference(simulate_trajectory_runs(40.0, [31], f=sparse_f))
    windows = ref.windows(3.0, 0.0, 0.05)
    m = model_from_terms(SPARSE_TERMS, "poly3")
    return windows, SindyModel(m.library, m.coef)  # the data's own dynamics: no dead time


def test_a_fit_on_the_compressed_problem_ends_where_least_squares_on_all_residuals_ends(problem):
    """From 25 % off, coefficients and dead times: the package's fit and scipy's on the
    uncompressed residuals (same method, scaling, tolerances) end at the same parameters."""
    windows, model = problem
    spec = SindyStructure(model.with_coefficients(model.coef * 1.25))
    p = len(spec.theta0)
    x0 = np.concatenate([spec.theta0, [0.05, 0.05]])

    def full(x):
        dyn = spec.build(x[:p], tuple(x[p:]))
        pred, sens = rollout_with_sensitivities(dyn, spec, windows, True, False)
        J = sens[:, 1:, :3, :].copy()
        J[..., 2, :] *= HEADING_WEIGHT_M
        return pose_residuals(pred, windows).reshape(-1), J.reshape(-1, J.shape[-1])

    ref_sol = least_squares(lambda x: full(x)[0], x0, jac=lambda x: full(x)[1],
                            bounds=(np.r_[np.full(p, -np.inf), 0, 0], np.r_[np.full(p, np.inf), 1, 1]),
                            method="trf", x_scale="jac", max_nfev=40, xtol=1e-8, ftol=1e-6)
    fit = fit_output_error(spec, spec.theta0, windows, (0.05, 0.05), True)
    np.testing.assert_allclose(fit.theta, ref_sol.x[:p], rtol=1e-6)
    np.testing.assert_allclose(fit.dead_time_s, ref_sol.x[p:], rtol=0, atol=1e-7)
    # and both found the data's own model
    np.testing.assert_allclose(fit.theta, SindyStructure(model).theta0, rtol=0.02)
    np.testing.assert_allclose(fit.dead_time_s, (0.0, 0.0), rtol=0, atol=5e-3)


def test_a_window_that_runs_away_to_huge_finite_numbers_counts_as_diverged(problem, monkeypatch):
    """A candidate whose prediction in one window reaches 1e200 (finite, but its square overflows
    the Gram matrix) is fitted exactly as if that window had left the finite numbers: the window
    costs DIVERGED_RESIDUAL_M with no slope, no overflow warning, the same parameters."""
    import warnings

    from identification.sindy import output_error

    windows, model = problem
    spec = SindyStructure(model.with_coefficients(model.coef * 1.1))
    real = output_error.rollout_with_sensitivities
    fits = {}
    for runaway in (np.nan, 1e200):

        monkeypatch.setattr(output_error, "rollout_with_sensitivities", spoilt_rollout(real, 3, runaway))
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an overflow in the fit would raise here
            fits[runaway] = fit_output_error(spec, spec.theta0, windows, (0.0, 0.0), False, max_nfev=8)
    nan_fit, huge_fit = fits[np.nan], fits[1e200]
    np.testing.assert_array_equal(huge_fit.theta, nan_fit.theta)
    assert huge_fit.rms_pos_m == nan_fit.rms_pos_m
    # and the fit moved toward the data's own model from 10 % off despite the runaway window
    err0 = np.abs(spec.theta0 - SindyStructure(model).theta0).max()
    assert np.abs(huge_fit.theta - SindyStructure(model).theta0).max() < 0.5 * err0


def test_an_overflow_inside_scipys_trust_region_step_prints_nothing(problem, monkeypatch):
    """scipy's bounded trust-region step overflows for a parameter the windows barely move (a huge
    ``x_scale="jac"`` scale; seen on a real campaign with a 30 s pose hole per run), which printed a
    RuntimeWarning from scipy's internals on the user's terminal. The same overflow, made inside the
    optimiser here, must stay there, and the fit end where it ends without it."""
    import warnings

    import identification.sindy.output_error as oe

    windows, model = problem
    spec = SindyStructure(model.with_coefficients(model.coef * 1.25))
    plain = fit_output_error(spec, spec.theta0, windows, (0.05, 0.05), True)
    real = oe.least_squares

    def overflowing(*args, **kwargs):
        big = np.float64(1e200)
        assert np.isinf(big * big)  # scipy's b * b in intersect_trust_region, as on that campaign
        return real(*args, **kwargs)

    monkeypatch.setattr(oe, "least_squares", overflowing)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fit = fit_output_error(spec, spec.theta0, windows, (0.05, 0.05), True)
    np.testing.assert_array_equal(fit.theta, plain.theta)
