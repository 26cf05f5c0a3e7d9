"""A small trajectory campaign of the simulator's robot (two train runs, one test run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundfloor.types import InputSeries, PoseTrack, TrajectoryRun
from identification.preprocessing.io_motion import IMU, IMU_CSV, ODOMETRY, ODOMETRY_CSV, MotionSamples, write_motion_csv
from identification.preprocessing.trajectory import write_trajectory_campaign
from simulation.motion_sensors import ImuSpec, OdometrySpec, record_imu, record_odometry
from simulation.robot import simulate_run

MINI_RUNS = (("run_a", 30.0, "train"), ("run_b", 30.0, "train"), ("run_c", 45.0, "test"))


def write_mini_campaign(root: Path, seed: int = 42, runs=MINI_RUNS, motion_sensors: bool = False) -> Path:
    """Write the simulator's runs ``(name, seconds, split)`` as a trajectory campaign at ``root``; return it.

    Poses (x, y, yaw at 50 Hz, on a UTC-like time base as preprocess writes) and the joystick
    inputs as recorded; no truth folder (a measured campaign, as far as readers can tell).
    ``motion_sensors``: each run also gets the simulator's gyro (``imu.csv``: ``t,wz``) and wheel
    odometry (``odometry.csv``: ``t,v,omega``), without std columns (the filters' assumed noise
    applies), drawn from their own random stream (the runs are those without them).
    """
    rng = np.random.default_rng(seed)
    sensor_rng = np.random.default_rng([seed, 16])
    out, truths = [], []
    for name, dur, split in runs:
        tr = simulate_run(dur, rng, dt=0.02)
        t = 1.7e9 + tr.t
        nan = np.full_like(t, np.nan)
        poses = PoseTrack(t, tr.x, tr.y, nan, nan, tr.psi, nan, nan, nan, nan, nan)
        inputs = InputSeries(1.7e9 + tr.t_joy, tr.u_joy[:, 0], tr.u_joy[:, 1])
        out.append((TrajectoryRun(name, split, poses, inputs), None))
        truths.append((name, tr))
    write_trajectory_campaign(root, root.name, out)
    for name, tr in truths if motion_sensors else ():
        t_ns = np.round((1.7e9 + tr.t) * 1e9).astype(np.int64)
        imu = record_imu(t_ns, tr.vx, tr.vy, tr.omega, ImuSpec(), sensor_rng)
        odo = record_odometry(t_ns, tr.vx, tr.omega, OdometrySpec(), sensor_rng)
        write_motion_csv(root / "runs" / name / IMU_CSV, MotionSamples(IMU, imu.t_ns * 1e-9, {"wz": imu.wz}))
        write_motion_csv(root / "runs" / name / ODOMETRY_CSV,
                         MotionSamples(ODOMETRY, odo.t_ns * 1e-9, {"v": odo.v, "omega": odo.omega}))
    return root
