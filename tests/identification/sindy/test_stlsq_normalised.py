"""STLSQ on normalised columns (``fit_stlsq(normalize=True)``): coefficients come back in the
original units, and the threshold compares each term's share of its equation's signal.

Independent references: the generating coefficients of an exact linear system whose columns
differ by six orders of magnitude, and the dimensionless share ``|xi_j| ||theta_j|| /
||target||`` computed here by hand.
"""

from __future__ import annotations

import numpy as np

from identification.sindy.regression import fit_stlsq


def _system(seed: int = 0):
    rng = np.random.default_rng(seed)
    scales = np.array([1e-3, 1.0, 1e3, 1.0])  # column sizes six orders of magnitude apart
    theta = rng.normal(size=(400, 4)) * scales
    coef = np.array([[250.0, -0.5, 0.0, 0.0],        # equation 1: terms 0 and 1
                     [0.0, 0.0, 2e-3, 0.8]])         # equation 2: terms 2 and 3
    return theta, coef, theta @ coef.T


def test_normalised_fit_returns_coefficients_in_the_original_units():
    theta, coef, target = _system()
    got = fit_stlsq(theta, target, threshold=0.0, alpha=0.0, normalize=True)
    np.testing.assert_allclose(got, coef, rtol=1e-9, atol=1e-12)


def test_threshold_compares_each_terms_share_of_its_equations_signal():
    theta, coef, target = _system(1)
    coef[0, 3] = 0.002  # a small term in equation 1: far below 5 % of the equation's signal
    target = theta @ coef.T
    share = np.abs(coef) * np.linalg.norm(theta, axis=0) / np.linalg.norm(target, axis=0)[:, None]
    assert share[0, 3] < 0.05 < share[0, 1]  # hand-computed: the small term is under the threshold
    assert share[0, 0] > 0.05 and share[1, 2] > 0.05 and share[1, 3] > 0.05
    got = fit_stlsq(theta, target, threshold=0.05, alpha=0.0, normalize=True)
    assert got[0, 3] == 0.0  # dropped by its share, although its raw coefficient (0.002) ...
    assert got[1, 2] != 0.0  # ... is as large as a kept one (2e-3 on a column of size 1e3)
    np.testing.assert_allclose(got[0, :2], coef[0, :2], rtol=1e-2)
    np.testing.assert_allclose(got[1, 2:], coef[1, 2:], rtol=1e-2)


def test_an_all_zero_column_is_left_out_not_divided_by_zero():
    theta, coef, target = _system(2)
    theta = np.column_stack([theta, np.zeros(len(theta))])
    got = fit_stlsq(theta, target, threshold=0.0, alpha=0.0, normalize=True)
    assert np.all(np.isfinite(got)) and np.all(got[:, 4] == 0.0)
    np.testing.assert_allclose(got[:, :4], coef, rtol=1e-9, atol=1e-12)


def test_a_weak_equation_keeps_its_terms_the_threshold_is_relative_to_its_own_signal():
    theta, coef, _ = _system(3)
    coef[1] = [0.0, 0.0, 2e-6, 8e-4]  # a weak equation: every term's absolute contribution is small
    target = theta @ coef.T
    absolute = np.abs(coef[1]) * np.linalg.norm(theta, axis=0)
    share = absolute / np.linalg.norm(target[:, 1])
    assert np.all(absolute[2:] < 0.05) and np.all(share[2:] > 0.05)  # hand-computed
    got = fit_stlsq(theta, target, threshold=0.05, alpha=0.0, normalize=True)
    np.testing.assert_allclose(got[1, 2:], coef[1, 2:], rtol=1e-6)
