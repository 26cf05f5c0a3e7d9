"""Typed values that flow between the preprocessing and identification stages.

Data flow one way, stage by stage (docs/ARCHITECTURE.md):
``TrackerCampaign/RawRun -> SyncedRun -> PoseTrack -> BodyStates -> SindyModel``.
All arrays are numpy float64, SI units, radians; times in seconds. Absolute UTC times are
float64 seconds since the Unix epoch; inside algorithms work relative to a run's first
trigger (``t - t0``) to keep sub-microsecond precision.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from groundfloor.errors import InputError


@dataclass(frozen=True)
class PointSeries:
    """Prism positions measured by one tracker: its own clock and its own frame."""

    t_tracker: np.ndarray  # (n,) tracker-internal clock, s (drifting, arbitrary start)
    xyz: np.ndarray  # (n, 3) prism position in the tracker's frame, m


@dataclass(frozen=True)
class RawRun:
    """One driving run as the instruments recorded it (data contract part 1, topics)."""

    name: str
    split: str  # "train" or "test"
    t_trigger_utc: np.ndarray  # (n,) /rpi/trigger time_ref, UTC s, rising edge
    at960: PointSeries  # /at960/measurement (rear prism)
    ltd800: PointSeries  # /ltd800/measurement (front prism)
    t_joy_utc: np.ndarray  # (m,) /joy_teleop/joy header.stamp (robot NTP clock)
    u_joy: np.ndarray  # (m, 2) [u1 throttle = axes[1], u2 steering = axes[0]]
    t_hub_utc: np.ndarray  # (k,) /turning_hub/azimuth header.stamp
    hub_azimuth: np.ndarray  # (k, 2) commanded azimuths [front, rear], rad


@dataclass(frozen=True)
class Survey:
    """Raw survey observations of calibration.yaml (thesis tables 6.1 to 6.3), sigmas in m."""

    network_at960: dict[str, np.ndarray]  # point id -> (6,) [x, y, z, sx, sy, sz]
    network_ltd800: dict[str, np.ndarray]
    body_frame: str  # tracker the body survey was measured with ("ltd800")
    wheel_hubs: dict[str, np.ndarray]  # front_left/rear_left/rear_right/front_right -> (k, 6)
    prisms: dict[str, np.ndarray]  # front/rear -> (6,)
    prism_tracker: dict[str, str]  # front -> "ltd800", rear -> "at960"


@dataclass(frozen=True)
class TrackerCampaign:
    """A tracker campaign on disk (data contract part 1): survey plus raw runs."""

    root: Path
    name: str
    survey: Survey
    runs: tuple[RawRun, ...]
    skipped: dict[str, str] = field(default_factory=dict)  # run -> why it was skipped


@dataclass(frozen=True)
class PoseTrack:
    """Poses of the body frame in the local frame at the trigger (or ground-truth) times."""

    t: np.ndarray  # (n,) UTC s (tracker campaigns) or the campaign's time base
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray  # NaN when unknown
    pitch: np.ndarray  # NaN when unknown
    yaw: np.ndarray  # unwrapped
    x_std: np.ndarray  # NaN when unknown (all *_std)
    y_std: np.ndarray
    z_std: np.ndarray
    pitch_std: np.ndarray
    yaw_std: np.ndarray


@dataclass(frozen=True)
class InputSeries:
    """Control inputs as recorded, on their own (irregular) stamps."""

    t: np.ndarray  # (m,)
    u1: np.ndarray  # throttle / forward command, about [-1, 1]
    u2: np.ndarray  # steering / turning command, about [-1, 1], left positive


# DATA_CONTRACT: u1, u2 are scaled to about [-1, 1]; a value beyond 1.5 is a scale error (axes in
# percent, raw counts), not a hard push of the stick (issue 14, item 4)
INPUT_ABS_MAX = 1.5
# a run whose poses span less than this never moved: 1 cm is 30 times the trackers' noise
MIN_MOTION_M, MIN_MOTION_RAD = 0.01, 0.01


def check_input_range(values, where: str, column: str, t=None) -> None:
    """Raise a one-line InputError naming ``where`` and ``column`` if any ``|value| > INPUT_ABS_MAX``.

    ``t`` (optional, same length) gives the stamp of the first value out of range in the message;
    NaN values are left to the readers' own checks.
    """
    v = np.asarray(values, dtype=float)
    bad = np.flatnonzero(np.abs(v) > INPUT_ABS_MAX)
    if bad.size:
        i = int(bad[0])
        at = f", t={float(t[i]):.3f} s" if t is not None else ""
        raise InputError(f"{where}: column {column}: {bad.size} value(s) beyond |u| = {INPUT_ABS_MAX:g} "
                         f"(first {v[i]:g} at row {i}{at}); inputs are scaled to about [-1, 1]")


def check_poses_move(x, y, yaw, where: str) -> None:
    """Raise a one-line InputError naming ``where`` if the finite poses span less than
    ``MIN_MOTION_M`` in position and ``MIN_MOTION_RAD`` in heading (a robot that never moved)."""
    x, y, yaw = (np.asarray(a, dtype=float) for a in (x, y, yaw))
    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return
    span_m = float(np.hypot(np.ptp(x[ok]), np.ptp(y[ok])))
    turn = yaw[np.isfinite(yaw)]
    span_rad = float(np.ptp(np.unwrap(turn))) if turn.size else 0.0
    if span_m < MIN_MOTION_M and span_rad < MIN_MOTION_RAD:
        raise InputError(f"{where}: poses never move ({1000 * span_m:.1f} mm and {np.degrees(span_rad):.2f} deg "
                         f"over {int(ok.sum())} poses): nothing to identify or score")


@dataclass(frozen=True)
class BodyStates:
    """Body-frame velocities and inputs at the pose times (thesis 5.3.5, eqs. 5.64 to 5.66)."""

    t: np.ndarray  # (n,)
    vx: np.ndarray  # forward velocity, m/s
    vy: np.ndarray  # lateral velocity (left positive), m/s
    omega: np.ndarray  # yaw rate, rad/s
    u1: np.ndarray
    u2: np.ndarray
    x: np.ndarray  # smoothed pose in the local frame (for local-frame evaluation)
    y: np.ndarray
    yaw: np.ndarray  # unwrapped

    @property
    def state(self) -> np.ndarray:
        """(n, 3) body state [vx, vy, omega]."""
        return np.column_stack([self.vx, self.vy, self.omega])

    @property
    def inputs(self) -> np.ndarray:
        """(n, 2) inputs [u1, u2]."""
        return np.column_stack([self.u1, self.u2])


@dataclass(frozen=True)
class TrajectoryRun:
    """One run of a trajectory campaign (data contract part 2)."""

    name: str
    split: str
    poses: PoseTrack
    inputs: InputSeries
    repairs: dict[str, int] = field(default_factory=dict)  # what was repaired -> count
    group: str = ""  # the day or session it was recorded in (campaign.yaml ``group``), "" when not given


@dataclass(frozen=True)
class TrajectoryCampaign:
    """A trajectory campaign on disk (data contract part 2), or the output of preprocess."""

    root: Path
    name: str
    runs: tuple[TrajectoryRun, ...]

    def split(self, which: str) -> tuple[TrajectoryRun, ...]:
        """Return the runs marked ``which`` ("train" or "test")."""
        return tuple(r for r in self.runs if r.split == which)
