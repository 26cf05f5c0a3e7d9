"""Scores of the estimators against the laser-tracker poses: ATE, error through outages, NEES, NIS.

At the pose times (the estimation grid holds them, so no interpolation): ATE of position and
heading (RMS over all test-run poses; no alignment: truth and estimates share the local
frame), position and heading error against the time since each scheduled outage began (each
estimator enters the outage from its own state; RMS over outages of equal length, as eq. 5.77),
NEES of the pose (3 dof) and NIS of the fixes (2 dof) with their chi-square bounds.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from groundfloor.angles import wrap_angle
from groundfloor.errors import InputError
from sindy_ekf.benchmark.result import BenchmarkResult, Estimate, Score

OUTAGE_TAU_STEP_S = 0.1


def pose_truth(poses) -> tuple[np.ndarray, np.ndarray | None]:
    """Return the truth ``(n, 4)`` [t, x, y, yaw unwrapped] at the poses whose t, x, y and yaw are all
    finite, and the height of the body origin there (None when the poses have no z)."""
    ok = np.isfinite(poses.t) & np.isfinite(poses.x) & np.isfinite(poses.y) & np.isfinite(poses.yaw)
    truth = np.column_stack([np.asarray(poses.t, float)[ok], np.asarray(poses.x, float)[ok],
                             np.asarray(poses.y, float)[ok], np.unwrap(np.asarray(poses.yaw, float)[ok])])
    return truth, (np.asarray(poses.z, float)[ok] if poses.z is not None else None)


def chi2_bounds_95(dof: int) -> tuple[float, float]:
    """Return the per-sample two-sided 95 % bounds of a chi-square variable with ``dof`` degrees."""
    lo, hi = chi2.ppf([0.025, 0.975], dof)
    return float(lo), float(hi)


def pose_error(e: Estimate, truth: np.ndarray) -> np.ndarray:
    """Return ``(n, 3)`` errors ``[dx, dy, dyaw]`` of an estimate against ``truth`` ``[t, x, y, yaw]`` (yaw wrapped).

    A diverged estimator's estimate stops early (:mod:`sindy_ekf.benchmark.health`): its ``n``
    poses are the first ``n`` of the truth.
    """
    truth = truth[:len(e.x)]
    return np.column_stack([e.x[:, 0] - truth[:, 1], e.x[:, 1] - truth[:, 2], wrap_angle(e.x[:, 2] - truth[:, 3])])


def nees_of(err: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the poses with a covariance (bool ``(n,)``) and the pose NEES there (3 dof).

    ``err`` are :func:`pose_error` rows, ``P`` the ``(n, 6, 6)`` covariances (NaN where none);
    solving instead of inverting keeps a nearly singular covariance accurate.
    """
    Pp = P[:, :3, :3]
    has = np.all(np.isfinite(Pp), axis=(1, 2))
    if not has.any():
        return has, np.empty(0)
    return has, np.einsum("ni,ni->n", err[has], np.linalg.solve(Pp[has], err[has][..., None])[..., 0])


def score_estimator(estimates: dict[str, Estimate], truth: dict[str, np.ndarray], outages: dict[str, np.ndarray],
                    runtime_s: float) -> tuple[Score, dict[str, np.ndarray]]:
    """Return the scores of one estimator over the test runs and its error-against-outage-time curves.

    Parameters
    ----------
    estimates : run -> the estimator's :class:`Estimate` at the pose times.
    truth : run -> ``(n, 4)`` ``[t, x, y, yaw]`` at the same times.
    outages : run -> ``(m, 2)`` scheduled outages ``[begin, end]``, s.
    runtime_s : the estimator's computing time over all runs.

    The curves map the outage length (s, as text) to ``(k, 3)`` ``[tau, RMS position error m,
    RMS heading error deg]`` against the time since the outage began (eqs. 5.77, 5.78 over the
    outages of that length).
    """
    d_pos, d_yaw, nees, nis = [], [], [], []
    curves: dict[str, list] = {}
    for run, tr in truth.items():
        e = estimates[run]
        err = pose_error(e, tr)
        dp = np.hypot(err[:, 0], err[:, 1])
        d_pos.append(dp)
        d_yaw.append(err[:, 2])
        has, nees_run = nees_of(err, e.P)
        if has.any():
            nees.append(nees_run)
        nis.append(e.nis)
        for a, b in outages[run]:
            key = f"{b - a:g}"
            tau = np.arange(0.0, b - a + 1e-9, OUTAGE_TAU_STEP_S)
            curves.setdefault(key, []).append(np.column_stack([
                np.interp(a + tau, tr[:, 0], dp), np.interp(a + tau, tr[:, 0], np.abs(err[:, 2]))]))
    d_pos, d_yaw = np.concatenate(d_pos), np.concatenate(d_yaw)
    nees = np.concatenate(nees) if nees else np.empty(0)
    nis = np.concatenate(nis) if nis else np.empty(0)
    lo3, hi3 = chi2_bounds_95(3)
    lo2, hi2 = chi2_bounds_95(2)
    rms_curves = {}
    for key, cs in curves.items():
        c = np.sqrt(np.mean(np.stack(cs) ** 2, axis=0))  # eqs. 5.77, 5.78 over the outages
        tau = np.arange(len(c)) * OUTAGE_TAU_STEP_S
        rms_curves[key] = np.column_stack([tau, c[:, 0], np.degrees(c[:, 1])])
    ends = sorted(rms_curves.items(), key=lambda kv: float(kv[0]))
    duration = sum(tr[-1, 0] - tr[0, 0] for tr in truth.values())
    score = Score(
        ate_pos_m=float(np.sqrt(np.mean(d_pos ** 2))),
        ate_yaw_deg=float(np.degrees(np.sqrt(np.mean(d_yaw ** 2)))),
        outage_pos_err_m={k: float(v[-1, 1]) for k, v in ends},
        outage_yaw_err_deg={k: float(v[-1, 2]) for k, v in ends},
        nees_mean=float(np.mean(nees)) if nees.size else float("nan"),
        nees_inside_95=float(np.mean((nees >= lo3) & (nees <= hi3))) if nees.size else float("nan"),
        nis_mean=float(np.mean(nis)) if nis.size else float("nan"),
        nis_inside_95=float(np.mean((nis >= lo2) & (nis <= hi2))) if nis.size else float("nan"),
        runtime_s=float(runtime_s), realtime_factor=float(duration / max(runtime_s, 1e-9)))
    return score, rms_curves


def ate(ref: np.ndarray, est: np.ndarray, max_diff_s: float = 0.01) -> tuple[float, float]:
    """Return ``(ATE position m, ATE heading deg)`` of ``est`` against ``ref`` (both ``[t, x, y, yaw]``).

    Stamps are associated like evo's ``associate_trajectories`` (nearest reference stamp within
    ``max_diff_s``), no alignment; position 2-D, heading as the wrapped yaw difference.
    """
    i = np.clip(np.searchsorted(ref[:, 0], est[:, 0]), 1, len(ref) - 1)
    left_closer = np.abs(est[:, 0] - ref[i - 1, 0]) <= np.abs(ref[i, 0] - est[:, 0])
    i = np.where(left_closer, i - 1, i)
    ok = np.abs(ref[i, 0] - est[:, 0]) <= max_diff_s
    if not ok.any():
        raise InputError("ATE: no estimate stamp within max_diff of a reference stamp")
    d = est[ok, 1:3] - ref[i[ok], 1:3]
    dyaw = wrap_angle(est[ok, 3] - ref[i[ok], 3])
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))), float(np.degrees(np.sqrt(np.mean(dyaw ** 2))))


def pose_nees(result: BenchmarkResult, run: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Return ``{estimator: (t since the run's first pose s, pose NEES)}`` of one test run.

    The NEES of ``(x, y, yaw)`` (3 dof) at every pose where the estimator gives a covariance;
    estimators with fewer than two such poses (dead reckoning) are left out.
    """
    tr = result.truth[run]
    out = {}
    for name, per_run in result.estimates.items():
        e = per_run[run]  # a diverged estimator's stops early (sindy_ekf.benchmark.health)
        has, nees = nees_of(pose_error(e, tr), e.P)
        if has.sum() < 2:
            continue
        out[name] = (e.t[has] - tr[0, 0], nees)
    return out
