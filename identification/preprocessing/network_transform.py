"""The LTD800-to-AT960 transform fitted to the survey network (thesis 5.2.1, table 7.2).

:func:`fit_transform`: the rigid 6-parameter transform ``x_at960 = t + R x_ltd800`` with
``R = Rz(rz) Ry(ry) Rx(rx)`` (eqs. 5.1 to 5.5), weighted least squares in the Gauss-Helmert
model of section 2.4 (eqs. 2.17 to 2.26) with the sigmas of both trackers, started from a
closed-form weighted Kabsch/Horn solution (:func:`fit_transform_closed_form`), with a global
chi-square test and a leave-one-out point test that names a blundered network point. See
``docs/conventions.md`` for the conventions and the measured agreement with table 7.2.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import stats

from groundfloor.adjustment import VarianceFactorTest, variance_factor_test
from groundfloor.errors import InputError
from groundfloor.types import Survey

log = logging.getLogger(__name__)

ARCSEC_PER_RAD = 180.0 / np.pi * 3600.0


# --------------------------------------------------------------------------------------------
# Rotations (eqs. 5.2 to 5.5)
# --------------------------------------------------------------------------------------------

def rotation_from_angles(rotation_rad: np.ndarray) -> np.ndarray:
    """Return ``Rz(rz) Ry(ry) Rx(rx)`` (eq. 5.5) for angles ``(..., 3)`` = (rx, ry, rz), rad."""
    return _rotation_and_derivatives(np.asarray(rotation_rad, dtype=float))[0]


def angles_from_rotation(R: np.ndarray) -> np.ndarray:
    """Return the angles (rx, ry, rz) in rad, ``(..., 3)``, with ``R = Rz Ry Rx`` (eq. 5.5)."""
    R = np.asarray(R, dtype=float)
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    ry = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([rx, ry, rz], axis=-1)


def _rotation_and_derivatives(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``R (..., 3, 3)`` of eq. 5.5 and ``dR/d(rx, ry, rz)`` as ``(..., 3, 3, 3)``."""
    c, s = np.cos(angles), np.sin(angles)
    one, zero = np.ones_like(c[..., 0]), np.zeros_like(c[..., 0])

    def mat(rows):
        return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)

    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    sx, sy, sz = s[..., 0], s[..., 1], s[..., 2]
    Rx = mat([[one, zero, zero], [zero, cx, -sx], [zero, sx, cx]])
    Ry = mat([[cy, zero, sy], [zero, one, zero], [-sy, zero, cy]])
    Rz = mat([[cz, -sz, zero], [sz, cz, zero], [zero, zero, one]])
    dRx = mat([[zero, zero, zero], [zero, -sx, -cx], [zero, cx, -sx]])
    dRy = mat([[-sy, zero, cy], [zero, zero, zero], [-cy, zero, -sy]])
    dRz = mat([[-sz, -cz, zero], [cz, -sz, zero], [zero, zero, zero]])
    R = Rz @ Ry @ Rx
    dR = np.stack([Rz @ Ry @ dRx, Rz @ dRy @ Rx, dRz @ Ry @ Rx], axis=-1)
    return R, dR


# --------------------------------------------------------------------------------------------
# LTD800 -> AT960 transform (section 5.2.1)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TransformFit:
    """The LTD800-to-AT960 rigid transform fitted to the network, with its statistics.

    Parameter order everywhere: ``[tx, ty, tz, rx, ry, rz]`` (m, rad), for
    ``x_at960 = t_at960_ltd800 + R_at960_ltd800 @ x_ltd800`` (eq. 5.1).
    """

    point_ids: tuple[str, ...]
    R_at960_ltd800: np.ndarray  # (3, 3)
    t_at960_ltd800: np.ndarray  # (3,) m
    rotation_rad: np.ndarray  # (3,) rx, ry, rz of eq. 5.5
    t_table: np.ndarray  # (3,) R^T t, the translation as table 7.2 lists it, m
    cov_params: np.ndarray  # (6, 6) a priori (sigma0 = 1: the survey sigmas are absolute)
    t_table_std: np.ndarray  # (3,) m, a priori
    variance_factor: float  # a posteriori s0^2 = Omega / dof (eq. 2.25)
    dof: int  # 3 n - 6
    residuals_m: np.ndarray  # (n, 3) x_at960 - (t + R x_ltd800), AT960 frame
    normalised_residuals: np.ndarray  # (n, 3) residual / its std (w-test, N(0, 1) if no blunder)
    global_test_p: float  # p-value of Omega ~ chi2(dof)
    point_test: np.ndarray  # (n,) leave-one-out statistic T_i ~ chi2(3) without blunder
    point_test_p: np.ndarray  # (n,) Bonferroni-corrected p-values of T_i
    worst_point: str  # point with the largest T_i
    blunder_point: str | None  # worst_point if it fails the test at level alpha, else None
    iterations: int

    @property
    def variance_factor_test(self) -> VarianceFactorTest:
        """The global test of ``variance_factor`` against chi2(dof) / dof (two-sided, 5 %)."""
        return variance_factor_test(self.variance_factor, self.dof)

    @property
    def params_std(self) -> np.ndarray:
        """Return the (6,) a priori standard deviations of ``[tx, ty, tz, rx, ry, rz]``."""
        return np.sqrt(np.diag(self.cov_params))

    def blunder_message(self, source: str = "calibration.yaml") -> str:
        """Return a one-line verdict of the outlier test that names the worst network point."""
        i = self.point_ids.index(self.worst_point)
        verdict = "fails" if self.blunder_point else "passes"
        return (f"{source}: network point '{self.worst_point}' {verdict} the outlier test "
                f"(T = {self.point_test[i]:.3g}, corrected p = {self.point_test_p[i]:.2g}, "
                f"residual {np.linalg.norm(self.residuals_m[i]) * 1e6:.0f} um)")


def fit_transform(survey: Survey, alpha: float = 0.001, strict: bool = False,
                  max_iter: int = 20, tol: float = 1e-13) -> TransformFit:
    """Return the weighted least-squares LTD800-to-AT960 transform of the survey network.

    Implements eqs. 5.1 to 5.5 (transform) in the Gauss-Helmert model of eqs. 2.17 to 2.26:
    condition equations ``x_at960 - t - R(rx, ry, rz) x_ltd800 = 0`` per network point, both
    trackers' coordinates as observations with their sigmas, iterated (linearised at the
    corrected observations) until the update is below ``tol``; started from a weighted
    Kabsch/Horn solution. No scale (the thesis uses 6 parameters).

    Blunders: the global test compares ``Omega = sum e_i^T W_i e_i`` with chi2(3n - 6); each
    point i is also tested against the transform fitted WITHOUT it,
    ``T_i = d_i^T (Sigma_i + J_i Q_xx^(-i) J_i^T)^-1 d_i ~ chi2(3)`` (the 3-D, leave-one-out
    form of Baarda's data snooping, robust to a gross blunder dragging the full fit). The worst
    point is flagged when its Bonferroni-corrected p-value is below ``alpha``.

    Parameters
    ----------
    survey : Survey
        From :func:`identification.preprocessing.io_survey.read_survey`.
    alpha : float
        Level of the point test (family-wise over the n points).
    strict : bool
        Raise :class:`InputError` naming the point when a blunder is flagged.

    Raises
    ------
    InputError
        Degenerate (collinear) network, or a blunder with ``strict``.
    """
    ids = tuple(survey.network_at960)
    at = np.array([survey.network_at960[i] for i in ids])
    ltd = np.array([survey.network_ltd800[i] for i in ids])
    x_at, x_ltd = at[:, :3], ltd[:, :3]
    cov_at, cov_ltd = _diag_cov(at[:, 3:]), _diag_cov(ltd[:, 3:])
    n = len(ids)
    _check_network_geometry(x_ltd, ids)

    # Problem 0 uses every point, problem 1 + i leaves point i out (leave-one-out test).
    use = np.vstack([np.ones(n, bool), ~np.eye(n, dtype=bool)]) if n > 3 else np.ones((1, n), bool)
    params, Q_xx, iterations = _solve_gauss_helmert(x_at, cov_at, x_ltd, cov_ltd, use,
                                                    max_iter, tol)
    R, dR = _rotation_and_derivatives(params[:, 3:])
    # Full-fit statistics.
    e = x_at - params[0, :3] - x_ltd @ R[0].T
    cov_e = cov_at + R[0] @ cov_ltd @ R[0].T
    W = np.linalg.inv(cov_e)
    omega = float(np.einsum("ni,nij,nj->", e, W, e))
    dof = 3 * n - 6
    J = _jacobian(x_ltd, dR[0])  # (n, 3, 6) d(t + R x)/d params
    # Residual covariance: Sigma_ee = Sigma_ww - A Q_xx A^T (blocks on the diagonal suffice).
    cov_res = cov_e - J @ Q_xx[0] @ J.transpose(0, 2, 1)
    w_norm = e / np.sqrt(np.clip(np.diagonal(cov_res, axis1=1, axis2=2), 1e-30, None))

    if n > 3:
        loo_R, loo_t = R[1:], params[1:, :3]  # (n, 3, 3), (n, 3): fit without point i
        d = x_at - loo_t - np.einsum("nij,nj->ni", loo_R, x_ltd)
        # Jacobian at point i of the fit without point i: (n, 3, 6).
        J_loo = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)),
                                np.einsum("nijk,nj->nik", dR[1:], x_ltd)], axis=-1)
        cov_d = cov_at + loo_R @ cov_ltd @ loo_R.transpose(0, 2, 1) \
            + J_loo @ Q_xx[1:] @ J_loo.transpose(0, 2, 1)
        T = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov_d), d)
        p_point = np.minimum(1.0, n * stats.chi2.sf(T, 3))
    else:  # no redundancy left after removing a point: cannot localise a blunder
        T, p_point = np.zeros(n), np.ones(n)
    worst = int(np.argmax(T))
    blunder = ids[worst] if p_point[worst] < alpha else None

    t = params[0, :3]
    J_tab = np.hstack([R[0].T, np.einsum("jik,j->ik", dR[0], t)])  # d(R^T t)/d params
    fit = TransformFit(
        point_ids=ids, R_at960_ltd800=R[0], t_at960_ltd800=t, rotation_rad=params[0, 3:],
        t_table=R[0].T @ t, cov_params=Q_xx[0],
        t_table_std=np.sqrt(np.diag(J_tab @ Q_xx[0] @ J_tab.T)),
        variance_factor=omega / dof, dof=dof, residuals_m=e, normalised_residuals=w_norm,
        global_test_p=float(stats.chi2.sf(omega, dof)), point_test=T, point_test_p=p_point,
        worst_point=ids[worst], blunder_point=blunder, iterations=iterations)
    if blunder is not None:
        log.warning("%s", fit.blunder_message())
        if strict:
            raise InputError(fit.blunder_message())
    return fit


def fit_transform_closed_form(x_ltd800: np.ndarray, x_at960: np.ndarray,
                              weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(R_at960_ltd800, t_at960_ltd800)`` of the closed-form weighted Kabsch/Horn fit.

    Minimises ``sum_i w_i |x_at960_i - t - R x_ltd800_i|^2`` over rotations (SVD of the
    weighted cross-covariance, reflection excluded). Leading batch dimensions are allowed:
    ``x_*`` ``(..., n, 3)``, ``weights`` ``(..., n)`` (a zero weight drops a point).
    """
    x_ltd800, x_at960 = np.asarray(x_ltd800, float), np.asarray(x_at960, float)
    w = np.ones(x_ltd800.shape[:-1]) if weights is None else np.asarray(weights, float)
    w = w / w.sum(axis=-1, keepdims=True)
    c_ltd = np.einsum("...n,...ni->...i", w, x_ltd800)
    c_at = np.einsum("...n,...ni->...i", w, x_at960)
    H = np.einsum("...n,...ni,...nj->...ij", w, x_ltd800 - c_ltd[..., None, :],
                  x_at960 - c_at[..., None, :])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2)
    # Force det(R) = +1: a reflection would fit a mirrored network.
    sign = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0], D[..., 1, 1], D[..., 2, 2] = 1.0, 1.0, sign
    R = V @ D @ np.swapaxes(U, -1, -2)
    t = c_at - np.einsum("...ij,...j->...i", R, c_ltd)
    return R, t


def _solve_gauss_helmert(x_at, cov_at, x_ltd, cov_ltd, use, max_iter, tol):
    """Return params ``(k, 6)``, ``Q_xx (k, 6, 6)`` and iterations for k point subsets ``use``.

    Implements eqs. 2.17 to 2.24 for the condition ``x_at - t - R x_ltd = 0``; the k problems
    (full network and leave-one-out subsets) are solved together, batched in numpy.
    """
    mask = use.astype(float)
    # Rotation-invariant scalar weights for the start: trace(R S R^T) = trace(S).
    w0 = mask / np.trace(cov_at + cov_ltd, axis1=1, axis2=2)
    R0, t0 = fit_transform_closed_form(np.broadcast_to(x_ltd, use.shape + (3,)),
                                       np.broadcast_to(x_at, use.shape + (3,)), w0)
    params = np.concatenate([t0, angles_from_rotation(R0)], axis=1)
    x_ltd_hat = np.broadcast_to(x_ltd, use.shape + (3,)).copy()  # corrected observations
    for iteration in range(1, max_iter + 1):
        R, dR = _rotation_and_derivatives(params[:, 3:])
        # Misclosure w = Phi(L, X_k); Phi is linear in L, so this equals
        # Phi(L_hat, X_k) + B (L - L_hat) of the iterated Gauss-Helmert model.
        w = x_at - params[:, None, :3] - np.einsum("kij,nj->kni", R, x_ltd)
        # J = d(t + R x_ltd)/dX at the corrected observations; the A of eq. 2.15 is -J, and
        # the two signs cancel in the normal equations below.
        J = _jacobian(x_ltd_hat, dR)  # (k, n, 3, 6)
        cov_w = cov_at + R[:, None] @ cov_ltd @ np.swapaxes(R, 1, 2)[:, None]
        W = np.linalg.inv(cov_w) * mask[..., None, None]  # dropped points weigh nothing
        N = np.einsum("knai,knab,knbj->kij", J, W, J)
        b = np.einsum("knai,knab,knb->ki", J, W, w)
        dx = np.linalg.solve(N, b[..., None])[..., 0]
        params = params + dx
        k_mult = np.einsum("knab,knb->kna", W, w - np.einsum("knai,ki->kna", J, dx))
        # Corrections of eq. 2.23, v = Q_ll B^T k with B_ltd = -R and k = -k_mult.
        x_ltd_hat = x_ltd + np.einsum("nab,kcb,knc->kna", cov_ltd, R, k_mult)
        if np.max(np.abs(dx)) < tol:
            break
    return params, np.linalg.inv(N), iteration


def _jacobian(x_ltd: np.ndarray, dR: np.ndarray) -> np.ndarray:
    """Return ``d(t + R x_ltd)/d[t, angles]`` as ``(..., n, 3, 6)`` for ``dR (..., 3, 3, 3)``."""
    J_rot = np.einsum("...ijk,...nj->...nik", dR, x_ltd)
    J_t = np.broadcast_to(np.eye(3), J_rot.shape)
    return np.concatenate([J_t, J_rot], axis=-1)


def _diag_cov(std: np.ndarray) -> np.ndarray:
    """Return ``(n, 3, 3)`` diagonal covariances from ``(n, 3)`` standard deviations."""
    return np.einsum("ni,ij->nij", std**2, np.eye(3))


def _check_network_geometry(x: np.ndarray, ids: tuple[str, ...]) -> None:
    """Raise InputError when the network points are (nearly) collinear: no rotation about it."""
    s = np.linalg.svd(x - x.mean(axis=0), compute_uv=False)
    if s[1] < 1e-6 * max(s[0], 1e-12):
        raise InputError(f"calibration.yaml: network points {', '.join(ids)} are collinear; "
                         "the transform needs 3 points that span a plane")
