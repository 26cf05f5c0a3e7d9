"""Monte-Carlo scoring against hand computations: a known estimate error gives its NEES, its
band verdict and its outage-end error; the NEES band is the chi-square law of a mean."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from groundfloor.gnss import GnssSeries
from simulation.gnss_faults import GnssFaults
from sindy_ekf.benchmark.health import RunStatus
from sindy_ekf.benchmark.monte_carlo import NEES_STRIDE_S, McWindow, mix_of, nees_band_95, outcome


def test_nees_band_of_one_sample_is_the_per_sample_band_and_narrows_about_the_dof():
    lo, hi = nees_band_95(1)
    np.testing.assert_allclose([lo, hi], chi2.ppf([0.025, 0.975], 3))
    lo, hi = nees_band_95(30)
    assert lo < 3.0 < hi and hi - lo < 0.3 * (chi2.ppf(0.975, 3) - chi2.ppf(0.025, 3))
    # a Monte-Carlo check of the same law: means of 30 chi2(3) draws fall inside 95 % of the time
    means = np.random.default_rng(0).chisquare(3, (20000, 30)).mean(axis=1)
    assert abs(np.mean((means >= lo) & (means <= hi)) - 0.95) < 0.01


def _window(offset_xy, outage=(40.0, 70.0)):
    t = np.arange(0.0, 100.0 + 1e-9, 0.02)
    truth = np.column_stack([t, 0.5 * t, np.zeros_like(t), np.zeros_like(t)])
    x = np.zeros((t.size, 6))
    x[:, :3] = truth[:, 1:]
    x[:, :2] += offset_xy
    faults = GnssFaults(outages=np.array([outage]))
    gnss = GnssSeries("t", t[:1], t[:1], np.zeros((1, 3)), np.ones((1, 3)), np.zeros(1, np.uint8), np.zeros(3),
                      faults.outages)
    w = McWindow(3, "outage", "run", truth, t, np.arange(t.size), np.zeros((t.size, 2)), x[0], gnss, faults)
    return w, x


@pytest.mark.parametrize("sigma, inside", [(1.0, False), (np.sqrt(0.25 / 3), True)])
def test_a_constant_error_gives_its_nees_verdict_and_outage_end_error(sigma, inside):
    w, x = _window([0.3, 0.4])  # 0.5 m off
    P = np.broadcast_to(np.diag([sigma ** 2, sigma ** 2, 1.0, 1, 1, 1]), (len(x), 6, 6))
    o = outcome(w, "sindy_ekf", x, P, RunStatus())
    nees = 0.25 / sigma ** 2  # 0.0625 for sigma 1: below the band of 20 samples [2.02, 4.12]; 3 inside
    assert o.nees_mean == pytest.approx(nees)
    lo, hi = nees_band_95(int(np.ceil(100.0 / NEES_STRIDE_S)))
    assert o.nees_in_band is inside and bool(lo <= nees <= hi) is inside
    assert o.outage_s == 30.0 and o.outage_end_err_m == pytest.approx(0.5)
    assert o.ate_pos_m == pytest.approx(0.5) and o.final_err_m == pytest.approx(0.5)


def test_a_diverged_run_is_never_inside_its_band_and_misses_a_later_outage_end():
    w, x = _window([0.0, 0.0])
    cut = 2000  # 40 s of the grid
    P = np.broadcast_to(np.diag([0.01, 0.01, 1.0, 1, 1, 1]), (cut, 6, 6)).copy()
    x = x[:cut].copy()
    x[:, 0] += 0.1 * np.random.default_rng(1).standard_normal(cut)  # consistent errors
    o = outcome(w, "sindy_ekf", x, P, RunStatus("diverged", 40.0, "test"))
    assert o.status == "diverged" and not o.nees_in_band
    assert np.isnan(o.outage_end_err_m)  # the outage ends at 70 s, after the estimate stops


def test_mixes_take_equal_turns():
    names = [mix_of(i) for i in range(70)]
    assert len(set(names)) == 7 and all(names.count(n) == 10 for n in set(names))
