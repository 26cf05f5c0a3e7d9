"""Measurement-noise adaptation (covariance matching on the innovations' scatter), against
independent references: a simulated order statistic, a hand-computed variance factor, and the
filter on simulated GNSS whose stated covariance is ten times too small."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from simulation.gnss import PROFILES, simulate_gnss
from sindy_ekf.estimation import adaptive
from sindy_ekf.estimation.adaptive import N_PAIRS, NoiseScaler, median_threshold, scatter_statistic
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, inputs_at, simulate_truth, simulate_truths, truth_on

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def test_median_threshold_is_the_quantile_of_a_simulated_sample_median():
    # independent reference: the 0.99 quantile of the median of 15 chi2(2) draws, by simulation
    rng = np.random.default_rng(0)
    med = np.median(rng.chisquare(2, size=(200_000, N_PAIRS)), axis=1) / (2 * math.log(2))
    assert median_threshold(N_PAIRS, 0.01) == pytest.approx(np.quantile(med, 0.99), rel=0.02)


def test_scatter_statistic_by_hand():
    # one difference d = (1, 0), S_state = 0, R = I: d^T (lambda I)^-1 d = 1 / lambda; over 2 ln 2
    d = np.array([[1.0, 0.0]])
    stat = scatter_statistic(d, np.zeros((1, 2, 2)), np.eye(2)[None], np.array([1.0, 4.0]))
    np.testing.assert_allclose(stat, [1 / (2 * math.log(2)), 0.25 / (2 * math.log(2))])


def _feed(scaler: NoiseScaler, y: np.ndarray, R: np.ndarray) -> list[float]:
    out = []
    for yi in y:
        out.append(scaler.scale())
        scaler.add(yi, np.zeros((2, 2)), R)
    return out


def test_correctly_stated_noise_is_left_alone_and_ten_times_too_small_is_found():
    rng = np.random.default_rng(1)
    R = 0.09 * np.eye(2)
    good = _feed(NoiseScaler(), rng.normal(0, 0.3, (2000, 2)), R)
    assert np.mean(np.array(good) == 1.0) > 0.99
    # the same receiver stating a covariance ten times too small: lambda near 10 (the sample
    # median of 15 pairs scatters: within a factor 2)
    bad = np.array(_feed(NoiseScaler(), rng.normal(0, 0.3, (2000, 2)), R / 10))[2 * N_PAIRS:]
    assert 6.0 < np.median(bad) < 16.0
    assert np.mean(bad > 3.0) > 0.95


def test_a_step_or_a_drift_of_the_innovations_is_not_noise():
    # the fixes jump by 3 m (20 sigma) or drift by 1 m/s: the scatter is unchanged, so R is too
    rng = np.random.default_rng(2)
    R = 0.09 * np.eye(2)
    y = rng.normal(0, 0.3, (400, 2))
    y[200:] += [3.0, -1.0]
    assert np.mean(np.array(_feed(NoiseScaler(), y, R)) == 1.0) > 0.99
    drift = rng.normal(0, 0.3, (400, 2)) + np.outer(np.arange(400) / 5.0, [1.0, 0.5])
    assert np.mean(np.array(_feed(NoiseScaler(), drift, R)) == 1.0) > 0.99


@pytest.fixture(scope="module")
def small_cov():
    """A 60 s run of a known model under DGNSS whose stated covariance is ten times too small."""
    model = fit_process_noise(ProcessModel(PolyBody(), name="oracle"),
                              simulate_truths(ProcessModel(PolyBody(), name="oracle"), 30.0,
                                              np.random.default_rng(100), n_runs=4))
    truth = simulate_truth(model, 60.0, np.random.default_rng(7))
    prof = replace(PROFILES["dgnss"], outlier_prob=0.0)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], prof, seed=3,
                         outages=np.empty((0, 2)))
    t = estimation_grid(truth.t, gnss.t_valid)
    run = EkfRun("small_cov", t, inputs_at(truth, t), truth.x6[0], P0, gnss)
    bad = replace(run, gnss=replace(gnss, std=gnss.std * math.sqrt(0.1)))
    return model, truth, run, bad


def test_the_filter_inflates_a_stated_covariance_ten_times_too_small(small_cov, monkeypatch):
    model, truth, run, bad = small_cov
    good_res, bad_res = run_ekf_batch(model, [run, bad])
    # correctly stated: untouched but for the scaler's false-alarm rate
    assert np.mean(good_res.r_scale == 1.0) > 0.97
    late = bad_res.nis_t > bad_res.nis_t[0] + 10.0
    assert 5.0 < np.median(bad_res.r_scale[late]) < 20.0
    # the NIS is back to chi2(2)'s scale (mean 2; 10 with the stated covariance)
    assert np.median(bad_res.nis[late]) < 2.0

    def pose_err(res):
        ref = truth_on(truth, res.t)
        return np.sqrt(np.mean((res.x[:, 0] - ref[:, 0]) ** 2 + (res.x[:, 1] - ref[:, 1]) ** 2))

    # mutation: without the adaptation the same fixes leave the filter over-confident
    monkeypatch.setattr(adaptive.NoiseScaler, "scale", lambda self: 1.0)
    plain = run_ekf_batch(model, [bad])[0]
    assert np.median(plain.nis[late]) > 5.0
    assert np.all(plain.r_scale == 1.0)
    assert pose_err(bad_res) < pose_err(plain) * 1.2
