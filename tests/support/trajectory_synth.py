"""A small trajectory campaign of the simulator's robot (two train runs, one test run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundfloor.types import InputSeries, PoseTrack, TrajectoryRun
from identification.preprocessing.trajectory import write_trajectory_campaign
from simulation.robot import simulate_run

MINI_RUNS = (("run_a", 30.0, "train"), ("run_b", 30.0, "train"), ("run_c", 45.0, "test"))


def write_mini_campaign(root: Path, seed: int = 42, runs=MINI_RUNS) -> Path:
    """Write the simulator's runs ``(name, seconds, split)`` as a trajectory campaign at ``root``; return it.

    Poses (x, y, yaw at 50 Hz, on a UTC-like time base as preprocess writes) and the joystick
    inputs as recorded; no truth folder (a measured campaign, as far as readers can tell).
    """
    rng = np.random.default_rng(seed)
    out = []
    for name, dur, split in runs:
        tr = simulate_run(dur, rng, dt=0.02)
        t = 1.7e9 + tr.t
        nan = np.full_like(t, np.nan)
        poses = PoseTrack(t, tr.x, tr.y, nan, nan, tr.psi, nan, nan, nan, nan, nan)
        inputs = InputSeries(1.7e9 + tr.t_joy, tr.u_joy[:, 0], tr.u_joy[:, 1])
        out.append((TrajectoryRun(name, split, poses, inputs), None))
    write_trajectory_campaign(root, root.name, out)
    return root
