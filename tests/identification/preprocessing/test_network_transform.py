"""The LTD800-to-AT960 transform from the survey network: table 7.2, independent methods, blunders.

Only the survey numbers of ``simulation/data/calibration.yaml`` go in; table 7.2 (the thesis's
own result, computed by Spatial Analyzer) is what comes out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from groundfloor.errors import InputError
from identification.preprocessing.network_transform import (
    ARCSEC_PER_RAD,
    _rotation_and_derivatives,
    angles_from_rotation,
    fit_transform,
    rotation_from_angles,
)
from tests.support.survey_tables import TABLE_7_2_ROT_DEG, TABLE_7_2_T

# ---------------------------------------------------------------- table 7.2

def test_transform_reproduces_table_7_2(survey):
    fit = fit_transform(survey)
    dt_um = (fit.t_table - TABLE_7_2_T) * 1e6
    drot_arcsec = (fit.rotation_rad - np.radians(TABLE_7_2_ROT_DEG)) * ARCSEC_PER_RAD
    assert np.all(np.abs(dt_um) < 10.0), dt_um
    assert np.all(np.abs(drot_arcsec) < 0.5), drot_arcsec
    # The INTERFACES translation t is R t_table, not t_table: both conventions in one fit.
    np.testing.assert_allclose(fit.R_at960_ltd800 @ fit.t_table, fit.t_at960_ltd800, atol=1e-12)
    # The survey sigmas are pessimistic (USMN); no point is flagged on the real network.
    assert fit.blunder_point is None
    assert 0.05 < fit.variance_factor < 1.0
    # ... so pessimistic that the global test rejects them (s0^2 below chi2(2.5 %, dof) / dof)
    test = fit.variance_factor_test
    assert test.verdict == "too small" and test.dof == fit.dof and test.s0_sq == fit.variance_factor
    # Uncertainties of the order of table 7.2's (20-36 um, 0.7-1.2 arcsec); USMN's own model
    # is not transparent (section 7.2), so only the magnitude is compared.
    assert np.all((fit.t_table_std > 10e-6) & (fit.t_table_std < 50e-6))
    assert np.all((fit.params_std[3:] * ARCSEC_PER_RAD > 0.4)
                  & (fit.params_std[3:] * ARCSEC_PER_RAD < 2.0))


# ---------------------------------------------------------------- second implementations

def _horn_quaternion(x_from, x_to, w):
    """Horn's (1987) closed-form absolute orientation with unit quaternions (weighted)."""
    w = w / w.sum()
    a, b = x_from - w @ x_from, x_to - w @ x_to
    S = np.einsum("n,ni,nj->ij", w, a, b)
    N = np.array([
        [S[0, 0] + S[1, 1] + S[2, 2], S[1, 2] - S[2, 1], S[2, 0] - S[0, 2], S[0, 1] - S[1, 0]],
        [S[1, 2] - S[2, 1], S[0, 0] - S[1, 1] - S[2, 2], S[0, 1] + S[1, 0], S[2, 0] + S[0, 2]],
        [S[2, 0] - S[0, 2], S[0, 1] + S[1, 0], -S[0, 0] + S[1, 1] - S[2, 2], S[1, 2] + S[2, 1]],
        [S[0, 1] - S[1, 0], S[2, 0] + S[0, 2], S[1, 2] + S[2, 1], -S[0, 0] - S[1, 1] + S[2, 2]]])
    q = np.linalg.eigh(N)[1][:, -1]  # (w, x, y, z)
    R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    return R, w @ x_to - R @ (w @ x_from)


def test_wls_equals_horn_when_sigmas_are_isotropic_and_equal(survey):
    """With one isotropic sigma everywhere the Gauss-Helmert fit IS Horn's closed form."""
    same = {k: np.r_[v[:3], 30e-6, 30e-6, 30e-6] for k, v in survey.network_ltd800.items()}
    same_at = {k: np.r_[v[:3], 30e-6, 30e-6, 30e-6] for k, v in survey.network_at960.items()}
    fit = fit_transform(dataclasses.replace(survey, network_ltd800=same, network_at960=same_at))
    x_ltd = np.array([same[i][:3] for i in fit.point_ids])
    x_at = np.array([same_at[i][:3] for i in fit.point_ids])
    R, t = _horn_quaternion(x_ltd, x_at, np.ones(len(x_at)))
    np.testing.assert_allclose(fit.R_at960_ltd800, R, atol=1e-12)
    np.testing.assert_allclose(fit.t_at960_ltd800, t, atol=1e-10)


def test_wls_and_horn_differ_only_by_the_weighting(survey):
    """On the real sigmas WLS and unweighted Horn differ by a few um / tenths of an arcsec."""
    fit = fit_transform(survey)
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in fit.point_ids])
    x_at = np.array([survey.network_at960[i][:3] for i in fit.point_ids])
    R, t = _horn_quaternion(x_ltd, x_at, np.ones(len(x_at)))
    d_rot = Rotation.from_matrix(R.T @ fit.R_at960_ltd800).magnitude() * ARCSEC_PER_RAD
    d_t_table = np.linalg.norm(R.T @ t - fit.t_table)
    assert 0.01 < d_rot < 2.0  # weights matter, but only within the parameter uncertainty
    assert d_t_table < 30e-6


def test_covariance_matches_monte_carlo(survey):
    """200 noisy copies of a consistent network: spread of the fits = reported std (20 %)."""
    fit = fit_transform(survey)
    ids = fit.point_ids
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in ids])
    std_ltd = np.array([survey.network_ltd800[i][3:] for i in ids])
    std_at = np.array([survey.network_at960[i][3:] for i in ids])
    x_at_true = fit.t_at960_ltd800 + x_ltd @ fit.R_at960_ltd800.T
    rng = np.random.default_rng(7)
    params, s0, T, accepted = [], [], [], []
    for _ in range(200):  # one fit per draw: each fit is one batched solve
        noisy_ltd = x_ltd + rng.normal(size=x_ltd.shape) * std_ltd
        noisy_at = x_at_true + rng.normal(size=x_ltd.shape) * std_at
        s = dataclasses.replace(
            survey, network_ltd800=dict(zip(ids, np.hstack([noisy_ltd, std_ltd]))),
            network_at960=dict(zip(ids, np.hstack([noisy_at, std_at]))))
        f = fit_transform(s)
        params.append(np.r_[f.t_at960_ltd800, f.rotation_rad])
        s0.append(f.variance_factor)
        T.append(f.point_test)
        accepted.append(f.variance_factor_test.accepted)
    mc_std = np.std(params, axis=0, ddof=1)
    ratio = mc_std / fit.params_std
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    assert abs(np.mean(s0) - 1.0) < 0.15  # sigma0^2 = 1 when the sigmas are right
    assert np.mean(accepted) > 0.9  # ... and the global test accepts 95 % of the draws (200: >= 90 %)
    # Without blunders the leave-one-out statistic is chi2(3): mean 3, variance 6.
    assert abs(np.mean(T) - 3.0) < 0.3
    assert abs(np.var(T) - 6.0) < 1.5


def test_rotation_convention_and_derivatives():
    """R = Rz Ry Rx (eq. 5.5) equals scipy's extrinsic xyz; dR/dangles = numerical."""
    angles = np.array([[-0.0065, -0.0032, 2.49], [0.3, -1.2, -2.0]])
    R, dR = _rotation_and_derivatives(angles)
    np.testing.assert_allclose(R, Rotation.from_euler("xyz", angles).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(angles_from_rotation(R), angles, atol=1e-13)
    np.testing.assert_allclose(rotation_from_angles(angles), R, atol=0)
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        num = (rotation_from_angles(angles + step) - rotation_from_angles(angles - step)) / (2 * h)
        np.testing.assert_allclose(dR[..., k], num, atol=1e-9)


# ---------------------------------------------------------------- blunders

@pytest.mark.parametrize("pid", ["31", "41", "43", "53", "63", "61", "51"])
def test_swapped_coordinates_are_flagged_and_named(survey, pid):
    net = {k: v.copy() for k, v in survey.network_ltd800.items()}
    net[pid][[0, 1]] = net[pid][[1, 0]]
    bad = dataclasses.replace(survey, network_ltd800=net)
    fit = fit_transform(bad)
    assert fit.blunder_point == pid
    assert fit.global_test_p < 1e-6
    with pytest.raises(InputError, match=f"network point '{pid}' fails the outlier test"):
        fit_transform(bad, strict=True)


@pytest.mark.parametrize("pid", ["31", "53", "61"])
def test_one_millimetre_blunder_in_at960_is_named(survey, pid):
    """A small blunder (1 mm in z, about 15 sigma) on the other tracker's list is found too."""
    net = {k: v.copy() for k, v in survey.network_at960.items()}
    net[pid][2] += 1e-3
    fit = fit_transform(dataclasses.replace(survey, network_at960=net))
    assert fit.blunder_point == pid
    assert pid in fit.blunder_message()


# ---------------------------------------------------------------- bad input

def test_collinear_network_is_rejected(survey):
    ids = ("a", "b", "c", "d")
    line = {i: np.r_[k * 1.0, 2 * k, 0.0, 1e-5, 1e-5, 1e-5] for k, i in enumerate(ids)}
    with pytest.raises(InputError, match="network points a, b, c, d are collinear"):
        fit_transform(dataclasses.replace(survey, network_at960=line, network_ltd800=line))
