"""Short simulated campaigns without the measurement chain, made in about a second.

The full simulation (:func:`simulation.campaign.simulate_campaign`) records what the laser
trackers and the robot would have recorded (bags, clocks, triggers), and preprocessing turns
that back into poses and body states: right for testing preprocessing, slow for anything that
only needs driving data. The two functions here go straight from the simulator's true
trajectory (:func:`simulation.robot.simulate_run`) to what preprocessing would give:

- :func:`simulate_states_campaign`: 50 Hz :class:`~groundfloor.types.BodyStates` with white
  measurement noise of the size preprocessing leaves (millimetres, millimetres per second), for
  the diagnosis (its tests, example and bench);
- :func:`simulate_trajectory_runs`: :class:`~groundfloor.types.TrajectoryRun` values (poses at
  50 Hz with tracker-level noise, the joystick inputs) that
  :func:`identification.preprocessing.trajectory.write_trajectory_campaign` writes as a
  trajectory campaign (data contract part 2), for the examples.

The inputs are the joystick messages as the robot received them, i.e. what a recording holds,
never what the motors saw. Both take a simulator variant (:mod:`simulation.variants`: an index
or a :class:`simulation.variant.Variant`), so that tests can use many variants cheaply; the
measurement noise then scales with the variant's tracker noise.
"""

from __future__ import annotations

import math

import numpy as np

from groundfloor.types import BodyStates, InputSeries, PoseTrack, TrajectoryRun
from simulation.driver import DrivingArea
from simulation.effects import Effect
from simulation.robot import TrueRun, simulate_run
from simulation.variant import Variant
from simulation.variants import check_variant

VEL_NOISE_STD = (0.004, 0.003, 0.008)  # vx m/s, vy m/s, omega rad/s
POSE_NOISE_STD = (0.0005, 0.0005, 0.0005)  # x m, y m, yaw rad

#: (name, split, seconds) of the runs of :func:`simulate_trajectory_runs`
TRAJECTORY_RUNS = (("run_01", "train", 60.0), ("run_02", "train", 60.0), ("run_03", "train", 60.0),
                   ("run_04", "test", 60.0))
POSE_STRIDE = 10  # simulator step 2 ms -> poses at 50 Hz, the trigger rate of the thesis
POSITION_STD_M = 2e-5  # tracker-level pose noise (preprocessing reaches about 0.02 mm, 0.0015 deg)
YAW_STD_RAD = math.radians(0.0015)


def states_from_true_run(run: TrueRun, rng: np.random.Generator, rate_hz: float = 50.0,
                         t0: float = 0.0, noise_scale: float = 1.0) -> BodyStates:
    """Return BodyStates of a TrueRun at ``rate_hz`` with measurement noise (``noise_scale`` times
    ``VEL_NOISE_STD`` and ``POSE_NOISE_STD``); inputs = joystick held (ZOH)."""
    step = max(int(round(1.0 / (rate_hz * (run.t[1] - run.t[0])))), 1)
    k = np.arange(0, len(run.t), step)
    t = run.t[k]
    idx = np.searchsorted(run.t_joy, t, side="right") - 1
    u = np.where((idx >= 0)[:, None], run.u_joy[np.maximum(idx, 0)], 0.0)
    vel_std, pose_std = (VEL_NOISE_STD, POSE_NOISE_STD) if noise_scale == 1.0 else \
        (np.multiply(VEL_NOISE_STD, noise_scale), np.multiply(POSE_NOISE_STD, noise_scale))
    v = np.column_stack([run.vx[k], run.vy[k], run.omega[k]]) + rng.normal(0, vel_std, (len(k), 3))
    p = np.column_stack([run.x[k], run.y[k], run.psi[k]]) + rng.normal(0, pose_std, (len(k), 3))
    return BodyStates(t=t + t0, vx=v[:, 0], vy=v[:, 1], omega=v[:, 2], u1=u[:, 0], u2=u[:, 1],
                      x=p[:, 0], y=p[:, 1], yaw=p[:, 2])


def simulate_states_campaign(seed: int, effect: Effect | None = None, n_train: int = 4, n_test: int = 2,
                             run_s: float = 60.0, dt: float = 0.004, rate_hz: float = 50.0,
                             variant: int | Variant | None = None):
    """Return ``(train, test, train_names, test_names)`` BodyStates of a short simulated campaign.

    Runs start at poses spread over the driving area (so a floor patch is visited), each with
    its own generator spawned from ``seed``; run ``i`` starts at ``t = 1000 (i + 1)`` s.
    ``variant``: the simulator variant (None or 0: the simulator before variants).
    """
    variant = check_variant(variant)
    scale = _noise_scale(variant)
    root = np.random.default_rng(seed)
    area = DrivingArea()
    rngs = root.spawn(n_train + n_test)
    out = []
    for i, rng in enumerate(rngs):
        r_start = np.random.default_rng(rng.integers(2**32))
        a, b = area.semi_axes_m
        ang = area.axis_angle_rad
        e1, e2 = r_start.uniform(-0.55, 0.55) * a, r_start.uniform(-0.4, 0.4) * b
        cx, cy = area.center_local_m
        start = (cx + e1 * math.cos(ang) - e2 * math.sin(ang), cy + e1 * math.sin(ang) + e2 * math.cos(ang),
                 ang + (math.pi if r_start.random() < 0.5 else 0.0))
        run = simulate_run(run_s, rng, effect=effect, dt=dt, start_pose=start, variant=variant)
        out.append(states_from_true_run(run, rng, rate_hz, t0=1000.0 * (i + 1), noise_scale=scale))
    names = [f"run_{i + 1:02d}" for i in range(n_train + n_test)]
    return out[:n_train], out[n_train:], names[:n_train], names[n_train:]


def simulate_trajectory_runs(seed: int = 0, runs=TRAJECTORY_RUNS, effect: Effect | None = None,
                             variant: int | Variant | None = None) -> list[TrajectoryRun]:
    """Return simulated trajectory runs: true poses at 50 Hz plus tracker-level noise, joystick inputs.

    ``runs`` are ``(name, split, seconds)``; each run draws from its own generator spawned from
    ``seed``. The poses have the standard deviations they were drawn with (``POSITION_STD_M``,
    ``YAW_STD_RAD``, times the variant's tracker noise scale) and no z or pitch. ``variant``:
    the simulator variant (None or 0: the simulator before variants).
    """
    variant = check_variant(variant)
    pos_std, yaw_std = POSITION_STD_M * _noise_scale(variant), YAW_STD_RAD * _noise_scale(variant)
    rng = np.random.default_rng(seed)
    out = []
    for (name, split, seconds), run_rng in zip(runs, rng.spawn(len(runs))):
        true = simulate_run(seconds, run_rng, effect=effect, variant=variant)
        sel = slice(None, None, POSE_STRIDE)
        n = true.t[sel].size
        noise = run_rng.normal(size=(n, 3)) * [pos_std, pos_std, yaw_std]
        nan = np.full(n, np.nan)
        poses = PoseTrack(t=true.t[sel], x=true.x[sel] + noise[:, 0], y=true.y[sel] + noise[:, 1], z=nan,
                          pitch=nan, yaw=true.psi[sel] + noise[:, 2], x_std=np.full(n, pos_std),
                          y_std=np.full(n, pos_std), z_std=nan, pitch_std=nan,
                          yaw_std=np.full(n, yaw_std))
        inputs = InputSeries(t=true.t_joy, u1=true.u_joy[:, 0], u2=true.u_joy[:, 1])
        out.append(TrajectoryRun(name=name, split=split, poses=poses, inputs=inputs))
    return out


def _noise_scale(variant: Variant) -> float:
    """Return the variant's tracker noise scale (the mean of both trackers'; 1 for ``Variant()``)."""
    at960, ltd800 = variant.tracker_noise_scale
    return 1.0 if at960 == ltd800 == 1.0 else 0.5 * (at960 + ltd800)
