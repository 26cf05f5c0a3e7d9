"""Recorded IMU gyro and wheel odometry beside the ground truth (issue 16): read, cleaned, written per run.

Declared in ``campaign.yaml`` under ``sensors:`` (:mod:`identification.preprocessing.io_sensors`):
a ``sensor_msgs/Imu`` topic gives ``imu.csv`` (``t,wz,ax,ay``: UTC s, the yaw rate
``angular_velocity.z`` in rad/s, the body accelerations in m/s^2, then ``wz_std`` from the stated
``angular_velocity_covariance[8]``), a ``nav_msgs/Odometry`` topic gives ``odometry.csv``
(``t,v,omega``: ``twist.twist.linear.x`` m/s and ``angular.z`` rad/s, then ``v_std,omega_std`` from
``twist.covariance[0]`` and ``[35]``). A trajectory campaign may carry these files directly; only
``t,wz`` resp. ``t,v,omega`` are required (std columns missing: the filter's defaults); an
``odometry.csv`` may give ``t,w_left,w_right`` (wheel speeds, rad/s) instead, with
``wheel_radius_m`` and ``track_m`` in ``campaign.yaml`` (data contract part 2). Rows with
a non-finite time or value are dropped and counted (a message whose header stamp was never set, zero,
takes its bag time, counted); samples outside the run's pose span are cut;
none inside it is an :class:`InputError` naming the file. ``sensor_msgs/JointState`` wheel speeds
(the joints named ``left`` and ``right`` averaged per side, rad/s) give ``odometry.csv`` as
``t,w_left,w_right`` where a run has no ``nav_msgs/Odometry``; the trajectory campaign carries the
tracker campaign's ``wheel_radius_m`` and ``track_m``, which turn them into ``v, omega`` when read.
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.stats

from groundfloor.errors import InputError
from groundfloor.geodetic import SIGNIFICANCE_P
from groundfloor.files import csv_header
from identification.preprocessing.io_sensors import (
    CONTRACT_TOPICS,
    WHEEL_KEYS,
    read_csv_columns,
    read_sensors_config,
    topic_messages,
    undeclared_guard,
)
from identification.preprocessing.io_tracker import find_bags
from identification.preprocessing.stamp_order import unstamped_to_receive
from identification.preprocessing.trajectory_checks import pose_motion

log = logging.getLogger(__name__)

IMU, ODOMETRY, WHEELS = "imu", "odometry", "wheels"
IMU_CSV, ODOMETRY_CSV = "imu.csv", "odometry.csv"
# per kind: CSV file, ROS message type, required value columns, optional columns
KINDS = {
    IMU: (IMU_CSV, "sensor_msgs/msg/Imu", ("wz",), ("ax", "ay", "wz_std")),
    ODOMETRY: (ODOMETRY_CSV, "nav_msgs/msg/Odometry", ("v", "omega"), ("v_std", "omega_std")),
    # wheel speeds (sensor_msgs/JointState): written as odometry.csv's w_left,w_right
    WHEELS: (ODOMETRY_CSV, "sensor_msgs/msg/JointState", ("w_left", "w_right"), ()),
}
DEFAULT_TOPICS = {IMU: CONTRACT_TOPICS["imu"], ODOMETRY: CONTRACT_TOPICS["odometry"],
                  WHEELS: CONTRACT_TOPICS["wheels"]}  # data contract part 1
#: an odometry.csv may give the wheel speeds of each side instead of v, omega (rad/s), with
#: io_sensors.WHEEL_KEYS in campaign.yaml
WHEEL_COLUMNS = ("w_left", "w_right")


@dataclass(frozen=True)
class MotionSamples:
    """One run's samples of a motion sensor: times and named columns."""

    kind: str  # imu or odometry
    t: np.ndarray  # (n,) UTC s (header stamps)
    columns: dict  # name -> (n,) array, e.g. wz, ax, ay, wz_std or v, omega, v_std, omega_std
    unstamped: int = 0  # messages whose header stamp was never set (zero): their bag time taken

    def select(self, keep: np.ndarray) -> MotionSamples:
        """Return the samples where ``keep``."""
        return MotionSamples(self.kind, self.t[keep], {k: v[keep] for k, v in self.columns.items()}, self.unstamped)

    def std(self, name: str) -> np.ndarray | None:
        """Return the stated std column of ``name`` (e.g. ``wz``), or None when not given."""
        return self.columns.get(f"{name}_std")


def clean_samples(s: MotionSamples, source: str) -> tuple[MotionSamples, dict[str, int]]:
    """Return the samples without non-finite times or required values, sorted, duplicates dropped, and the counts."""
    required = KINDS[s.kind][2]
    ok = np.isfinite(s.t) & np.all([np.isfinite(s.columns[c]) for c in required], axis=0)
    counts = {"samples": int(s.t.size), "nan_dropped": int((~ok).sum()), "unstamped_receive_time": s.unstamped}
    if (~ok).any():
        log.info("%s: dropped %d non-finite %s samples", source, (~ok).sum(), s.kind)
    kept = s.select(ok)
    kept = kept.select(np.argsort(kept.t, kind="stable"))
    dup = np.concatenate([[False], np.diff(kept.t) == 0])
    counts["duplicates_dropped"] = int(dup.sum())
    return kept.select(~dup), counts


def overlapping_samples(s: MotionSamples, t_pose: np.ndarray, source: str) -> MotionSamples:
    """Return the samples inside the poses' time span; InputError naming ``source`` when none is."""
    t_pose = np.asarray(t_pose, float)
    t_pose = t_pose[np.isfinite(t_pose)]
    keep = (s.t >= t_pose.min()) & (s.t <= t_pose.max()) if t_pose.size else np.zeros(s.t.size, bool)
    if not keep.any():
        span = f"[{s.t.min():.3f}, {s.t.max():.3f}]" if s.t.size else "none"
        raise InputError(f"{source}: no {s.kind} sample inside the poses' time span (samples {span} s, poses "
                         f"[{t_pose.min():.3f}, {t_pose.max():.3f}] s)")
    return s.select(keep)


def _side_speeds(m) -> tuple[float, float]:
    """Return the mean ``velocity`` (rad/s) of the joints of a ``sensor_msgs/JointState`` whose
    name says ``left``, and of those that say ``right`` (NaN for a side without one, or without velocities)."""
    names = [str(n).lower() for n in m.name]
    vel = np.asarray(m.velocity, float)
    if vel.size != len(names):
        return np.nan, np.nan
    left = [v for n, v in zip(names, vel) if "left" in n]
    right = [v for n, v in zip(names, vel) if "right" in n]
    return (float(np.mean(left)) if left else np.nan), (float(np.mean(right)) if right else np.nan)


def _row(kind: str, m) -> tuple:
    if kind == WHEELS:
        return _side_speeds(m)
    if kind == IMU:
        cov = np.asarray(m.angular_velocity_covariance, float)
        return (m.angular_velocity.z, m.linear_acceleration.x, m.linear_acceleration.y,
                np.sqrt(cov[8]) if cov[8] > 0 else np.nan)
    cov = np.asarray(m.twist.covariance, float)
    return (m.twist.twist.linear.x, m.twist.twist.angular.z, np.sqrt(cov[0]) if cov[0] > 0 else np.nan,
            np.sqrt(cov[35]) if cov[35] > 0 else np.nan)


def read_motion_topic(bags: list[Path], topic: str, kind: str, run: str) -> MotionSamples | None:
    """Return the messages of ``topic`` (an IMU or odometry) across a run's bags, or None if absent.

    Raises
    ------
    InputError
        The topic recorded with another message type (names run, topic and type).
    """
    msgtype, names = KINDS[kind][1], KINDS[kind][2] + KINDS[kind][3]
    rows = [(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, t_bag * 1e-9, *_row(kind, m))
            for t_bag, m in topic_messages(bags, topic, msgtype, run)]
    if not rows:
        return None
    a = np.array(rows, float)
    t, unset = unstamped_to_receive(a[:, 0], a[:, 1])
    if unset:
        log.warning("run %s: topic %s: %d of %d messages have no header stamp (zero); their bag times are taken",
                    run, topic, unset, len(t))
    a = np.column_stack([t, a[:, 2:]])
    if kind == WHEELS and not np.isfinite(a[:, 1:]).all(axis=1).any():
        raise InputError(f"run {run}: topic {topic}: no message with a velocity of a joint named left and "
                         "of one named right (sensor_msgs/JointState wheel speeds)")
    return MotionSamples(kind, a[:, 0], {n: a[:, 1 + i] for i, n in enumerate(names)}, unset)


def write_motion_csv(path: str | Path, s: MotionSamples) -> Path:
    """Write ``imu.csv`` or ``odometry.csv`` (module docstring); return its path."""
    names = [n for n in KINDS[s.kind][2] + KINDS[s.kind][3] if n in s.columns]
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack([s.t] + [s.columns[n] for n in names]), delimiter=",",
               fmt=["%.9f"] + ["%.9g"] * len(names), header=",".join(["t", *names]), comments="")
    Path(path).write_text(buf.getvalue())
    return Path(path)


def read_motion_csv(path: str | Path, kind: str) -> MotionSamples:
    """Return the samples of an ``imu.csv`` or ``odometry.csv`` as written (NaN rows kept: :func:`clean_samples`).

    Raises
    ------
    InputError
        Naming the file: unreadable, a required column missing.
    """
    path = Path(path)
    if kind == ODOMETRY and _gives_wheel_speeds(path):
        return _wheel_odometry(path)
    data = read_csv_columns(path, ("t",) + KINDS[kind][2])
    names = data.dtype.names
    known = KINDS[kind][2] + KINDS[kind][3]
    return MotionSamples(kind, np.array(data["t"], float), {n: np.array(data[n], float) for n in known if n in names})


def _gives_wheel_speeds(path: Path) -> bool:
    """Return whether an ``odometry.csv`` gives wheel speeds ``w_left,w_right`` instead of ``v,omega``."""
    try:
        header = csv_header(path)
    except OSError:
        return False  # read_csv_columns names the file
    return "v" not in header and all(c in header for c in WHEEL_COLUMNS)


def _wheel_odometry(path: Path) -> MotionSamples:
    """Return the odometry of an ``odometry.csv`` with wheel speeds ``w_left,w_right`` (rad/s, each
    side's wheels): ``v = r (w_l + w_r) / 2`` and ``omega = r (w_r - w_l) / b`` with the wheel radius
    ``r`` and track ``b`` of the campaign's ``campaign.yaml`` (data contract part 2). The track is the
    geometric one: a skid-steered robot turns slower than it says (the filters' ``scale_std``)."""
    data = read_csv_columns(path, ("t",) + WHEEL_COLUMNS)
    campaign = path.parent.parent.parent
    config = read_sensors_config(campaign)  # checks the keys' values (positive numbers)
    for key in WHEEL_KEYS:
        if getattr(config, key) is None:
            raise InputError(f"{campaign / 'campaign.yaml'}: key '{key}' missing; {path} gives wheel speeds "
                             f"({','.join(WHEEL_COLUMNS)}), which need {' and '.join(WHEEL_KEYS)}")
    radius, track = config.wheel_radius_m, config.track_m
    w_l, w_r = np.array(data["w_left"], float), np.array(data["w_right"], float)
    return MotionSamples(ODOMETRY, np.array(data["t"], float),
                         {"v": radius * (w_l + w_r) / 2.0, "omega": radius * (w_r - w_l) / track})


def load_run_motion(run_dir: str | Path, kind: str, t_pose: np.ndarray) -> tuple[MotionSamples, dict] | None:
    """Return a trajectory run's cleaned samples of ``kind`` inside its poses and the counts, or None without the file."""
    path = Path(run_dir) / KINDS[kind][0]
    if not path.is_file():
        return None
    s, counts = clean_samples(read_motion_csv(path, kind), str(path))
    return overlapping_samples(s, t_pose, str(path)), counts


def write_run_motion(campaign_dir: Path, out_dir: Path, runs: dict[str, np.ndarray]) -> dict:
    """Write ``imu.csv`` / ``odometry.csv`` of each preprocessed run from the bags; return counts per kind and run.

    ``runs`` maps each written run (a part ``<run>.k`` of a cut run included) to its pose times.
    A kind without a declared sensor is read from the data contract's default topic where a run has it.
    """
    config = read_sensors_config(campaign_dir)
    out: dict = {}
    for kind in (IMU, ODOMETRY, WHEELS):
        spec, declared = config.sensor(kind)
        topic = spec.topic or DEFAULT_TOPICS[kind]
        for name, t_pose in runs.items():
            if kind == WHEELS and name in out.get(ODOMETRY, {}):
                continue  # nav_msgs/Odometry gives v and omega already
            folder = name if (campaign_dir / "runs" / name).is_dir() else name.rsplit(".", 1)[0]
            s = undeclared_guard(lambda: read_motion_topic(find_bags(campaign_dir / "runs" / folder), topic, kind, name),
                                 declared, name, topic)
            if s is None:
                if declared:
                    log.warning("run %s: no %s topic %s", name, kind, topic)
                continue
            s, counts = clean_samples(s, f"run {name}: topic {topic}")
            s = overlapping_samples(s, t_pose, f"run {name}: topic {topic}")
            counts["written"] = int(s.t.size)
            write_motion_csv(out_dir / "runs" / name / KINDS[kind][0], s)
            out.setdefault(kind, {})[name] = counts
    if out.get(WHEELS) and (config.wheel_radius_m is None or config.track_m is None):
        log.warning("%s: wheel speeds written to odometry.csv (runs %s), but campaign.yaml has no %s: a filter "
                    "fusing odometry needs them", campaign_dir / "campaign.yaml", ", ".join(out[WHEELS]),
                    " and ".join(WHEEL_KEYS))
    return out


#: a sensor column anti-correlated with the motion it measures (the poses' yaw rate or forward speed)
#: below this is a sign against the data contract's axes (the simulated gyro and odometry: +0.88 to +1.00)
MIN_SENSOR_CORRELATION = -0.3
#: ... and one that follows it (correlation above 0.5) this many times larger, another unit: degrees
#: per second are 57 times radians per second, wheel rpm about 9.5 times rad/s (a skid-steered robot's
#: odometry overstates its turn rate by up to about 2 or 3, which stays below)
MAX_SENSOR_SCALE = {"wz": 20.0, "omega": 20.0, "v": 5.0}
#: time shifts of a sensor against the poses scored by :func:`check_against_poses` (s); a best shift
#: beyond MIN_TIME_OFFSET_S that correlates significantly better (:func:`_fisher_worse`) is
#: another time base or a latency the filters do not model (a gyro stamped 0.5 s late took the simulated
#: campaign's sindy_ekf from 0.04 to 3.7 m); a gyro's or an odometry's own delay is milliseconds
OFFSET_GRID_S = np.round(np.arange(-30.0, 30.0 + 1e-9, 0.05), 2)
MIN_TIME_OFFSET_S = 0.25
#: correlations with the poses' finite-difference rates above this are told apart by their noise alone
MAX_RESOLVED_CORRELATION = 0.99


def _fisher_worse(r_low: float, r_high: float, seconds: float) -> bool:
    """Return whether a correlation ``r_low`` is significantly below ``r_high`` (Fisher's z at
    :data:`~groundfloor.geodetic.SIGNIFICANCE_P`, on one independent sample a second: consecutive
    samples of a motion are not independent)."""
    # beyond 0.99 the pose-derived rates' own noise, not the alignment, makes the difference
    z = np.arctanh(np.clip([r_low, r_high], -MAX_RESOLVED_CORRELATION, MAX_RESOLVED_CORRELATION))
    return seconds > 3 and (z[1] - z[0]) * np.sqrt((seconds - 3) / 2.0) > scipy.stats.norm.isf(SIGNIFICANCE_P)


def _shift_scores(tracks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Return, per shift of :data:`OFFSET_GRID_S`, the correlation of a sensor column with its truth
    at the shifted stamps, pooled over ``tracks`` (per run ``(t, a, t_truth, truth)``), and the seconds
    it rests on. A run counts at a shift where at least half of its samples' time span stays inside
    its truth's (a correlation over a few seconds at the edge of a short run means nothing)."""
    thinned = []
    for t, a, t_truth, truth in tracks:
        k = max(t.size // 2000, 1)  # 2000 samples a run are plenty for a correlation; 1200 shifts of 30000 are not
        thinned.append((t[::k], a[::k], t_truth, truth))
    r, seconds = np.full(OFFSET_GRID_S.size, np.nan), np.zeros(OFFSET_GRID_S.size)
    for i, shift in enumerate(OFFSET_GRID_S):
        xs, ys, sec = [], [], 0.0
        for t, a, t_truth, truth in thinned:
            m = np.interp(t + shift, t_truth, truth, left=np.nan, right=np.nan)
            ok = np.isfinite(a) & np.isfinite(m)
            if ok.sum() < 20 or np.ptp(t[ok]) < 0.5 * np.ptp(t):
                continue
            xs.append(a[ok])
            ys.append(m[ok])
            sec += float(np.ptp(t[ok]))
        if not xs:
            continue
        x, y = np.concatenate(xs), np.concatenate(ys)
        if np.std(x) > 0 and np.std(y) > 0:
            r[i], seconds[i] = np.corrcoef(x, y)[0, 1], sec
    return r, seconds


def time_shift(tracks) -> tuple[float, float, float, bool]:
    """Return the shift of the stamps at which a sensor column follows its truth (``tracks`` as
    :func:`_shift_scores`), the correlation there and at the stamps, and whether that makes another
    time base.

    Of the shifts of :data:`OFFSET_GRID_S` that correlate about as well as the best in magnitude (a
    periodic drive, a figure of eight, repeats itself, and half a period away it is inverted), the
    nearest to the stamps, then the best within a second of it (the band of "about as well" is
    wide, its edge no estimate); another time base where it is more than :data:`MIN_TIME_OFFSET_S`
    away and the stamps themselves correlate significantly worse (:func:`_fisher_worse`)."""
    rs, seconds = _shift_scores(tracks)
    zero = int(np.argmin(np.abs(OFFSET_GRID_S)))
    if not np.isfinite(rs).any() or not np.isfinite(rs[zero]):
        return 0.0, float("nan"), float("nan"), False
    top = int(np.nanargmax(np.abs(rs)))
    near = next(i for i in np.argsort(np.abs(OFFSET_GRID_S), kind="stable") if np.isfinite(rs[i])
                and not _fisher_worse(abs(rs[i]), abs(rs[top]), seconds[top]))
    around = np.flatnonzero((np.abs(OFFSET_GRID_S - OFFSET_GRID_S[near]) <= 1.0) & np.isfinite(rs))
    near = int(around[np.argmax(np.abs(rs[around]))])
    shift = float(OFFSET_GRID_S[near])
    off = abs(shift) > MIN_TIME_OFFSET_S and _fisher_worse(abs(rs[zero]), abs(rs[top]), seconds[top])
    return shift, float(rs[near]), float(rs[zero]), bool(off)


def check_against_poses(runs: list[tuple[MotionSamples, object]], source: str) -> None:
    """Raise a one-line InputError naming ``source`` and the column when a gyro or odometry column
    runs against the ground truth's motion (a z-down IMU frame, left and right wheels swapped, a
    reversed speed), is many times larger than it (degrees per second, rpm), or follows it best
    seconds away from its stamps (another time base: :data:`OFFSET_GRID_S`).

    ``runs``: per run its samples (of one kind) and its poses. The evidence is pooled over them: a
    sensor's axes, unit and clock are the campaign's, and a short run alone cannot tell a clock off
    by two seconds from an inverted axis. The truth: the poses' yaw rate and forward speed over about
    0.2 s (:func:`identification.preprocessing.trajectory_checks.pose_motion`), at the samples'
    times. Runs whose truth barely moves say nothing and pass.
    """
    runs = [(s, pose_motion(poses)) for s, poses in runs if s.t.size >= 3]
    runs = [(s, (mid, {"rate": rate, "speed": speed})) for s, (mid, speed, rate) in runs if mid.size >= 3]
    if not runs:
        return
    pairs = {IMU: (("wz", "rate"),), ODOMETRY: (("v", "speed"), ("omega", "rate"))}[runs[0][0].kind]
    words = {"rate": "the poses' yaw rate", "speed": "the poses' forward speed"}
    for column, motion in pairs:
        a = np.concatenate([s.columns[column] for s, _ in runs])
        m = np.concatenate([np.interp(s.t, mid, truth[motion], left=np.nan, right=np.nan) for s, (mid, truth) in runs])
        ok = np.isfinite(a) & np.isfinite(m)
        if ok.sum() < 10 or np.std(m[ok]) < 1e-3 or np.std(a[ok]) == 0:
            continue
        r = float(np.corrcoef(a[ok], m[ok])[0, 1])
        slope = float(np.sum(a[ok] * m[ok]) / np.sum(m[ok] ** 2))
        shift, r_there, r_zero, off = time_shift([(s.t, s.columns[column], mid, truth[motion]) for s, (mid, truth) in runs])
        # against the truth as stamped but with it a shift away: the clock, not the axis
        off = off or (r < MIN_SENSOR_CORRELATION and abs(shift) > MIN_TIME_OFFSET_S and r_there > -MIN_SENSOR_CORRELATION)
        if off:
            raise InputError(f"{source}: column {column} follows {words[motion]} best at its stamps {shift:+.2f} s "
                             f"(r = {r_there:.2f} there, {r_zero:.2f} as stamped): t must be on the poses' time base")
        if r < MIN_SENSOR_CORRELATION:
            why = ("the data contract's gyro z axis is up, counter-clockwise positive (a z-down IMU frame?)"
                   if column == "wz" else "the data contract's v is positive forward and omega counter-clockwise "
                   "(left and right wheels swapped, or a reversed axis?)")
            raise InputError(f"{source}: column {column} runs against {words[motion]} (r = {r:.2f}, slope {slope:.2f}): "
                             f"{why}")
        if r > 0.5 and slope > MAX_SENSOR_SCALE[column]:
            raise InputError(f"{source}: column {column} is {slope:.3g} times {words[motion]} (r = {r:.2f}): another "
                             f"unit than the data contract's {'m/s' if column == 'v' else 'rad/s'} (degrees per "
                             "second? wheel rpm?)")
