"""Recorded IMU gyro and wheel odometry for the benchmark's EKFs (issue 16 item 2).

An estimator whose ``sensors:`` (``sindy_ekf/data/filters.yaml``) hold ``imu`` and/or
``odometry`` runs :func:`sindy_ekf.estimation.ekf_motion.run_ekf_motion` on each test run, with the
run's ``imu.csv`` / ``odometry.csv`` of the trajectory campaign (written by ``preprocess`` from the
declared topics, or by a user; read by :mod:`identification.preprocessing.io_motion`: non-finite
rows dropped and counted, samples outside the poses cut, none inside an error naming the file).
Gyro and odometry keep coming through the scheduled GNSS outages: only the fixes drop out. A
factor graph (``sindy_graph``, ``sindy_graph_lateral``) with them runs
:func:`sindy_ekf.estimation.graph_motion.smooth_batch_motion`, started from its EKF's estimate;
``sindy_isam2`` runs :func:`sindy_ekf.estimation.graph_motion.smooth_isam2_motion`.
What the filter and the graph assume of the sensors is the estimator's ``imu`` and ``odometry``
settings (:class:`~sindy_ekf.estimation.ekf_motion.GyroNoise`, ``OdometryNoise``). The NIS
monitor of the six-state EKFs (:mod:`sindy_ekf.benchmark.health`) watches this filter too, with its
step test, but does not re-initialise it: an alarm that is no step of the fixes ends the run as
``diverged`` there (before, a filter that had lost the fixes and gated 60 % of them was reported
``ok``: lag_ekf fusing the gyro on a simulated rtk campaign, 0.78 m ATE, NIS mean 112).
"""

from __future__ import annotations

import logging

import numpy as np

from groundfloor.errors import InputError
from identification.preprocessing.io_motion import IMU, KINDS, ODOMETRY, check_against_poses, load_run_motion
from sindy_ekf.benchmark.health import RunStatus, guarded, watch_nis
from sindy_ekf.estimation.ekf import EkfRun
from sindy_ekf.estimation.ekf_motion import GyroNoise, MotionSensors, OdometryNoise, run_ekf_motion
from sindy_ekf.estimation.graph_motion import smooth_batch_motion, smooth_isam2_motion

log = logging.getLogger(__name__)


def _missing(run_dir, kind: str) -> InputError:
    """Return the one-line error of a test run without the file a fused sensor needs."""
    return InputError(f"{run_dir / KINDS[kind][0]}: missing; sensors: [{kind}] needs it")


def motion_sensors_of(campaign, run_name: str, t_pose, kinds: tuple[str, ...]) -> MotionSensors:
    """Return the gyro and/or odometry samples of a test run for the filter.

    Raises
    ------
    InputError
        A wanted file missing (names it), or without a sample inside the poses.
    """
    run_dir = campaign.root / "runs" / run_name
    got = {}
    for kind in kinds:
        loaded = load_run_motion(run_dir, kind, t_pose)
        if loaded is None:
            raise _missing(run_dir, kind)
        got[kind] = loaded[0]
    im, od = got.get(IMU), got.get(ODOMETRY)
    gyro = {} if im is None else {"t_gyro": im.t, "wz": im.columns["wz"], "wz_std": im.std("wz")}
    odo = {}
    if od is not None:
        std = None if od.std("v") is None or od.std("omega") is None \
            else np.column_stack([od.std("v"), od.std("omega")])
        odo = {"t_odometry": od.t, "v_omega": np.column_stack([od.columns["v"], od.columns["omega"]]),
               "v_omega_std": std}
    return MotionSensors(**gyro, **odo)


def check_motion_sensors(campaign, test_runs, kinds: tuple[str, ...]) -> None:
    """Raise the first InputError of the fused sensors, each file read once: a test run's file missing,
    or the campaign's files, pooled over every run that has one (train runs included: a sensor's axes,
    unit and clock are the campaign's, and every run adds evidence), against their ground truth
    (:func:`identification.preprocessing.io_motion.check_against_poses`)."""
    tested = {r.name for r in test_runs}
    for kind in kinds:
        pooled = []
        for run in campaign.runs:
            loaded = load_run_motion(campaign.root / "runs" / run.name, kind, run.poses.t)
            if loaded is None and run.name in tested:
                raise _missing(campaign.root / "runs" / run.name, kind)
            if loaded is not None:
                pooled.append((loaded[0], run.poses))
        check_against_poses(pooled, str(campaign.root / "runs" / "*" / KINDS[kind][0]))


def run_motion_ekfs(model, runs, campaign, kinds: tuple[str, ...], gate_prob: float, lateral, name: str,
                    P0, gnss_of, use_motor: bool = False, gyro_noise: GyroNoise = GyroNoise(),
                    odometry_noise: OdometryNoise = OdometryNoise()) -> list:
    """Return ``(result or None, RunStatus)`` of the seven-state EKF on each prepared test run."""
    out = []
    for r in runs:
        sensors = motion_sensors_of(campaign, r.name, r.t_pose, kinds)
        u = r.u_motor if use_motor and r.u_motor is not None else r.inputs_for(model.dynamics)
        run = EkfRun(f"{r.name} {name}", r.grid, u, r.x0, P0, gnss_of(r))
        res, status = guarded(run_ekf_motion, model, run, sensors, gate_prob=gate_prob, lateral=lateral,
                              gyro_noise=gyro_noise, odometry_noise=odometry_noise)
        out.append(monitored(model, run, res, status, gate_prob, lateral))
    return out


def monitored(model, run: EkfRun, res, status: RunStatus, gate_prob: float, lateral):
    """Return ``(result, status)`` of a seven-state EKF run after the NIS monitor (no re-initialisation):
    cut at a divergence the innovations show (:func:`~sindy_ekf.benchmark.health.watch_nis`)."""
    if res is None or status.status != "ok" or run.gnss is None:
        return res, status
    cut, status = watch_nis(model, run, res, gate_prob, lateral, recover=False)
    if status.status != "ok":
        log.warning("%s: %s at t=%.2f s: %s", run.name, status.status, status.t_s, status.reason)
    return cut, status


def run_motion_graphs(model, runs, campaign, kinds: tuple[str, ...], lateral, name: str, P0, gnss_of,
                      x_init_of, gyro_noise: GyroNoise = GyroNoise(),
                      odometry_noise: OdometryNoise = OdometryNoise()) -> list:
    """Return ``(result or None, RunStatus)`` of the batch smoother with gyro / odometry factors on each run.

    ``x_init_of(r)``: the starting trajectory on the run's grid (None: the seven-state EKF's
    estimate, with the same sensor noise).
    """
    noise = {"gyro_noise": gyro_noise, "odometry_noise": odometry_noise}
    out = []
    for r in runs:
        sensors = motion_sensors_of(campaign, r.name, r.t_pose, kinds)
        x_init = x_init_of(r)
        if x_init is None:
            ekf, _ = guarded(run_ekf_motion, model, EkfRun(f"{r.name} {name}", r.grid, r.inputs_for(model.dynamics),
                                                           r.x0, P0, gnss_of(r)), sensors, lateral=lateral, **noise)
            x_init = None if ekf is None else ekf.x
        if x_init is None:
            out.append((None, RunStatus("failed", 0.0, "no starting trajectory (its EKF failed)")))
            continue
        out.append(guarded(smooth_batch_motion, model, r.grid, r.inputs_for(model.dynamics), r.x0, P0, gnss_of(r),
                           sensors, x_init, marginal_stride=10, lateral=lateral, name=f"{r.name} {name}", **noise))
    return out


def isam2_motion_tasks(model, runs, campaign, kinds: tuple[str, ...], P0, gnss_of, gyro_noise: GyroNoise = GyroNoise(),
                       odometry_noise: OdometryNoise = OdometryNoise()) -> list:
    """Return the ``(function, args, kwargs)`` tasks of the fixed-lag iSAM2 with gyro / odometry factors,
    one per prepared test run (the sensors read here, so that a missing file fails before any work)."""
    return [(smooth_isam2_motion, (model, r.grid, r.inputs_for(model.dynamics), r.x0, P0, gnss_of(r),
                                   motion_sensors_of(campaign, r.name, r.t_pose, kinds)),
             dict(name=f"{r.name} sindy_isam2", gyro_noise=gyro_noise, odometry_noise=odometry_noise)) for r in runs]
