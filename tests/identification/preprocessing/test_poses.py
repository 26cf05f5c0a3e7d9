"""Pose adjustment (eqs. 5.26 to 5.37) against synthetic truth (tests/tests.support.pose_synth.py)."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import PoseTrack
from identification.preprocessing.figures import plot_poses
from identification.preprocessing.hub import fit_hub_model
from identification.preprocessing.poses import (
    _prisms_and_jacobian,
    fit_poses,
    fit_poses_2d,
    fit_poses_full,
)
from tests.support.pose_synth import LEVER_FRONT, LEVER_REAR, measurements

#: yaw noise floor of two prisms with sigma per coordinate and horizontal baseline b:
#: yaw = atan2 of the baseline, the perpendicular noise of both ends adds: sqrt(2) sigma / b
BASE_H = float(np.hypot(*(LEVER_FRONT - LEVER_REAR)[:2]))


def _yaw_floor_rad(sigma_m: float) -> float:
    return np.sqrt(2.0) * sigma_m / BASE_H


def _errors(track: PoseTrack, truth) -> np.ndarray:
    """Return (n, 5) pose errors; yaw modulo 2 pi (the unwrapped yaw starts in (-pi, pi])."""
    d_yaw = (track.yaw - truth.yaw + np.pi) % (2 * np.pi) - np.pi
    return np.column_stack([track.x - truth.x, track.y - truth.y, track.z - truth.z,
                            track.pitch - truth.pitch, d_yaw])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_poses_recover_truth_without_eccentricity(seed):
    m = measurements(duration_s=60.0, seed=seed, radius_m=(0.0, 0.0))
    fit = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR, std_front=m.noise_m, std_rear=m.noise_m)
    err = _errors(fit.track, m.truth)
    rms = np.sqrt(np.mean(err**2, axis=0))
    assert np.all(rms[:3] < 0.5e-3)  # the bar
    assert np.degrees(rms[4]) < 0.01
    # ... and what the tracker noise allows: about 10 um in position, 0.0015 deg in yaw
    assert rms[4] == pytest.approx(_yaw_floor_rad(m.noise_m), rel=0.15)
    assert np.all(rms[:2] < 1.5 * m.noise_m)
    # the a priori covariance is consistent: mean NEES = 5 (chi-square, 5 dof, 3000 epochs)
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(fit.cov), err)
    assert np.mean(nees) == pytest.approx(5.0, abs=0.3)
    # the dof-1 variance factor is a chi-square(1) draw per epoch: mean 1, a quarter below 0.1
    assert np.mean(fit.s0_sq) == pytest.approx(1.0, abs=0.1)
    assert np.mean(fit.s0_sq < 0.1) == pytest.approx(0.248, abs=0.04)
    assert fit.iterations <= 5
    np.testing.assert_allclose(fit.track.yaw_std, _yaw_floor_rad(m.noise_m), rtol=0.05)


def test_hub_model_then_poses_reaches_yaw_floor():
    """With table 7.5's eccentricities the raw yaw is biased; time-varying lever arms fix it."""
    m = measurements(duration_s=90.0, seed=4)
    raw = fit_poses(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR)
    hub = fit_hub_model(m.t, np.linalg.norm(m.p_front - m.p_rear, axis=1), m.az_front, m.az_rear)
    e_f, e_r = hub.eccentricity_body(m.az_front, m.az_rear, LEVER_FRONT, LEVER_REAR)
    fixed = fit_poses(m.t, m.p_front, m.p_rear, LEVER_FRONT + e_f, LEVER_REAR + e_r)
    pf, pr = hub.correct(m.p_front, m.p_rear, m.az_front, m.az_rear)
    local = fit_poses(m.t, pf, pr, LEVER_FRONT, LEVER_REAR)
    rms_raw, rms_fixed, rms_local = (np.sqrt(np.mean(_errors(p, m.truth) ** 2, axis=0)) for p in (raw, fixed, local))
    floor = _yaw_floor_rad(m.noise_m)
    assert rms_raw[4] > 3 * floor  # eccentricity dominates the yaw error ...
    assert rms_fixed[4] < 1.5 * floor and rms_local[4] < 1.5 * floor  # ... and is removed
    assert np.degrees(rms_fixed[4]) < 0.01 and np.all(rms_fixed[:3] < 0.5e-3)


def test_2d_start_exact_without_pitch_and_noise():
    m = measurements(duration_s=20.0, seed=3, noise_m=0.0, radius_m=(0.0, 0.0))
    tr = m.truth
    c, s = np.cos(tr.yaw), np.sin(tr.yaw)

    def prism_flat(lev):
        """Prism positions with zero pitch: the 2D similarity of eqs. 5.26-5.31 is then exact."""
        return np.column_stack([tr.x + c * lev[0] - s * lev[1], tr.y + s * lev[0] + c * lev[1], tr.z + lev[2]])

    start = fit_poses_2d(prism_flat(LEVER_FRONT), prism_flat(LEVER_REAR), LEVER_FRONT, LEVER_REAR)
    np.testing.assert_allclose(start[:, 0], tr.x, atol=1e-9)
    np.testing.assert_allclose(np.cos(start[:, 2] - tr.yaw), 1.0, atol=1e-15)
    assert np.ptp(np.diff(start[:, 2]) - np.diff(tr.yaw)) < 1e-9  # unwrapped like the truth
    # with pitch the 2D start is off (lever z tilted into x) and the 3D adjustment removes it
    fit = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR)
    err_2d = np.abs(fit.start[:, 0] - m.truth.x).max()
    err_3d = np.abs(fit.track.x - m.truth.x).max()
    assert err_2d > 1e-3 and err_3d < 1e-9


def test_jacobian_matches_numerical_derivative():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.normal(size=4), rng.normal(size=4), rng.normal(size=4),
                         rng.uniform(-0.2, 0.2, 4), rng.uniform(-3, 3, 4)]).T
    lf, lr = (np.repeat(v[:, None], 4, axis=1) for v in (LEVER_FRONT, LEVER_REAR))
    _, J = _prisms_and_jacobian(X, lf, lr)
    eps = 1e-6
    for k in (3, 4):  # the angle columns; translation columns are the identity by construction
        d = np.zeros((5, 1))
        d[k] = eps
        J_num = (_prisms_and_jacobian(X + d, lf, lr)[0] - _prisms_and_jacobian(X - d, lf, lr)[0]) / (2 * eps)
        np.testing.assert_allclose(J[:, :, k - 3], J_num, atol=1e-8)


def test_nan_rows_give_nan_poses_and_leave_others_alone():
    m = measurements(duration_s=10.0, seed=2, radius_m=(0.0, 0.0))
    pf = m.p_front.copy()
    pf[100:150] = np.nan
    full = fit_poses(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR)
    holed = fit_poses(m.t, pf, m.p_rear, LEVER_FRONT, LEVER_REAR)
    assert np.all(np.isnan(holed.x[100:150])) and np.all(np.isnan(holed.yaw_std[100:150]))
    keep = np.r_[0:100, 150:len(m.t)]
    np.testing.assert_allclose(holed.yaw[keep], full.yaw[keep], atol=1e-12)


def test_a_posteriori_variance_is_scaled_by_s0():
    m = measurements(duration_s=5.0, seed=6, radius_m=(0.0, 0.0))
    prior = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR)
    post = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR, variance="a_posteriori")
    np.testing.assert_allclose(post.track.yaw_std, prior.track.yaw_std * np.sqrt(prior.s0_sq), rtol=1e-9)


def test_global_test_of_the_pose_adjustment_checks_the_tracker_sigmas():
    # one degree of freedom per epoch: the epochs' s0^2 together are tested against chi2(n) / n
    m = measurements(duration_s=20.0, seed=3, radius_m=(0.0, 0.0))
    right = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR, std_front=m.noise_m, std_rear=m.noise_m)
    t = right.variance_factor_test
    assert t.accepted and t.dof == len(m.t) and t.s0_sq == pytest.approx(np.mean(right.s0_sq))
    # sigmas twice the noise: s0^2 about 1/4, rejected as pessimistic; half the noise: optimistic
    for factor, verdict in ((2.0, "too small"), (0.5, "too large")):
        fit = fit_poses_full(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR, std_front=factor * m.noise_m,
                             std_rear=factor * m.noise_m)
        assert fit.variance_factor_test.verdict == verdict
        assert fit.variance_factor_test.s0_sq == pytest.approx(t.s0_sq / factor**2, rel=1e-3)


def test_plot_poses(tmp_path):
    m = measurements(duration_s=5.0, seed=1)
    figs = plot_poses(fit_poses(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR), tmp_path / "run")
    assert len(figs) == 2 and (tmp_path / "run_attitude.png").stat().st_size > 10_000


# ------------------------------------------------------------------------------- bad inputs

@pytest.fixture(scope="module")
def small():
    return measurements(duration_s=2.0, seed=0)


def test_bad_prism_shape(small):
    with pytest.raises(InputError, match="p_rear_local"):
        fit_poses(small.t, small.p_front, small.p_rear[:-1], LEVER_FRONT, LEVER_REAR)


def test_bad_lever_arm(small):
    with pytest.raises(InputError, match="lever_front_body"):
        fit_poses(small.t, small.p_front, small.p_rear, [np.nan, 0, 0], LEVER_REAR)
    with pytest.raises(InputError, match="lever_rear_body.*apart"):
        fit_poses(small.t, small.p_front, small.p_rear, LEVER_FRONT, LEVER_FRONT + [0, 0, 0.1])


def test_bad_std(small):
    with pytest.raises(InputError, match="std_front"):
        fit_poses(small.t, small.p_front, small.p_rear, LEVER_FRONT, LEVER_REAR, std_front=-1e-5)


def test_bad_time_order(small):
    t = small.t.copy()
    t[10] = t[9]
    with pytest.raises(InputError, match="t: .*sample 10"):
        fit_poses(t, small.p_front, small.p_rear, LEVER_FRONT, LEVER_REAR)


def test_bad_variance_option(small):
    with pytest.raises(InputError, match="variance"):
        fit_poses(small.t, small.p_front, small.p_rear, LEVER_FRONT, LEVER_REAR, variance="sometimes")
