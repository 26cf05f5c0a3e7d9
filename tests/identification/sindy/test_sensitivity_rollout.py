"""The compiled output-error rollout (identification.sindy.sensitivity_rollout) against the numpy
recursion of output_error and against finite differences of evaluate.rollout: the fast path of
``identify``'s refinement computes what the straightforward one does."""

from __future__ import annotations

import numpy as np
import pytest

from identification.sindy.evaluate import rollout
from identification.sindy.model import SindyModel, envelope_from_data, model_from_terms
from identification.sindy.output_error import SindyStructure, fit_output_error, rollout_with_sensitivities
from identification.sindy.reference import reference
from tests.support.sindy_synth import SPARSE_TERMS, simulate_trajectory_runs, sparse_f

# a term of each atom kind (x, x^2, x^3, |x|, x|x|) and the constant: the library with |u| atoms
ABS_TERMS = {"vx": {"1": 0.05, "vx": -5.0, "u1": 4.5, "vx omega^2": -2.0, "|u1|": -0.3},
             "vy": {"vy": -4.0, "vx omega": 1.5},
             "omega": {"omega": -6.0, "u2": 7.0, "omega^3": -1.5, "u2|u2|": -0.4}}


@pytest.fixture(scope="module")
def windows_and_envelope():
    """The 3 s output-error windows of one 40 s run of the sparse model, and a narrow envelope
    (half the data's) so that frozen extrapolation clamps the velocities on many steps."""
    ref = reference(simulate_trajectory_runs(40.0, [31], f=sparse_f))
    x = np.vstack([st.state for st in ref.states])
    u = np.vstack([st.inputs for st in ref.states])
    env = envelope_from_data(0.5 * x, u)
    return ref.windows(3.0, 0.0, 0.05), env


def _models(env):
    """Return the test's models: poly3 and poly3_absu, frozen with dead times and input lags."""
    out = []
    for terms, lib in ((SPARSE_TERMS, "poly3"), (ABS_TERMS, "poly3_absu")):
        m = model_from_terms(terms, lib)
        out.append(SindyModel(m.library, m.coef, envelope=env, extrapolation="frozen", dead_time_s=(0.1, 0.05),
                              input_lag_s=(0.12, 0.0)))
    return out


def test_the_compiled_rollout_equals_the_numpy_recursion(windows_and_envelope):
    windows, env = windows_and_envelope
    for model in _models(env):
        spec = SindyStructure(model)
        fast, fast_S = rollout_with_sensitivities(model, spec, windows, True, True, compiled=True)
        slow, slow_S = rollout_with_sensitivities(model, spec, windows, True, True, compiled=False)
        assert np.all(np.isfinite(fast_S))
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)
        np.testing.assert_allclose(fast_S, slow_S, rtol=0, atol=1e-10 * np.abs(slow_S).max())
        # and both are the evaluation's rollout, frozen extrapolation included
        np.testing.assert_allclose(fast, rollout(model, windows), rtol=0, atol=1e-12)


def test_the_clamped_case_is_exercised(windows_and_envelope):
    windows, env = windows_and_envelope
    lo, hi = _models(env)[0]._clamp_bounds()
    v = rollout(_models(env)[0], windows)[..., 3:]
    assert np.mean((v < lo) | (v > hi)) > 0.05  # the clamp acts on a good share of the steps


def test_compiled_sensitivities_equal_finite_differences_of_the_rollout(windows_and_envelope):
    windows, env = windows_and_envelope
    model = _models(env)[1]
    spec = SindyStructure(model)
    _, S = rollout_with_sensitivities(model, spec, windows, fit_dead_time=True, fit_input_lag=False)
    theta = spec.theta0
    h = 1e-6
    for q in range(len(theta)):
        up, down = theta.copy(), theta.copy()
        up[q] += h
        down[q] -= h
        fd = (rollout(spec.build(up, model.dead_time_s, model.input_lag_s), windows)
              - rollout(spec.build(down, model.dead_time_s, model.input_lag_s), windows)) / (2 * h)
        assert np.linalg.norm(fd - S[..., q]) <= 1e-5 * np.linalg.norm(fd), spec.names[q]


def test_a_fit_on_the_compiled_path_ends_where_the_numpy_path_ends(windows_and_envelope):
    """Both paths of one output-error fit from 25 % off: same parameters to 1e-6 relative (the
    two differ by round-off in the sensitivities, which least squares' steps carry on)."""
    windows, env = windows_and_envelope
    model = _models(env)[0]
    spec = SindyStructure(model.with_coefficients(model.coef * 1.25))
    fits = [fit_output_error(spec, spec.theta0, windows, model.dead_time_s, input_lag0=model.input_lag_s,
                             fit_input_lag=True, compiled=c) for c in (True, False)]
    fast, slow = fits
    assert fast.nfev == slow.nfev
    np.testing.assert_allclose(fast.theta, slow.theta, rtol=1e-6)
    np.testing.assert_allclose(fast.dead_time_s + fast.input_lag_s, slow.dead_time_s + slow.input_lag_s,
                               rtol=0, atol=1e-7)
    np.testing.assert_allclose(fast.cov, slow.cov, rtol=1e-5, atol=1e-12)
