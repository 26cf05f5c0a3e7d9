"""Normalised STLSQ on a column whose norm is below one: the threshold still compares the term's
share ``|xi_j| ||theta_j|| / ||target||`` (computed here by hand), however small the column."""

from __future__ import annotations

import numpy as np

from identification.sindy.regression import fit_stlsq


def test_a_small_share_on_a_small_column_is_dropped_and_a_large_one_kept():
    rng = np.random.default_rng(8)
    theta = rng.normal(size=(400, 3)) * np.array([1e-3, 1.0, 1.0])  # column 0: norm about 0.02
    coef = np.array([[4.0, 1.0, -0.5],      # column 0's share about 0.4 %: under a 10 % threshold
                     [400.0, 0.0, 1.0]])    # column 0's share about 36 %: kept
    target = theta @ coef.T
    share = np.abs(coef) * np.linalg.norm(theta, axis=0) / np.linalg.norm(target, axis=0)[:, None]
    assert np.linalg.norm(theta[:, 0]) < 0.1
    assert share[0, 0] < 0.1 < share[0, 2] and share[1, 0] > 0.2  # hand-computed
    got = fit_stlsq(theta, target, threshold=0.1, alpha=0.0, normalize=True)
    assert got[0, 0] == 0.0
    np.testing.assert_allclose(got[1, 0], 400.0, rtol=1e-6)
    np.testing.assert_allclose(got[0, 1:], [1.0, -0.5], rtol=0.05)


def test_by_default_the_threshold_is_on_the_raw_coefficients():
    # unnormalised (the default): a coefficient of 0.1 on a column of norm about 200 is under a
    # threshold of 0.25 and dropped although it carries most of the signal; the rest is then the
    # plain least-squares fit on the kept columns (alpha 0)
    rng = np.random.default_rng(9)
    theta = rng.normal(size=(300, 3)) * np.array([10.0, 1.0, 1.0])
    target = theta @ np.array([[0.1, 1.0, 0.5]]).T + 0.01 * rng.normal(size=(300, 1))
    got = fit_stlsq(theta, target, threshold=0.25, alpha=0.0)
    keep = np.linalg.lstsq(theta[:, 1:], target[:, 0], rcond=None)[0]
    assert got[0, 0] == 0.0
    np.testing.assert_allclose(got[0, 1:], keep, rtol=1e-9)
    # normalised, the same term's share is above the threshold and it stays
    assert fit_stlsq(theta, target, threshold=0.25, alpha=0.0, normalize=True)[0, 0] != 0.0
