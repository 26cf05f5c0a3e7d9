"""Body poses from the two synchronised prism positions (thesis 5.2.4, eqs. 5.26 to 5.37).

Per epoch the two prisms give six coordinates in the local frame (the leveled AT960 frame);
their lever arms in the body frame (x forward, y left, z up) are known. Roll about the
baseline is unobservable, so the pose is ``[x, y, z, pitch, yaw]`` with roll 0:

.. math:: p_{i}^{l} = t^{l} + R_z(\\psi) R_y(\\theta) \\, l_{i}^{b} \\qquad (5.33 - 5.35)

Six observations, five unknowns: one degree of freedom per epoch (the baseline length). The
2D over-parameterised linear solution (eqs. 5.26 to 5.31) gives the start values, with
``z0`` from eq. 5.37 and ``pitch0 = 0``; Gauss-Newton on eq. 5.36 then converges in two or
three iterations. Everything is batched over epochs: (n, 6, 5) Jacobians and (n, 5, 5) normal
equations solved together, no Python loop per pose.

Uncertainties: the cofactor matrix ``(J^T P J)^-1`` with ``P`` from the tracker standard
deviations is the *a priori* covariance (default). The thesis scaled it by the a posteriori
variance factor ``s0^2 = v^T P v / 1`` (eqs. 2.25, 2.26); with one degree of freedom that
factor is a chi-square(1) draw per epoch (it is below 0.1 in a quarter of the epochs and above
2.7 in a tenth of them even for a perfect model), so it makes the pose sigmas jump from sample
to sample; it is offered with ``variance="a_posteriori"`` for comparison with figs. 7.2 and 7.3.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from groundfloor.adjustment import VarianceFactorTest, variance_factor_test
from groundfloor.errors import InputError
from groundfloor.types import PoseTrack

log = logging.getLogger(__name__)

#: default tracker standard deviation per coordinate when none is given, m (table 3.2:
#: AT960 repeatability 7.5 um + 3 um/m, LTD800 12 um at the ranges of the lab)
TRACKER_STD_DEFAULT_M = 10e-6


@dataclass(frozen=True)
class PoseFit:
    """Everything the pose adjustment computed; ``track`` is what the pipeline passes on."""

    track: PoseTrack
    cov: np.ndarray  # (n, 5, 5) covariance of [x, y, z, pitch, yaw] (as chosen by `variance`)
    cov_a_priori: np.ndarray  # (n, 5, 5) cofactor matrix scaled by the tracker variances
    s0_sq: np.ndarray  # (n,) a posteriori variance factor v^T P v / 1 (dof = 1)
    residual_m: np.ndarray  # (n, 6) observation corrections [front xyz, rear xyz], m
    start: np.ndarray  # (n, 3) 2D start values [x, y, yaw] of eqs. 5.26 to 5.31
    iterations: int  # Gauss-Newton iterations until the largest update fell below tolerance

    @property
    def variance_factor_test(self) -> VarianceFactorTest | None:
        """The global test over all epochs (None without one): the sum of the epochs' ``v^T P v``
        against chi2(number of epochs), i.e. their mean ``s0^2`` against 1 (eqs. 2.25, 2.26)."""
        ok = np.isfinite(self.s0_sq)
        return variance_factor_test(float(np.mean(self.s0_sq[ok])), int(ok.sum())) if ok.any() else None


def _as_rows(value, n: int, name: str) -> np.ndarray:
    """Return ``value`` broadcast to (n, 3) floats, or raise InputError naming ``name``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(3, float(arr))
    if arr.shape == (3,):
        return np.broadcast_to(arr, (n, 3))
    if arr.shape != (n, 3):
        raise InputError(f"{name}: shape {arr.shape}, expected (3,) or ({n}, 3)")
    return arr


def fit_poses_2d(p_front_local, p_rear_local, lever_front_body, lever_rear_body) -> np.ndarray:
    """Return (n, 3) 2D poses ``[x, y, yaw]`` (yaw unwrapped) from the prisms' xy coordinates.

    Implements eqs. 5.26 to 5.31: with ``a = cos(yaw)``, ``b = sin(yaw)`` as free unknowns the
    similarity transform is linear, four equations in four unknowns per epoch; the 4x4 matrix
    depends on the lever arms only, so for constant lever arms one inverse serves all epochs.
    ``yaw = atan2(b, a)`` (eq. 5.31). Rows with non-finite coordinates give NaN.
    """
    pf = np.asarray(p_front_local, float)
    pr = np.asarray(p_rear_local, float)
    n = pf.shape[0]
    lf = _as_rows(lever_front_body, n, "lever_front_body")
    lr = _as_rows(lever_rear_body, n, "lever_rear_body")
    const = np.ndim(lever_front_body) <= 1 and np.ndim(lever_rear_body) <= 1
    lf_, lr_ = (lf[:1], lr[:1]) if const else (lf, lr)
    A = np.zeros((lf_.shape[0], 4, 4))
    for row, lev in ((0, lf_), (2, lr_)):  # eq. 5.28, two rows per prism
        A[:, row, 0] = 1.0
        A[:, row, 2] = lev[:, 0]
        A[:, row, 3] = -lev[:, 1]
        A[:, row + 1, 1] = 1.0
        A[:, row + 1, 2] = lev[:, 1]
        A[:, row + 1, 3] = lev[:, 0]
    b = np.column_stack([pf[:, 0], pf[:, 1], pr[:, 0], pr[:, 1]])
    if const:
        sol = b @ np.linalg.inv(A[0]).T  # eq. 5.30, same matrix for every epoch
    else:
        sol = np.linalg.solve(A, b[..., None])[..., 0]
    yaw = np.arctan2(sol[:, 3], sol[:, 2])
    ok = np.isfinite(yaw)
    yaw[ok] = np.unwrap(yaw[ok])
    return np.column_stack([sol[:, 0], sol[:, 1], yaw])


def _prisms_and_jacobian(X: np.ndarray, lf: np.ndarray, lr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return modelled prisms (2, 3, n) and angle Jacobians J_p_angles (2, 3, 2, n) of eq. 5.33.

    Arrays are laid out prism, axis, (angle,) epoch so that every operation runs over the
    contiguous epoch axis. The Jacobian with respect to the translation is the identity.
    ``X`` is (5, n) ``[x, y, z, pitch, yaw]``; ``lf``, ``lr`` are (3, n) lever arms.
    """
    cth, sth = np.cos(X[3]), np.sin(X[3])
    cps, sps = np.cos(X[4]), np.sin(X[4])
    lev = np.stack([lf, lr])  # (2, 3, n)
    # q = R_y(pitch) l and its pitch derivative (eq. 5.34)
    qx = cth * lev[:, 0] + sth * lev[:, 2]
    qy = lev[:, 1]
    qz = -sth * lev[:, 0] + cth * lev[:, 2]
    qx_th = -sth * lev[:, 0] + cth * lev[:, 2]
    qz_th = -cth * lev[:, 0] - sth * lev[:, 2]
    rx = cps * qx - sps * qy  # R_z(yaw) q (eq. 5.35)
    ry = sps * qx + cps * qy
    p = np.stack([X[0] + rx, X[1] + ry, X[2] + qz], axis=1)
    zero = np.zeros_like(rx)
    J = np.stack([np.stack([cps * qx_th, -ry], 1),
                  np.stack([sps * qx_th, rx], 1),
                  np.stack([qz_th, zero], 1)], axis=1)
    return p, J


def _solve_normal(J: np.ndarray, P: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the Gauss-Newton update (5, n) and cofactor matrix (5, 5, n) of ``J dx = w``.

    ``J`` (2, 3, 2, n) are the angle columns, ``P`` (2, 3, n) the weights, ``w`` (2, 3, n)
    the misclosures. The translation block of ``J^T P J`` is diagonal (each prism's Jacobian
    is the identity in x, y, z), so the 5x5 normal equations reduce to 2x2 ones in pitch and
    yaw by a Schur complement, solved in closed form: elementwise arithmetic over the epoch
    axis instead of one small LAPACK call per epoch.
    """
    D_inv = 1.0 / P.sum(0)  # (3, n) inverse of the diagonal translation block
    B = np.sum(P[:, :, None] * J, axis=0)  # (3, 2, n) translation-angle block
    C = np.sum(P[:, :, None, None] * J[:, :, :, None] * J[:, :, None, :], axis=(0, 1))  # (2, 2, n)
    g_t = np.sum(P * w, axis=0)  # (3, n)
    g_a = np.sum((P * w)[:, :, None] * J, axis=(0, 1))  # (2, n)
    DB = D_inv[:, None] * B
    S = C - np.sum(B[:, :, None] * DB[:, None, :], axis=0)  # Schur complement (2, 2, n)
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    S_inv = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
    r_a = g_a - np.sum(DB * g_t[:, None], axis=0)
    dx_a = np.sum(S_inv * r_a[None], axis=1)
    dx_t = D_inv * g_t - np.sum(DB * dx_a[None], axis=1)
    DBS = np.sum(DB[:, :, None] * S_inv[None], axis=1)  # (3, 2, n) = D^-1 B S^-1
    Q = np.empty((5, 5, w.shape[-1]))
    Q[3:, 3:] = S_inv
    Q[:3, 3:] = -DBS
    Q[3:, :3] = -np.swapaxes(DBS, 0, 1)
    Q[:3, :3] = np.sum(DBS[:, None] * DB[None], axis=2)
    Q[[0, 1, 2], [0, 1, 2]] += D_inv
    return np.concatenate([dx_t, dx_a]), Q


def fit_poses_full(t, p_front_local, p_rear_local, lever_front_body, lever_rear_body,
                   std_front=None, std_rear=None, variance: str = "a_priori",
                   max_iter: int = 10, tol: float = 1e-11) -> PoseFit:
    """Return the 3D least-squares poses with covariances and diagnostics (see :func:`fit_poses`)."""
    if variance not in ("a_priori", "a_posteriori"):
        raise InputError(f"variance: must be 'a_priori' or 'a_posteriori', got {variance!r}")
    t = np.asarray(t, dtype=float).ravel()
    n = t.size
    pf = np.asarray(p_front_local, dtype=float)
    pr = np.asarray(p_rear_local, dtype=float)
    for name, p in (("p_front_local", pf), ("p_rear_local", pr)):
        if p.shape != (n, 3):
            raise InputError(f"{name}: shape {p.shape}, expected ({n}, 3) to match t")
    if n and np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(f"t: stamps not strictly increasing at sample {i + 1}")
    lf = _as_rows(lever_front_body, n, "lever_front_body")
    lr = _as_rows(lever_rear_body, n, "lever_rear_body")
    for name, lev in (("lever_front_body", lf), ("lever_rear_body", lr)):
        if not np.all(np.isfinite(lev)):
            raise InputError(f"{name}: non-finite lever arm")
    if np.any(np.hypot(lf[:, 0] - lr[:, 0], lf[:, 1] - lr[:, 1]) < 1e-3):
        raise InputError("lever_rear_body: prisms less than 1 mm apart horizontally; yaw unobservable")
    stds = []
    for name, std in (("std_front", std_front), ("std_rear", std_rear)):
        s = _as_rows(TRACKER_STD_DEFAULT_M if std is None else std, n, name)
        if not np.all(s[np.isfinite(s)] > 0):
            raise InputError(f"{name}: standard deviations must be positive")
        stds.append(s)
    std_obs = np.concatenate(stds, axis=1)  # (n, 6)
    obs = np.concatenate([pf, pr], axis=1)
    ok = np.all(np.isfinite(obs), axis=1) & np.all(np.isfinite(std_obs), axis=1)

    X = np.full((n, 5), np.nan)
    start = fit_poses_2d(pf, pr, lever_front_body, lever_rear_body)
    cov = np.full((n, 5, 5), np.nan)
    cov_prior = np.full((n, 5, 5), np.nan)
    s0_sq = np.full(n, np.nan)
    resid = np.full((n, 6), np.nan)
    it = 0
    if ok.any():
        o = obs[ok].T.reshape(2, 3, -1)  # prism, axis, epoch
        lf_o, lr_o = np.ascontiguousarray(lf[ok].T), np.ascontiguousarray(lr[ok].T)
        P = (1.0 / std_obs[ok] ** 2).T.reshape(2, 3, -1)
        Xo = np.stack([start[ok, 0], start[ok, 1],
                       0.5 * (o[0, 2] - lf_o[2] + o[1, 2] - lr_o[2]),  # eq. 5.37
                       np.zeros(o.shape[-1]), start[ok, 2]])
        for it in range(1, max_iter + 1):
            p_model, J = _prisms_and_jacobian(Xo, lf_o, lr_o)
            dx, Q = _solve_normal(J, P, o - p_model)
            Xo += dx
            if np.max(np.abs(dx)) < tol:
                break  # Q belongs to a point closer than tol to the solution: good enough
        else:
            log.warning("pose adjustment: no convergence after %d iterations (max update %.3g)",
                        max_iter, float(np.max(np.abs(dx))))
        v = _prisms_and_jacobian(Xo, lf_o, lr_o)[0] - o
        Q = np.moveaxis(Q, -1, 0)
        Q = 0.5 * (Q + np.swapaxes(Q, 1, 2))
        s0 = np.sum(P * v**2, axis=(0, 1)) / 1.0  # six observations, five unknowns
        X[ok], resid[ok], s0_sq[ok], cov_prior[ok] = Xo.T, v.reshape(6, -1).T, s0, Q
        cov[ok] = Q if variance == "a_priori" else s0[:, None, None] * Q
    if (~ok).any():
        log.info("pose adjustment: %d of %d epochs without both prisms -> NaN", int((~ok).sum()), n)
    std = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
    track = PoseTrack(t=t, x=X[:, 0], y=X[:, 1], z=X[:, 2], pitch=X[:, 3], yaw=X[:, 4],
                      x_std=std[:, 0], y_std=std[:, 1], z_std=std[:, 2], pitch_std=std[:, 3],
                      yaw_std=std[:, 4])
    return PoseFit(track=track, cov=cov, cov_a_priori=cov_prior, s0_sq=s0_sq, residual_m=resid,
                   start=start, iterations=it)


def fit_poses(t, p_front_local, p_rear_local, lever_front_body, lever_rear_body,
              std_front=None, std_rear=None, variance: str = "a_priori") -> PoseTrack:
    """Return the body poses ``[x, y, z, pitch, yaw]`` (roll 0) with standard deviations.

    Implements eqs. 5.26 to 5.37: 2D over-parameterised start values, then the 3D weighted
    least-squares adjustment of eq. 5.36 by batched Gauss-Newton.

    Parameters
    ----------
    t : (n,) strictly increasing times, s (copied into the track).
    p_front_local, p_rear_local : (n, 3) prism positions in the local frame at ``t``, m.
        Rows with NaN (a prism lost) give NaN poses.
    lever_front_body, lever_rear_body : (3,) lever arms in the body frame, m, or (n, 3) when
        they vary in time (e.g. plus :meth:`identification.preprocessing.hub.HubModel.eccentricity_body`).
    std_front, std_rear : tracker standard deviation per coordinate, m: scalar, (3,) or
        (n, 3); default :data:`TRACKER_STD_DEFAULT_M`.
    variance : ``"a_priori"`` (default, from the tracker sigmas) or ``"a_posteriori"``
        (scaled by the dof-1 variance factor as in the thesis; see the module docstring).

    Returns
    -------
    PoseTrack
        Body origin in the local frame, yaw unwrapped, ``*_std`` per the chosen variance.
    """
    return fit_poses_full(t, p_front_local, p_rear_local, lever_front_body, lever_rear_body,
                          std_front, std_rear, variance=variance).track
