"""Geodetic fixes into the local frame: WGS84 -> east-north-up (pymap3d), then ENU -> local.

The local frame ``l`` of the poses is leveled (its z is up), so it differs from the east-north-up
frame at a geodetic origin by a rotation about the vertical and a translation:

    p_local = Rz(yaw) p_enu + t_local,    yaw = ``enu_to_local_yaw_deg``

(``Rz(yaw)`` takes a vector's ENU coordinates to its local coordinates). The transform is either
given in ``campaign.yaml`` (``geodetic_origin: {lat_deg, lon_deg, alt_m}``,
``enu_to_local_yaw_deg``, optionally ``enu_to_local_t_m``) or estimated by
:func:`estimate_enu_to_local` from fixes and the ground-truth antenna positions, with its
uncertainty. Geodetic -> ENU is pymap3d's (a maintained library; WGS84 ellipsoid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pymap3d
import scipy.stats
from scipy.signal import fftconvolve

from groundfloor.errors import InputError

OUTLIER_SIGMA = 4.0  # residuals above this many stated stds are left out of the refits
MAX_REFITS = 10
#: a fit of the fixes better at this significance (F test) than the one stamped or rotated: a mirror
#: image (a left-handed frame), another time (a time base other than the poses')
SIGNIFICANCE_P = 1e-6


@dataclass(frozen=True)
class GeodeticOrigin:
    """Origin of the east-north-up frame (WGS84 degrees, ellipsoidal height in metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @classmethod
    def from_yaml(cls, value, source: str) -> GeodeticOrigin:
        """Return the origin from a ``{lat_deg, lon_deg, alt_m}`` mapping; InputError naming ``source``."""
        keys = ("lat_deg", "lon_deg", "alt_m")
        if not isinstance(value, dict) or any(k not in value for k in keys):
            raise InputError(f"{source}: geodetic_origin needs keys {', '.join(keys)}")
        try:
            lat, lon, alt = (float(value[k]) for k in keys)
        except (TypeError, ValueError):
            raise InputError(f"{source}: geodetic_origin values must be numbers") from None
        if not (np.isfinite(alt) and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise InputError(f"{source}: geodetic_origin ({lat}, {lon}, {alt}) out of range")
        return cls(lat, lon, alt)

    def to_yaml(self) -> dict:
        """Return the origin as ``campaign.yaml`` writes it."""
        return {"lat_deg": float(self.lat_deg), "lon_deg": float(self.lon_deg), "alt_m": float(self.alt_m)}


@dataclass(frozen=True)
class EnuToLocal:
    """``p_local = Rz(yaw) p_enu + t_local``; ``cov`` of (yaw rad, tx, ty) when estimated."""

    yaw_rad: float
    t_local_m: np.ndarray  # (3,)
    cov: np.ndarray | None = None  # (3, 3) of yaw [rad], t_x, t_y [m]; None when given
    n_fixes: int = 0  # fixes the estimate rests on
    n_rejected: int = 0  # fixes left out as outliers
    sigma0: float = float("nan")  # a posteriori standard deviation of unit weight
    # the residuals' correlation time spans half a run or more (:func:`correlated_over_runs`): their
    # errors likely share a bias across runs too, which no block of the data shows, so ``cov`` may be
    # too small
    correlated_over_runs: bool = False

    @property
    def R(self) -> np.ndarray:
        """Return ``Rz(yaw)`` (3, 3)."""
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def apply(self, p_enu: np.ndarray) -> np.ndarray:
        """Return local positions (n, 3) of ENU positions (n, 3)."""
        return np.asarray(p_enu, float) @ self.R.T + self.t_local_m

    def inverse(self, p_local: np.ndarray) -> np.ndarray:
        """Return ENU positions (n, 3) of local positions (n, 3)."""
        return (np.asarray(p_local, float) - self.t_local_m) @ self.R

    def rotate_cov(self, cov_enu: np.ndarray) -> np.ndarray:
        """Return covariances (n, 3, 3) of ENU positions expressed in the local frame."""
        return self.R @ np.asarray(cov_enu, float) @ self.R.T

    def to_json_dict(self) -> dict:
        """Return the transform and its standard deviations as plain values."""
        out = {"enu_to_local_yaw_deg": float(np.degrees(self.yaw_rad)),
               "enu_to_local_t_m": [float(v) for v in self.t_local_m], "estimated": self.cov is not None}
        if self.cov is not None:
            sd = np.sqrt(np.diag(self.cov))
            out.update(yaw_std_deg=float(np.degrees(sd[0])), t_std_m=[float(sd[1]), float(sd[2])],
                       n_fixes=int(self.n_fixes), n_rejected=int(self.n_rejected), sigma0=float(self.sigma0),
                       errors_correlated_over_runs=bool(self.correlated_over_runs))
        return out


def geodetic_to_enu(lat_deg, lon_deg, alt_m, origin: GeodeticOrigin) -> np.ndarray:
    """Return ENU positions (n, 3) in metres of WGS84 fixes at ``origin`` (pymap3d)."""
    e, n, u = pymap3d.geodetic2enu(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                   np.asarray(alt_m, float), origin.lat_deg, origin.lon_deg, origin.alt_m)
    return np.column_stack([np.ravel(e), np.ravel(n), np.ravel(u)])


def enu_to_geodetic(p_enu: np.ndarray, origin: GeodeticOrigin) -> np.ndarray:
    """Return WGS84 ``lat_deg, lon_deg, alt_m`` (n, 3) of ENU positions (n, 3) (pymap3d)."""
    p = np.asarray(p_enu, float).reshape(-1, 3)
    lat, lon, alt = pymap3d.enu2geodetic(p[:, 0], p[:, 1], p[:, 2], origin.lat_deg, origin.lon_deg,
                                         origin.alt_m)
    return np.column_stack([lat, lon, alt])


def _fit(e: np.ndarray, loc: np.ndarray, w: np.ndarray) -> tuple[float, np.ndarray]:
    """Return the weighted 2-D Procrustes rotation and translation taking ``e`` onto ``loc``."""
    ce = (w[:, None] * e).sum(0) / w.sum()
    cl = (w[:, None] * loc).sum(0) / w.sum()
    a, b = e - ce, loc - cl
    yaw = np.arctan2(np.sum(w * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])), np.sum(w * (a * b).sum(1)))
    c, s = np.cos(yaw), np.sin(yaw)
    return float(yaw), cl - np.array([[c, -s], [s, c]]) @ ce


def median_residual(e: np.ndarray, loc: np.ndarray, w: np.ndarray) -> float:
    """Return the median horizontal residual, in stated stds, of the Procrustes fit of ``e`` onto ``loc``
    (``(n, 2)`` each, weights ``w`` the inverse variances)."""
    yaw, t2 = _fit(e, loc, w)
    c, s = np.cos(yaw), np.sin(yaw)
    res = e @ np.array([[c, -s], [s, c]]).T + t2 - loc
    return float(np.median(np.hypot(res[:, 0], res[:, 1]) * np.sqrt(w)))


def correlation_time(res: np.ndarray, groups: np.ndarray | None = None) -> float:
    """Return the integrated autocorrelation time of residual vectors ``res (n, d)`` in samples (>= 1):
    by how much their correlation in time inflates the variance of what is fitted to them.

    ``groups`` (n,) labels the independent stretches (runs), each in time order; none: one stretch.
    The autocorrelation is pooled over the stretches about zero, not about each stretch's mean
    (a receiver's bias that stays for a run is exactly the correlated part): ``rho_k`` is the mean
    of ``r_i . r_(i+k)`` over the pairs ``k`` apart within a stretch over the mean ``|r_i|^2``, and
    ``tau = 1 + 2 sum rho_k`` up to the first lag where ``rho_k`` is no longer positive (the initial
    positive sequence). White errors give 1; a bias of correlation time ``T`` sampled every
    ``dt`` gives about ``2 T / dt``. A fit's covariance from ``n`` such residuals is that of
    ``n / tau`` independent ones.
    """
    res = np.asarray(res, float).reshape(len(res), -1)
    groups = np.zeros(len(res), int) if groups is None else np.asarray(groups)
    parts = [res[groups == g] for g in dict.fromkeys(groups.tolist())]
    den = float(np.sum(res ** 2)) / max(len(res), 1)
    longest = max((len(p) for p in parts), default=0)
    if longest < 2 or not den > 0:
        return 1.0
    products, pairs = np.zeros(longest), np.zeros(longest)  # per lag 0 .. longest - 1, pooled over the runs
    for p in parts:  # the sums of r_i . r_(i+k) of a run at every lag at once (its autocorrelation by FFT)
        n = len(p)
        products[:n] += sum(fftconvolve(p[:, d], p[::-1, d])[n - 1:] for d in range(p.shape[1]))
        pairs[:n] += np.arange(n, 0, -1)
    rho = products[1:] / pairs[1:] / den
    stop = np.flatnonzero(~(rho > 0.0))
    return float(1.0 + 2.0 * rho[:stop[0] if stop.size else rho.size].sum())


def correlated_over_runs(tau: float, groups: np.ndarray) -> bool:
    """Return whether a correlation time of ``tau`` samples spans half the median run of ``groups``
    or more: errors that stay correlated over most of every run (a standalone receiver's bias,
    wandering over minutes) are likely correlated across runs as well, and then the runs are not
    the independent blocks :func:`block_covariance` takes them for."""
    sizes = np.unique(np.asarray(groups), return_counts=True)[1]
    return bool(sizes.size and tau >= 0.5 * float(np.median(sizes)))


def block_covariance(J: np.ndarray, r: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, int]:
    """Return the cluster-robust covariance of a least-squares estimate, ``H^-1 S H^-1 G / (G - 1)``
    with ``H = J^T J`` and ``S`` the sum over the ``G`` blocks of the outer products of their score
    ``J_b^T r_b``, and ``G``.

    ``J (m, p)`` and ``r (m,)`` are the weighted Jacobian and residuals, ``blocks (m,)`` the block of
    each row. Errors correlated within a block and independent between blocks are then counted as
    what they are: a bias that stays for a block moves only the parameters its rows' Jacobian
    projects it on (a constant offset over a run moves a translation, hardly a rotation about the
    run's centre), where inflating every variance by the correlation time would overstate them all.
    """
    H_inv = np.linalg.pinv(J.T @ J)
    labels, idx = np.unique(blocks, return_inverse=True)
    score = np.zeros((len(labels), J.shape[1]))
    np.add.at(score, idx, J * r[:, None])
    G = len(labels)
    return H_inv @ (score.T @ score) @ H_inv * (G / max(G - 1, 1)), G


def widened(cov: np.ndarray, robust: np.ndarray) -> np.ndarray:
    """Return ``cov`` with each parameter's variance raised to ``robust``'s where that is larger (its
    correlations kept: ``D cov D``, ``D`` the diagonal of the ratios' square roots, at least 1). A
    cluster-robust covariance from a few blocks is noisy; it may widen a stated uncertainty, never
    narrow the model's."""
    d = np.sqrt(np.maximum(np.diag(robust) / np.maximum(np.diag(cov), 1e-300), 1.0))
    return cov * np.outer(d, d)


def time_blocks(groups: np.ndarray, length: int) -> np.ndarray:
    """Return a block label per sample: consecutive samples of each group (run, in time order) cut
    into blocks of ``length`` samples (the last of a group may be shorter)."""
    groups = np.asarray(groups)
    out = np.empty(len(groups), int)
    start = 0
    for g in dict.fromkeys(groups.tolist()):
        where = np.flatnonzero(groups == g)
        out[where] = start + np.arange(len(where)) // max(int(length), 1)
        start = int(out[where].max()) + 1 if len(where) else start
    return out


def estimate_enu_to_local(p_enu: np.ndarray, p_local: np.ndarray, std_m: np.ndarray,
                          source: str = "GNSS", groups: np.ndarray | None = None) -> EnuToLocal:
    """Return the ENU -> local transform fitted to fixes and true antenna positions, with its covariance.

    Weighted least squares over the horizontal plane (weights from the fixes' stated horizontal
    std), in closed form (2-D Procrustes), refitted without residuals above
    :data:`OUTLIER_SIGMA` stated stds (multipath) until the set kept no longer changes. The vertical offset is the weighted mean of
    ``local z - up``. The covariance of (yaw, t_x, t_y) is the Gauss-Newton one,
    ``sigma0^2 (J^T W J)^-1`` with the a posteriori variance factor ``sigma0^2``, widened to the
    cluster-robust one over blocks of each run as long as the residuals' :func:`correlation_time`
    where that is larger (:func:`block_covariance`, :func:`widened`): a receiver's errors wander (a
    standalone fix's bias over minutes). A bias shared across runs shows in no block (a simulated
    standalone campaign's yaw stayed 3.8 of its stated stds off): ``correlated_over_runs`` then says
    that the stated uncertainty may be too small (:func:`correlated_over_runs`).

    Parameters
    ----------
    p_enu, p_local : (n, 3) the same antenna positions as fixes (ENU) and from the ground truth.
    std_m : (n,) stated horizontal std of each fix.
    groups : (n,) the run of each fix (fixes of a run in time order); none: one run.
    """
    p_enu, p_local = np.asarray(p_enu, float), np.asarray(p_local, float)
    groups = np.zeros(len(p_enu), int) if groups is None else np.asarray(groups)
    w = 1.0 / np.asarray(std_m, float) ** 2
    ok = np.all(np.isfinite(p_enu), 1) & np.all(np.isfinite(p_local[:, :2]), 1) & np.isfinite(w) & (w > 0)
    if ok.sum() < 3:
        raise InputError(f"{source}: fewer than 3 fixes beside ground truth to estimate the ENU -> local transform")
    e, loc, w, groups = p_enu[ok], p_local[ok], w[ok], groups[ok]
    if np.linalg.norm(e[:, :2] - e[:, :2].mean(0), axis=1).max() < 1.0:
        raise InputError(f"{source}: the antenna moved less than 1 m; ENU -> local yaw not observable")
    # a left-handed local frame (north-east-down, or y or yaw negated) is no rotation of ENU: the best
    # rotation then leaves residuals of the size of the trajectory, its mirror image fits
    # (squared median residuals compared by an F test, conservatively on one degree of freedom per fix)
    rotated, mirrored = (median_residual(e[:, :2] * [1.0, sign], loc[:, :2], w) for sign in (1.0, -1.0))
    if significantly_better(rotated, mirrored, len(e)):
        raise InputError(f"{source}: the local frame is mirrored against east-north-up (left-handed, e.g. x north and "
                         f"y east as NED, or y and yaw negated): the best rotation leaves a median residual of "
                         f"{rotated:.3g} stated stds, the mirror image {mirrored:.3g}; the data contract's local "
                         "frame is right-handed, z up")
    keep = np.ones(len(e), bool)
    for _ in range(MAX_REFITS):
        yaw, t2 = _fit(e[keep, :2], loc[keep, :2], w[keep])
        c, s = np.cos(yaw), np.sin(yaw)
        res = e[:, :2] @ np.array([[c, -s], [s, c]]).T + t2 - loc[:, :2]
        norm = np.hypot(res[:, 0], res[:, 1]) * np.sqrt(w)  # in stated stds
        # a fit pulled by outliers has large residuals everywhere: the threshold shrinks from
        # three median residuals to OUTLIER_SIGMA stated stds as the refits clean it up
        new = norm < max(OUTLIER_SIGMA * np.sqrt(2.0), 3.0 * float(np.median(norm[keep])))
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    r = res[keep].ravel()
    wk = np.repeat(w[keep], 2)
    dof = max(r.size - 3, 1)
    sigma0 = float(np.sqrt(np.sum(wk * r ** 2) / dof))
    ek = e[keep, :2]
    J = np.zeros((ek.shape[0], 2, 3))
    J[:, 0, 0] = -s * ek[:, 0] - c * ek[:, 1]
    J[:, 1, 0] = c * ek[:, 0] - s * ek[:, 1]
    J[:, 0, 1] = J[:, 1, 2] = 1.0
    J = J.reshape(-1, 3)
    cov = sigma0 ** 2 * np.linalg.inv(J.T @ (wk[:, None] * J))
    rw = res[keep] * np.sqrt(w[keep])[:, None]
    tau = correlation_time(rw, groups[keep])
    blocks = np.repeat(time_blocks(groups[keep], int(np.ceil(tau))), 2)
    cov = widened(cov, block_covariance(J * np.sqrt(wk)[:, None], rw.ravel(), blocks)[0])
    finite_z = keep & np.isfinite(loc[:, 2]) & np.isfinite(e[:, 2])
    tz = float(np.average(loc[finite_z, 2] - e[finite_z, 2], weights=w[finite_z])) if finite_z.any() else 0.0
    return EnuToLocal(yaw, np.array([t2[0], t2[1], tz]), cov, int(keep.sum()), int((~keep).sum()), sigma0,
                      correlated_over_runs(tau, groups[keep]))


def significantly_better(worse: float, better: float, n: int, p: float = SIGNIFICANCE_P) -> bool:
    """Return whether a fit of median residual ``better`` beats one of ``worse`` on ``n`` fixes at
    significance ``p`` (an F test of the squared medians, conservatively on ``n - 3`` degrees of freedom)."""
    dof = max(n - 3, 1)
    return (worse / max(better, 1e-12)) ** 2 > scipy.stats.f.ppf(1.0 - p, dof, dof)
