"""A small simulated trajectory campaign for the examples, made in about a second.

The examples need a campaign that runs in seconds, so this skips the laser-tracker measurement
chain (bags, clocks, synchronisation; ``sindy-ekf simulate`` and ``preprocess`` do that) and
writes what preprocessing would give: a trajectory campaign (data contract part 2) with the
simulated robot's true poses at 50 Hz plus tracker-level noise, and the joystick inputs as the
robot received them. The simulator is thesis model B with process noise (``simulation.robot``),
driven by the human-like driver; ``effect`` hides one effect of ``simulation.effects``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundfloor.types import InputSeries, PoseTrack, TrajectoryRun
from identification.preprocessing.trajectory import write_trajectory_campaign
from simulation.effects import Effect
from simulation.robot import simulate_run

RUNS = (("run_01", "train", 60.0), ("run_02", "train", 60.0), ("run_03", "train", 60.0),
        ("run_04", "test", 60.0))
POSE_STRIDE = 10  # simulator step 2 ms -> poses at 50 Hz, the trigger rate of the thesis
POSITION_STD_M = 2e-5  # tracker-level pose noise (preprocessing reaches about 0.02 mm, 0.0015 deg)
YAW_STD_RAD = np.radians(0.0015)


def simulate_trajectory_campaign(out: str | Path, seed: int = 0, runs=RUNS,
                                 effect: tuple[str, float] | None = None) -> Path:
    """Return ``out`` after writing a simulated trajectory campaign there (replaced if present)."""
    rng = np.random.default_rng(seed)
    eff = Effect(*effect) if effect is not None else None
    written = []
    for (name, split, seconds), run_rng in zip(runs, rng.spawn(len(runs))):
        true = simulate_run(seconds, run_rng, effect=eff)
        sel = slice(None, None, POSE_STRIDE)
        n = true.t[sel].size
        noise = run_rng.normal(size=(n, 3)) * [POSITION_STD_M, POSITION_STD_M, YAW_STD_RAD]
        nan = np.full(n, np.nan)
        poses = PoseTrack(t=true.t[sel], x=true.x[sel] + noise[:, 0], y=true.y[sel] + noise[:, 1], z=nan,
                          pitch=nan, yaw=true.psi[sel] + noise[:, 2], x_std=np.full(n, POSITION_STD_M),
                          y_std=np.full(n, POSITION_STD_M), z_std=nan, pitch_std=nan,
                          yaw_std=np.full(n, YAW_STD_RAD))
        inputs = InputSeries(t=true.t_joy, u1=true.u_joy[:, 0], u2=true.u_joy[:, 1])
        written.append((TrajectoryRun(name=name, split=split, poses=poses, inputs=inputs), None))
    effect_text = "none" if eff is None else f"{eff.name}={eff.value:g}"
    return write_trajectory_campaign(out, f"examples-seed{seed}", written, force=True,
                                     source=f"examples/_small_campaign.py seed {seed}, effect {effect_text}",
                                     ground_truth="simulator truth plus tracker-level noise")
