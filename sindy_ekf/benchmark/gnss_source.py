"""Recorded GNSS for the benchmark (``benchmark --gnss recorded``, issue 16).

The campaign's own fixes (``runs/<run>/gnss.csv`` of a trajectory campaign, written by
``preprocess`` from a ``sensor_msgs/NavSatFix`` topic or by a user) replace the simulated ones:
NO_FIX and non-finite fixes dropped and counted, WGS84 -> ENU at the campaign's
``geodetic_origin`` (pymap3d; the first fix when none is given), ENU -> local either as
``campaign.yaml`` gives it or estimated from the ground-truth poses over the first
:data:`ESTIMATE_WINDOW_S` of every run (:func:`groundfloor.geodetic.estimate_enu_to_local`,
reported with its uncertainty). Each fix keeps its stated covariance (rotated into the local
frame); the filters gate them as they gate simulated fixes. Outage experiments drop the recorded
fixes whose time of validity falls in a scheduled outage.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.stats

from groundfloor.errors import InputError
from groundfloor.geodetic import (
    SIGNIFICANCE_P,
    EnuToLocal,
    GeodeticOrigin,
    block_covariance,
    correlation_time,
    estimate_enu_to_local,
    geodetic_to_enu,
    median_residual,
    significantly_better,
    time_blocks,
    widened,
)
from groundfloor.gnss import GnssSeries
from identification.preprocessing.io_sensors import (
    GNSS,
    GNSS_CSV,
    GnssFixes,
    clean_fixes,
    overlapping,
    read_gnss_csv,
    read_sensors_config,
)

log = logging.getLogger(__name__)

RECORDED = "recorded"
ESTIMATE_WINDOW_S = 60.0  # seconds of each run's start the ENU -> local estimate rests on
#: time shifts of the fixes against the poses scored by :func:`check_time_base` (s), and the shift
#: below which a better fit is a receiver's latency (0.1 to 0.2 s on the simulated receivers), not a time base
OFFSET_GRID_S = np.round(np.arange(-30.0, 30.0 + 1e-9, 0.25), 2)
MIN_TIME_OFFSET_S = 1.0
#: a lever arm the fixes give this far from the declared one is named (below the dgnss profile's 0.3 m noise)
MIN_LEVER_DIFF_M = 0.1
#: residuals beyond this many stated stds weigh less in the lever-arm fit (multipath)
OUTLIER_STDS = 4.0


@dataclass(frozen=True)
class RecordedGnss:
    """A campaign's recorded fixes per run, with the frame they are taken into the local frame by."""

    origin: GeodeticOrigin
    transform: EnuToLocal
    lever_arm_body_m: np.ndarray  # (3,)
    fixes: dict[str, GnssFixes]  # run -> cleaned fixes inside its poses' span
    counts: dict[str, dict[str, int]]  # run -> fixes read, NO_FIX / NaN / duplicates dropped
    lever_arm_fit: dict | None = None  # the horizontal lever arm the fixes give (check_lever_arm), None if too few

    def series(self, run: str, outages: np.ndarray) -> GnssSeries:
        """Return the run's fixes in the local frame as the filters take them, none inside ``outages``.

        Raises
        ------
        InputError
            The run has no recorded fix (names the run and the file).
        """
        if run not in self.fixes:
            raise InputError(f"run {run}: no {GNSS_CSV} for --gnss recorded")
        f = self.fixes[run]
        p_local = self.transform.apply(geodetic_to_enu(f.lla[:, 0], f.lla[:, 1], f.lla[:, 2], self.origin))
        std = np.sqrt(np.diagonal(self.transform.rotate_cov(f.cov_enu), axis1=1, axis2=2))
        outages = np.asarray(outages, float).reshape(-1, 2)
        keep = ~np.any((f.t[:, None] >= outages[:, 0]) & (f.t[:, None] < outages[:, 1]), axis=1)
        return GnssSeries(RECORDED, f.t[keep], np.maximum(f.t_arrival[keep], f.t[keep]), p_local[keep], std[keep],
                          np.zeros(int(keep.sum()), np.uint8), self.lever_arm_body_m, outages)

    def to_json_dict(self) -> dict:
        """Return the origin, the transform (with its std when estimated) and the counts per run."""
        return {"origin": self.origin.to_yaml(), "enu_to_local": self.transform.to_json_dict(),
                "lever_arm_body_m": [float(v) for v in self.lever_arm_body_m], "runs": self.counts,
                "lever_arm_fit": self.lever_arm_fit}


def antenna_local(poses, t: np.ndarray, lever_arm_body_m: np.ndarray) -> np.ndarray:
    """Return the true antenna positions (n, 3) at ``t`` from the poses (z NaN where unknown)."""
    tp = np.asarray(poses.t, float)
    ok = np.isfinite(tp) & np.isfinite(poses.x) & np.isfinite(poses.y) & np.isfinite(poses.yaw)
    tp = tp[ok]
    yaw = np.interp(t, tp, np.unwrap(np.asarray(poses.yaw, float)[ok]))
    z = np.asarray(poses.z, float)[ok] if poses.z is not None else np.full(tp.size, np.nan)
    c, s = np.cos(yaw), np.sin(yaw)
    lx, ly, lz = lever_arm_body_m
    return np.column_stack([np.interp(t, tp, np.asarray(poses.x, float)[ok]) + c * lx - s * ly,
                            np.interp(t, tp, np.asarray(poses.y, float)[ok]) + s * lx + c * ly,
                            np.interp(t, tp, z) + lz])


def with_covariance(fixes: GnssFixes, counts: dict, source: str) -> tuple[GnssFixes, dict]:
    """Return the fixes that state a positive horizontal covariance, the others dropped and counted
    (``no_covariance_dropped``; a NavSatFix of covariance type UNKNOWN carries zeros), with a warning;
    an InputError naming ``source`` when none does."""
    var = np.stack([fixes.cov_enu[:, 0, 0], fixes.cov_enu[:, 1, 1]], axis=1)
    none = ~np.all(var > 0, axis=1)
    if none.size and none.all():
        raise InputError(f"{source}: no fix states its covariance (all zero: a NavSatFix of covariance type UNKNOWN?); "
                         "the filters weigh each fix by it: give std_e,std_n,std_u (m) in it")
    counts = {**counts, "no_covariance_dropped": int(none.sum())}
    if none.any():
        log.warning("%s: %d of %d fixes state no horizontal covariance (zero); left out", source, none.sum(), len(none))
    return fixes.select(~none), counts


def check_time_base(campaign, fixes: dict[str, GnssFixes], origin: GeodeticOrigin, lever: np.ndarray,
                    source: str) -> None:
    """Raise a one-line InputError when the fixes fit the ground truth significantly better at
    another time than their own, by more than :data:`MIN_TIME_OFFSET_S`: a ``t`` on another time base
    than the poses' (GPS time, 18 s ahead of UTC; a receiver's clock; the arrival time of a late log).

    Each shift of :data:`OFFSET_GRID_S` is scored by the median residual of the best ENU -> local
    rotation of the fixes whose shifted time lies inside their run against the true antenna
    positions at ``t + shift`` (at least 20 fixes, and, but for the stamps as they are, at least half
    as many as at the shift that keeps the most inside; as stamped fewer than 20 with a shift that has
    enough is another time base by itself). Of the shifts that fit about as well as the best
    (a track driven round and round fits again a lap later), the one nearest the stamps is taken,
    and refused where the stamps themselves fit significantly worse (the F test of
    :func:`groundfloor.geodetic.significantly_better`, on the fewer of the two sets). A robot standing
    still or driving straight cannot tell a shift and passes.
    """
    parts = [(run.poses, fixes[run.name]) for run in campaign.runs if run.name in fixes]
    enu = [geodetic_to_enu(f.lla[:, 0], f.lla[:, 1], f.lla[:, 2], origin)[:, :2] for _, f in parts]
    w = [2.0 / (f.cov_enu[:, 0, 0] + f.cov_enu[:, 1, 1]) for _, f in parts]
    scores = []
    for shift in OFFSET_GRID_S:
        inside = [(f.t + shift >= p.t[0]) & (f.t + shift <= p.t[-1]) for p, f in parts]
        n = int(sum(k.sum() for k in inside))
        if n < 20:
            scores.append((np.inf, n))
            continue
        local = np.concatenate([antenna_local(p, f.t[k] + shift, lever)[:, :2] for (p, f), k in zip(parts, inside)])
        scores.append((median_residual(np.concatenate([e[k] for e, k in zip(enu, inside)]), local,
                                       np.concatenate([wk[k] for wk, k in zip(w, inside)])), n))
    # shifts that keep fewer than half of the most fixes inside their runs are not compared: a median
    # over a few fixes at the edge of a run can fall low by chance
    # (the stamps as they are always are, on their own fixes)
    counts = np.array([n for _, n in scores])
    zero = int(np.argmin(np.abs(OFFSET_GRID_S)))
    residual = np.where((counts >= 0.5 * counts.max()) | (np.arange(counts.size) == zero), [r for r, _ in scores], np.inf)
    best = int(np.argmin(residual))
    if not np.isfinite(residual[best]):
        return
    if not np.isfinite(residual[zero]):  # as stamped, fewer than 20 fixes fall inside their runs' poses
        shift = float(OFFSET_GRID_S[best])
        raise InputError(f"{source}: as stamped, {scores[zero][1]} fixes fall inside their runs' poses, {scores[best][1]} "
                         f"at their stamps {shift:+.2f} s (median residual {residual[best]:.3g} stated stds there): t of "
                         f"{GNSS_CSV} (the NavSatFix header stamp) must be on the poses' time base"
                         + ("; GPS time runs 18 s ahead of UTC" if abs(abs(shift) - 18.0) < 1.0 else ""))
    # of the shifts that fit about as well as the best (a track driven round and round repeats itself),
    # the nearest to the stamps, then the best within a second of it
    near = next(i for i in np.argsort(np.abs(OFFSET_GRID_S), kind="stable") if np.isfinite(residual[i])
                and not significantly_better(float(residual[i]), float(residual[best]), scores[best][1]))
    around = np.flatnonzero(np.abs(OFFSET_GRID_S - OFFSET_GRID_S[near]) <= 1.0)
    best = int(around[np.argmin(residual[around])])
    shift, n = float(OFFSET_GRID_S[best]), min(scores[best][1], scores[zero][1])
    if abs(shift) > MIN_TIME_OFFSET_S and significantly_better(float(residual[zero]), float(residual[best]), n):
        leap = "; GPS time runs 18 s ahead of UTC" if abs(abs(shift) - 18.0) < 1.0 else ""
        raise InputError(f"{source}: the fixes fit the ground truth best at their stamps {shift:+.2f} s (median "
                         f"residual {residual[best]:.3g} stated stds there, {residual[zero]:.3g} as stamped): t of "
                         f"{GNSS_CSV} (the NavSatFix header stamp) must be on the poses' time base{leap}")


def fit_lever_arm(poses_and_fixes, origin: GeodeticOrigin, lever: np.ndarray, start: EnuToLocal
                  ) -> tuple[np.ndarray, np.ndarray, int]:
    """Return the horizontal antenna lever arm (body x, y, m) that fits the fixes best, its
    covariance (m^2) and the number of fixes.

    ``poses_and_fixes``: ``(poses, fixes)`` per run. Least squares over the ENU -> local rotation,
    translation and the lever arm (the fix ``R e + t`` against the body origin plus the lever arm
    turned by the heading), started from the ENU -> local transform ``start`` (the benchmark's, given or
    estimated at ``lever``) and ``lever``."""
    from scipy.optimize import least_squares

    e, body, yaw, w, run = [], [], [], [], []
    for k, (poses, f) in enumerate(poses_and_fixes):
        e.append(geodetic_to_enu(f.lla[:, 0], f.lla[:, 1], f.lla[:, 2], origin)[:, :2])
        body.append(antenna_local(poses, f.t, np.zeros(3))[:, :2])
        tp = np.asarray(poses.t, float)
        yaw.append(np.interp(f.t, tp, np.unwrap(np.asarray(poses.yaw, float))))
        w.append(2.0 / (f.cov_enu[:, 0, 0] + f.cov_enu[:, 1, 1]))
        run.append(np.full(len(f.t), k))
    e, body, yaw, w, run = (np.concatenate(v) for v in (e, body, yaw, w, run))
    ok = np.all(np.isfinite(e), 1) & np.all(np.isfinite(body), 1) & np.isfinite(yaw) & np.isfinite(w)
    e, body, yaw, sw, run = e[ok], body[ok], yaw[ok], np.sqrt(w[ok]), run[ok]
    c, s_ = np.cos(yaw), np.sin(yaw)

    def antenna(l):
        return body + np.column_stack([c * l[0] - s_ * l[1], s_ * l[0] + c * l[1]])

    def residual(x):
        cr, sr = np.cos(x[0]), np.sin(x[0])
        fix = e @ np.array([[cr, -sr], [sr, cr]]).T + x[1:3]
        return ((fix - antenna(x[3:5])) * sw[:, None]).ravel()

    x0 = np.concatenate([[start.yaw_rad], np.asarray(start.t_local_m, float)[:2], np.asarray(lever, float)[:2]])
    sol = least_squares(residual, x0, loss="soft_l1", f_scale=OUTLIER_STDS)
    # the lever arm's covariance: Gauss-Newton with its variance factor from the residuals and at most one
    # independent fix a second (a receiver's errors are correlated over seconds), widened to the
    # cluster-robust one over blocks of each run at least as long as the residuals' correlation time
    # (a standalone receiver's bias wanders for minutes and, moving with where the run drives, turns
    # into a lever arm: a simulated standalone campaign's came out 3 and 6 of its Gauss-Newton stds off)
    J = sol.jac
    dof = max(J.shape[0] - J.shape[1], 1)
    seconds = sum(float(np.ptp(f.t)) for _, f in poses_and_fixes if len(f.t) > 1)
    per_second = max(len(e) / max(seconds, 1.0), 1.0)
    cov = np.linalg.pinv(J.T @ J) * (np.sum(sol.fun ** 2) / dof) * per_second
    r = sol.fun.reshape(-1, 2)
    r = r * np.minimum(1.0, OUTLIER_STDS / np.maximum(np.hypot(r[:, 0], r[:, 1]), 1e-300))[:, None]  # multipath capped
    length = int(np.ceil(max(correlation_time(r, run), per_second)))
    cov = widened(cov, block_covariance(J, r.ravel(), np.repeat(time_blocks(run, length), 2))[0])
    return sol.x[3:5], cov[3:5, 3:5], int(len(e))


def check_lever_arm(campaign, fixes: dict[str, GnssFixes], origin: GeodeticOrigin, lever: np.ndarray,
                    transform: EnuToLocal, source: str) -> dict | None:
    """Warn when the fixes give a horizontal antenna lever arm significantly (chi-square at
    :data:`~groundfloor.geodetic.SIGNIFICANCE_P`) and more than :data:`MIN_LEVER_DIFF_M` away from the declared one (``sensors:`` ``lever_arm_body_m`` in
    ``campaign.yaml``, zero without), naming the one the data give: an antenna off the body origin
    moves around it in every turn, which no ENU -> local transform absorbs. Return the fit
    (``estimated_m``, ``std_m``, ``declared_m``, ``differs``), None with fewer than 20 fixes."""
    parts = [(run.poses, fixes[run.name]) for run in campaign.runs if run.name in fixes]
    if sum(len(f.t) for _, f in parts) < 20:
        return None
    est, cov, _ = fit_lever_arm(parts, origin, lever, transform)
    d = est - np.asarray(lever, float)[:2]
    sd = np.sqrt(np.diag(cov))
    differs = bool(np.hypot(*d) > MIN_LEVER_DIFF_M and float(d @ np.linalg.pinv(cov) @ d)
                   > scipy.stats.chi2.isf(SIGNIFICANCE_P, 2))
    if differs:
        log.warning("%s: the fixes put the antenna at (%.2f +- %.2f, %.2f +- %.2f) m in the body frame, not at the declared "
                    "(%.2f, %.2f) m: declare it as lever_arm_body_m of the gnss sensor in campaign.yaml (an antenna off "
                    "the body origin swings around it in every turn, which the filters would read as error)", source,
                    est[0], sd[0], est[1], sd[1], *np.asarray(lever, float)[:2])
    return {"estimated_m": [float(v) for v in est], "std_m": [float(v) for v in sd],
            "declared_m": [float(v) for v in np.asarray(lever, float)[:2]], "differs": differs}


def load_recorded_gnss(campaign, window_s: float = ESTIMATE_WINDOW_S) -> RecordedGnss:
    """Return the recorded GNSS of a trajectory campaign, the ENU -> local transform given or estimated.

    Raises
    ------
    InputError
        No test run with a ``gnss.csv``; fixes on another time base than the poses
        (:func:`check_time_base`); a ``gnss.csv`` without a fix inside its run's poses (names the
        file); a bad sensor declaration in ``campaign.yaml``; too little motion to estimate the
        transform; a mirrored local frame.
    """
    root = campaign.root
    config = read_sensors_config(root)
    spec = config.first(GNSS)
    lever = np.asarray(spec.lever_arm_body_m if spec is not None else (0.0, 0.0, 0.0), float)
    fixes, counts = {}, {}
    for run in campaign.runs:
        path = root / "runs" / run.name / GNSS_CSV
        if not path.is_file():
            continue
        fixes[run.name], counts[run.name] = with_covariance(*clean_fixes(read_gnss_csv(path), str(path)), str(path))
    if not any(r.name in fixes for r in campaign.split("test")):
        raise InputError(f"{root}: --gnss recorded needs runs/<run>/{GNSS_CSV} in the test runs (none found)")

    # the time base first: fixes stamped on another clock may miss a short run's poses altogether
    check_time_base(campaign, fixes, config.origin or GeodeticOrigin(*(float(v) for v in next(iter(fixes.values())).lla[0])),
                    lever, f"{root}: GNSS")
    fixes = {name: overlapping(f, next(r.poses.t for r in campaign.runs if r.name == name),
                               str(root / "runs" / name / GNSS_CSV)) for name, f in fixes.items()}
    first = fixes[next(iter(fixes))]
    origin = config.origin or GeodeticOrigin(*(float(v) for v in first.lla[0]))
    if config.enu_to_local_yaw_deg is not None:
        transform = EnuToLocal(float(np.radians(config.enu_to_local_yaw_deg)), np.asarray(config.enu_to_local_t_m))
    else:
        enu, local, std, group = [], [], [], []
        for run in campaign.runs:
            if run.name not in fixes:
                continue
            f = fixes[run.name]
            f = f.select(f.t <= f.t[0] + window_s)
            enu.append(geodetic_to_enu(f.lla[:, 0], f.lla[:, 1], f.lla[:, 2], origin))
            local.append(antenna_local(run.poses, f.t, lever))
            std.append(np.sqrt(0.5 * (f.cov_enu[:, 0, 0] + f.cov_enu[:, 1, 1])))
            group.append(np.full(len(f.t), len(group)))
        transform = estimate_enu_to_local(np.concatenate(enu), np.concatenate(local), np.concatenate(std),
                                          f"{root}: GNSS", np.concatenate(group))
        sd = np.sqrt(np.diag(transform.cov))
        if transform.correlated_over_runs:
            log.warning("%s: GNSS: the fixes' errors stay correlated over most of every run (a receiver bias that "
                        "wanders for minutes), so they likely share it across runs too: the ENU -> local transform "
                        "estimated from them (yaw %.2f +- %.2f deg) may be off by more than its stated uncertainty; "
                        "give enu_to_local_yaw_deg and enu_to_local_t_m in campaign.yaml if they are known",
                        root, np.degrees(transform.yaw_rad), np.degrees(sd[0]))
        log.info("ENU -> local estimated from %d fixes: yaw %.3f +- %.3f deg, t (%.3f, %.3f) +- (%.3f, %.3f) m",
                 transform.n_fixes, np.degrees(transform.yaw_rad), np.degrees(sd[0]), *transform.t_local_m[:2],
                 sd[1], sd[2])
    lever_fit = check_lever_arm(campaign, fixes, origin, lever, transform, f"{root}: GNSS")
    return RecordedGnss(origin, transform, lever, fixes, counts, lever_fit)
