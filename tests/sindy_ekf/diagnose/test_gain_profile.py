"""The input gain's profile over time since the run start (``sindy_ekf.diagnose.gain_profile``).

References independent of the code under test: the monotone fit against a constrained least-squares
solver and a case worked by hand; the bins counted by hand; and data from ``tests.support.sindy_synth``
(its own RK4 of a first-order lag system) whose recorded inputs are rewritten here, by hand, as a robot
whose motors lose gain with a known shape would have recorded them (motors see ``g(t) u``, the log
holds ``u``), so the profile must find ``g``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from sindy_ekf.diagnose.design import equation_weights, gain_recalibrated
from sindy_ekf.diagnose.gain_profile import gain_profile, isotonic, monotone, time_bins
from tests.sindy_ekf.diagnose.test_input_gains_reference import lag_model, recorded_as, splits
from tests.support.sindy_synth import lag_f, simulate_trajectory_runs

RUN_S = 120.0


def test_isotonic_by_hand():
    # 3, 1 violate: pooled to 2, 2; then 2 follows without violation
    np.testing.assert_allclose(isotonic([3.0, 1.0, 2.0], [1.0, 1.0, 1.0], True), [2.0, 2.0, 2.0])
    # weights 3 and 1: the pool's mean is (3 * 3 + 1 * 1) / 4 = 2.5
    np.testing.assert_allclose(isotonic([3.0, 1.0, 4.0], [3.0, 1.0, 1.0], True), [2.5, 2.5, 4.0])
    np.testing.assert_allclose(isotonic([1.0, 3.0, 2.0], [1.0, 1.0, 1.0], False), [2.0, 2.0, 2.0])


@pytest.mark.parametrize("seed", range(5))
def test_isotonic_against_a_constrained_solver(seed):
    rng = np.random.default_rng(seed)
    y, w = rng.normal(size=7), rng.uniform(0.5, 2.0, size=7)
    for inc in (True, False):
        sign = 1.0 if inc else -1.0
        cons = [{"type": "ineq", "fun": lambda x, i=i: sign * (x[i + 1] - x[i])} for i in range(6)]
        ref = minimize(lambda x: np.sum(w * (x - y) ** 2), np.full(7, y.mean()), constraints=cons,
                       method="SLSQP", options={"ftol": 1e-12, "maxiter": 500}).x
        np.testing.assert_allclose(isotonic(y, w, inc), ref, atol=1e-5)
    # the better direction: a falling sequence is fitted falling
    np.testing.assert_allclose(monotone(np.array([3.0, 2.0, 1.0]), np.ones(3)), [3.0, 2.0, 1.0])


def test_time_bins_by_hand():
    # windows at 0..59 s, one per second: 6 equal bins of 10 s, 10 windows each; at least 12 a bin
    # pools bins in pairs (20, 20, 20)
    t = np.arange(60.0)
    b = time_bins(t, n_bins=6, min_windows=12)
    np.testing.assert_array_equal(np.bincount(b), [20, 20, 20])
    assert np.all(np.diff(b) >= 0)
    # 5 windows in the last bin alone: they join the bin before
    t2 = np.concatenate([np.repeat(np.arange(5.0) * 10 + 1, 12), [55.0, 56, 57, 58, 59.0]])
    np.testing.assert_array_equal(np.bincount(time_bins(t2, n_bins=6, min_windows=12)), [12, 12, 12, 12, 17])


@pytest.fixture(scope="module")
def runs():
    return simulate_trajectory_runs(RUN_S, [11, 12, 13, 14, 15], f=lag_f(), pose_std_m=0.002, yaw_std_rad=0.002)


def profile_of(runs, g):
    """Return the gain profile of the true lag model on runs whose motors saw ``g(t) x`` the logged inputs."""
    logged = recorded_as(runs, lambda t, u: u / g(t)[:, None])
    model = lag_model()
    tr, _ = splits(model, logged)
    w = equation_weights(model, tr)
    null, _ = gain_recalibrated(model, tr, w)
    return gain_profile(null, tr, w)


def early(t):
    return 1.0 - 0.2 * (1.0 - np.exp(-t / 20.0))


def late(t):
    return np.where(t < 60.0, 1.0, 1.0 - 0.15 * (t - 60.0) / 60.0)


@pytest.mark.parametrize("g", [early, late], ids=["early", "late"])
def test_profile_finds_the_shape_of_the_decay(runs, g):
    p = profile_of(runs, g)
    t = np.array(p["gain_profile_t_s"])
    truth = g(t) / g(t[0])
    est = np.array(p["gain_profile_monotone"]) / p["gain_profile_monotone"][0]
    # the monotone profile follows the truth at every bin centre within 1 % of gain
    np.testing.assert_allclose(est, truth, atol=0.01)
    true_loss = 1.0 - g(np.array([p["loss_to_s"]]))[0] / g(np.array([p["loss_from_s"]]))[0]
    assert p["loss_over_runs"] == pytest.approx(true_loss, rel=0.15)
    assert np.all(np.diff(est) <= 1e-12)  # falling, as the truth


def test_shapes_are_told_apart(runs):
    # the early decay loses most of its gain in the first half of the runs, the late one in the second
    for g, first_half_share in ((early, lambda s: s > 0.7), (late, lambda s: s < 0.3)):
        p = profile_of(runs, g)
        t, m = np.array(p["gain_profile_t_s"]), np.log(p["gain_profile_monotone"])
        mid = np.interp(RUN_S / 2, t, m)
        assert first_half_share((m[0] - mid) / (m[0] - m[-1]))


def test_no_decay_gives_no_loss(runs):
    p = profile_of(runs, lambda t: np.ones_like(t))
    assert abs(p["loss_over_runs"]) < 0.01


def test_jackknife_is_the_profile_refitted_without_each_run(runs):
    # the standard deviation from the per-run residual sums equals refitting on the windows of the
    # other runs, one run left out at a time (same bins: the left-out run's windows only removed)
    logged = recorded_as(runs, lambda t, u: u / early(t)[:, None])
    model = lag_model()
    tr, _ = splits(model, logged)
    w = equation_weights(model, tr)
    null, _ = gain_recalibrated(model, tr, w)
    full = gain_profile(null, tr, w)
    losses = []
    for r in range(len(tr.names)):
        sub = gain_profile(null, tr.select_windows(tr.window_run != r), w)
        assert len(sub["gain_profile_t_s"]) == len(full["gain_profile_t_s"])  # the same bins
        losses.append(sub["loss_over_runs"])
    n, losses = len(losses), np.array(losses)
    assert full["loss_over_runs_std"] == pytest.approx(np.sqrt((n - 1) / n * np.sum((losses - losses.mean()) ** 2)),
                                                       rel=1e-6)


def test_a_model_without_input_terms_has_no_profile(runs):
    model = lag_model((0.0, 0.0))  # the input coefficients zero: no gain to fit
    tr, _ = splits(model, runs)
    assert gain_profile(model, tr, equation_weights(model, tr)) is None


def test_the_steering_alone_carries_the_gain(runs):
    # a model whose throttle term is zero: only the omega equation sees the inputs, and the profile
    # must still follow the decay there (a gain read from one input's terms alone would find none)
    logged = recorded_as(runs, lambda t, u: u / early(t)[:, None])
    model = lag_model((0.0, 1.0))
    tr, _ = splits(model, logged)
    w = equation_weights(model, tr)
    null, _ = gain_recalibrated(model, tr, w)
    p = gain_profile(null, tr, w)
    t = np.array(p["gain_profile_t_s"])
    est = np.array(p["gain_profile_monotone"]) / p["gain_profile_monotone"][0]
    np.testing.assert_allclose(est, early(t) / early(t[0]), atol=0.015)
    assert p["gain_profile_runs"] == [4] * len(t)  # every bin reached by all four train runs


def test_the_diagnosis_names_the_decay_and_shows_its_profile(runs):
    # end to end on the independent lag system (one more run as a second test run): the pipeline names
    # the decay, its profile's loss is the truth's between the same bins, and the report's diagnosis
    # section draws the profile and keeps its per-bin lists out of the table
    from types import SimpleNamespace

    from identification.sindy.data import states_of_runs
    from sindy_ekf.diagnose import diagnose_states
    from sindy_ekf.report.blocks import Section
    from sindy_ekf.report.sections import section_diagnosis

    more = simulate_trajectory_runs(RUN_S, [16], f=lag_f(), pose_std_m=0.002, yaw_std_rad=0.002)
    st, names, _ = states_of_runs(recorded_as(list(runs) + list(more), lambda t, u: u / early(t)[:, None]), 0.0)
    d = diagnose_states(lag_model(), st[:4], st[4:], names[:4], names[4:], uncertainty=False)
    assert d.verdict == "time_dependence"
    est = d.ranked[0].score.estimate
    truth = 1.0 - early(np.array([est["loss_to_s"]]))[0] / early(np.array([est["loss_from_s"]]))[0]
    assert est["loss_over_runs"] == pytest.approx(truth, rel=0.05)
    sec = Section("diagnosis", "Diagnosis")
    section_diagnosis.__wrapped__(sec, SimpleNamespace(diagnosis=d))
    text = sec.to_html()
    assert "input gain over time since the run start" in text and "gain_profile_monotone" not in text
    assert "loss_over_runs" in text
