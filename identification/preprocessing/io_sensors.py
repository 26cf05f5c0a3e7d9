"""Recorded sensors beside the ground truth (issue 16): declared in ``campaign.yaml``, read by name and type.

``campaign.yaml`` names the sensors under ``sensors:``, either as a list of
``{name, topic, type[, lever_arm_body_m]}`` or as a mapping ``{name: topic}`` (the type then
follows from the name, data contract part 1). A type outside :data:`SENSOR_TYPES` is a one-line
:class:`InputError` naming it; keys and topics readers do not know are ignored. IMU and wheel odometry
(``nav_msgs/Odometry``) are read by :mod:`identification.preprocessing.io_motion`.

GNSS (``sensor_msgs/NavSatFix``) is read from the run's bags (ROS1 and ROS2, rosbags' AnyReader)
or from a trajectory campaign's ``runs/<run>/gnss.csv``; fixes with status ``NO_FIX`` (< 0) or
non-finite latitude, longitude or altitude are dropped and counted (:func:`clean_fixes`).
``gnss.csv`` columns: ``t,lat,lon,alt`` (UTC s, degrees, metres), then either
``cov_ee,cov_en,cov_eu,cov_nn,cov_nu,cov_uu`` (m^2, east-north-up) or ``std_e,std_n,std_u`` (m),
optionally ``status`` (NavSatStatus, missing = 0) and ``t_arrival`` (when the fix was received).
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as ReaderError1
from rosbags.rosbag2 import ReaderError as ReaderError2
from rosbags.typesys import Stores, get_typestore

from groundfloor.errors import InputError
from groundfloor.files import csv_header, missing_column, no_numbers
from groundfloor.geodetic import GeodeticOrigin
from identification.preprocessing.io_tracker import find_bags
from identification.preprocessing.stamp_order import unstamped_to_receive

log = logging.getLogger(__name__)

GNSS = "gnss"
# sensor type -> kind; gnss read here, imu, odometry and wheels (JointState) by io_motion
SENSOR_TYPES = {"sensor_msgs/NavSatFix": GNSS, "sensor_msgs/Imu": "imu",
                "sensor_msgs/JointState": "wheels", "nav_msgs/Odometry": "odometry"}
DEFAULT_TYPES = {"gnss": "sensor_msgs/NavSatFix", "imu": "sensor_msgs/Imu",
                 "wheels": "sensor_msgs/JointState", "odometry": "nav_msgs/Odometry"}
#: the keys of campaign.yaml that turn wheel speeds into v and omega (metres)
WHEEL_KEYS = ("wheel_radius_m", "track_m")
#: the optional topics' default names (data contract part 1), read without a declaration
CONTRACT_TOPICS = {"gnss": "/gnss/fix", "imu": "/imu/data", "wheels": "/wheels/joint_states",
                   "odometry": "/odometry"}
GNSS_CSV = "gnss.csv"
COV_COLUMNS = ("cov_ee", "cov_en", "cov_eu", "cov_nn", "cov_nu", "cov_uu")
STD_COLUMNS = ("std_e", "std_n", "std_u")
_COV_INDEX = (0, 1, 2, 4, 5, 8)  # of a row-major 3x3 ENU covariance


@dataclass(frozen=True)
class SensorSpec:
    """One declared sensor."""

    name: str
    topic: str | None
    type: str
    lever_arm_body_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def kind(self) -> str:
        """Return ``gnss``, ``imu``, ``wheels`` or ``odometry``."""
        return SENSOR_TYPES[self.type]


@dataclass(frozen=True)
class SensorsConfig:
    """The sensor keys of a ``campaign.yaml``: declared sensors and the geodetic frame, if given."""

    sensors: tuple[SensorSpec, ...] = ()
    origin: GeodeticOrigin | None = None
    enu_to_local_yaw_deg: float | None = None
    enu_to_local_t_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wheel_radius_m: float | None = None  # the wheel geometry that turns wheel speeds into v, omega
    track_m: float | None = None

    def first(self, kind: str) -> SensorSpec | None:
        """Return the first declared sensor of ``kind``, or None."""
        return next((s for s in self.sensors if s.kind == kind), None)

    def sensor(self, kind: str) -> tuple[SensorSpec, bool]:
        """Return the first declared sensor of ``kind`` and True; without one, the data contract's
        default (part 1: its default topic name and type) and False. A run may carry an optional
        topic under its default name without any ``sensors:`` key, and a reader uses what is there."""
        spec = self.first(kind)
        if spec is not None:
            return spec, True
        return SensorSpec(kind, CONTRACT_TOPICS[kind], DEFAULT_TYPES[kind]), False

    def to_yaml(self) -> dict:
        """Return the keys as ``campaign.yaml`` carries them (for the trajectory campaign)."""
        out: dict = {}
        if self.sensors:
            out["sensors"] = [{"name": s.name, "topic": s.topic, "type": s.type,
                               "lever_arm_body_m": [float(v) for v in s.lever_arm_body_m]} for s in self.sensors]
        if self.origin is not None:
            out["geodetic_origin"] = self.origin.to_yaml()
        if self.enu_to_local_yaw_deg is not None:
            out["enu_to_local_yaw_deg"] = float(self.enu_to_local_yaw_deg)
            out["enu_to_local_t_m"] = [float(v) for v in self.enu_to_local_t_m]
        for key in WHEEL_KEYS:
            if getattr(self, key) is not None:
                out[key] = float(getattr(self, key))
        return out


def _numbers(value, n: int, what: str, source: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        out = ()
    if len(out) != n or not np.all(np.isfinite(out)):
        raise InputError(f"{source}: {what} must be {n} finite numbers, got {value!r}")
    return out


def _spec(entry, i: int, source: str) -> SensorSpec:
    if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
        raise InputError(f"{source}: sensors[{i}] has no 'name'")
    kind = entry.get("type", DEFAULT_TYPES.get(entry["name"]))
    if kind not in SENSOR_TYPES:
        raise InputError(f"{source}: sensor {entry['name']!r}: unknown type {kind!r} "
                         f"(known: {', '.join(SENSOR_TYPES)})")
    lever = _numbers(entry.get("lever_arm_body_m", (0.0, 0.0, 0.0)), 3, f"sensor {entry['name']!r} "
                     "lever_arm_body_m", source)
    topic = entry.get("topic")
    return SensorSpec(entry["name"], None if topic is None else str(topic), kind, lever)


def read_sensors_config(root: str | Path) -> SensorsConfig:
    """Return the sensor keys of ``root/campaign.yaml`` (nothing declared: an empty config).

    Raises
    ------
    InputError
        An unknown sensor type (named), a malformed entry, origin or transform.
    """
    file = Path(root) / "campaign.yaml"
    try:
        doc = yaml.safe_load(file.read_text()) if file.is_file() else {}
    except yaml.YAMLError as exc:
        raise InputError(f"{file}: not valid YAML ({str(exc).splitlines()[0]})") from None
    doc = doc if isinstance(doc, dict) else {}
    raw = doc.get("sensors") or []
    if isinstance(raw, dict):  # {name: topic}, the short form of the data contract
        raw = [{"name": k, "topic": v} for k, v in raw.items()]
    if not isinstance(raw, list):
        raise InputError(f"{file}: key 'sensors' must be a list or a mapping")
    sensors = tuple(_spec(e, i, str(file)) for i, e in enumerate(raw))
    origin = None if doc.get("geodetic_origin") is None else GeodeticOrigin.from_yaml(doc["geodetic_origin"], str(file))
    yaw = doc.get("enu_to_local_yaw_deg")
    if yaw is not None:
        yaw = _numbers([yaw], 1, "enu_to_local_yaw_deg", str(file))[0]
        if origin is None:
            raise InputError(f"{file}: enu_to_local_yaw_deg given without geodetic_origin")
    t = _numbers(doc.get("enu_to_local_t_m", (0.0, 0.0, 0.0)), 3, "enu_to_local_t_m", str(file))
    wheels = {}
    for key in WHEEL_KEYS:
        if doc.get(key) is not None:
            value = _numbers([doc[key]], 1, key, str(file))[0]
            if value <= 0:
                raise InputError(f"{file}: key '{key}' is {doc[key]!r}, expected a positive number of metres")
            wheels[key] = value
    return SensorsConfig(sensors, origin, yaw, t, **wheels)


@dataclass(frozen=True)
class GnssFixes:
    """Recorded fixes as the receiver gave them (geodetic), one row each."""

    t: np.ndarray  # (n,) time of validity (header stamp), UTC s
    t_arrival: np.ndarray  # (n,) when received (bag time), UTC s
    lla: np.ndarray  # (n, 3) lat_deg, lon_deg, alt_m
    cov_enu: np.ndarray  # (n, 3, 3) m^2
    status: np.ndarray  # (n,) int, NavSatStatus (-1 NO_FIX)

    def select(self, keep: np.ndarray) -> GnssFixes:
        """Return the fixes where ``keep``."""
        return GnssFixes(self.t[keep], self.t_arrival[keep], self.lla[keep], self.cov_enu[keep], self.status[keep])


def clean_fixes(fixes: GnssFixes, source: str) -> tuple[GnssFixes, dict[str, int]]:
    """Return the fixes without NO_FIX and non-finite ones, sorted by time, and the counts dropped
    (a fix whose header stamp was never set takes its bag time, counted as ``unstamped_receive_time``)."""
    t, unset = unstamped_to_receive(fixes.t, fixes.t_arrival)
    if unset:
        log.warning("%s: %d of %d GNSS fixes have no header stamp (zero); their bag times are taken", source,
                    unset, len(t))
        fixes = replace(fixes, t=t)
    no_fix = fixes.status < 0
    bad = ~no_fix & ~(np.all(np.isfinite(fixes.lla), 1) & np.isfinite(fixes.t)
                      & np.all(np.isfinite(fixes.cov_enu[:, :2, :2].reshape(-1, 4)), 1))
    counts = {"fixes": int(len(fixes.t)), "no_fix_dropped": int(no_fix.sum()), "nan_dropped": int(bad.sum()),
              "unstamped_receive_time": unset}
    if no_fix.any() or bad.any():
        log.info("%s: dropped %d NO_FIX and %d non-finite GNSS fixes", source, no_fix.sum(), bad.sum())
    kept = fixes.select(~no_fix & ~bad)
    order = np.argsort(kept.t, kind="stable")
    kept = kept.select(order)
    dup = np.concatenate([[False], np.diff(kept.t) == 0])
    counts["duplicates_dropped"] = int(dup.sum())
    return kept.select(~dup), counts


def read_csv_columns(path: Path, required: Sequence[str]) -> np.ndarray:
    """Return the CSV file ``path`` with a header line as a structured array (one field per column).

    Raises
    ------
    InputError
        Naming the file: unreadable, or a column of ``required`` missing.
    """
    try:
        header = csv_header(path)  # the names as the project reads them (quotes and a byte-order mark off)
        data = np.genfromtxt(path, delimiter=",", skip_header=1, names=header, dtype=float, ndmin=1,
                             encoding="utf-8-sig")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable CSV ({str(exc).splitlines()[-1].strip()})") from None
    names = data.dtype.names or ()
    missing = [c for c in required if c not in names]
    if missing:
        raise missing_column(path, missing[0], csv_header(path))
    for c in required:
        if (err := no_numbers(path, csv_header(path), c, data[c])) is not None:
            raise err
    return data


_UNREADABLE_SAID: set = set()  # (run, bags) whose unreadability topic_messages has logged


def topic_messages(bags: list[Path], topic: str, msgtype: str, run: str):
    """Yield ``(t_bag_ns, message)`` of ``topic`` across a run's bags (ROS1 bags read together,
    each ROS2 bag alone), in each reader's order; nothing when the topic is absent.

    Bags that rosbags cannot read (a truncated recording, whose tracker topics
    :mod:`identification.preprocessing.io_bags` salvages) give what was read before the damage, with
    a warning naming run, bags and topic: a sensor beside the ground truth is optional data.

    Raises
    ------
    InputError
        The topic recorded with another message type (names run, topic and type).
    """
    ros1 = [b for b in bags if b.suffix == ".bag"]
    for group in [ros1] + [[b] for b in bags if b.suffix != ".bag"]:
        if not group:
            continue
        try:
            with AnyReader(group, default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
                conns = [c for c in reader.connections if c.topic == topic]
                for c in conns:
                    if c.msgtype != msgtype:
                        raise InputError(f"run {run}: topic {topic} is {c.msgtype}, expected {msgtype}")
                for conn, t_bag, raw in reader.messages(connections=conns) if conns else ():  # none: all
                    yield t_bag, reader.deserialize(raw, conn.msgtype)
        except (AnyReaderError, ReaderError1, ReaderError2) as exc:
            key = (run, tuple(str(b) for b in group))
            if key not in _UNREADABLE_SAID:  # once per run and bags, not once per sensor topic asked for
                _UNREADABLE_SAID.add(key)
                log.warning("run %s: %s unreadable (%s); its sensor topics (%s, ...) not read from it", run,
                            ", ".join(b.name for b in group), str(exc).splitlines()[0], topic)


def read_navsat(bags: list[Path], topic: str, run: str) -> GnssFixes | None:
    """Return the ``sensor_msgs/NavSatFix`` messages of ``topic`` across a run's bags, or None if absent.

    Raises
    ------
    InputError
        The topic recorded with another message type (names run, topic and type).
    """
    parts = []
    for t_bag, m in topic_messages(bags, topic, "sensor_msgs/msg/NavSatFix", run):
        parts.append((m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, t_bag * 1e-9, m.latitude,
                      m.longitude, m.altitude, *np.asarray(m.position_covariance, float), m.status.status))
    if not parts:
        return None
    a = np.array(parts, dtype=float)
    return GnssFixes(a[:, 0], a[:, 1], a[:, 2:5], a[:, 5:14].reshape(-1, 3, 3), a[:, 14].astype(int))


def write_gnss_csv(path: str | Path, fixes: GnssFixes) -> Path:
    """Write ``gnss.csv`` (module docstring); return its path."""
    cov = fixes.cov_enu.reshape(-1, 9)[:, _COV_INDEX]
    buf = io.StringIO()
    body = np.column_stack([fixes.t, fixes.lla, cov, fixes.status, fixes.t_arrival])
    np.savetxt(buf, body, delimiter=",", fmt=["%.9f", "%.10f", "%.10f", "%.4f"] + ["%.6g"] * 6 + ["%d", "%.9f"],
               header=",".join(("t", "lat", "lon", "alt", *COV_COLUMNS, "status", "t_arrival")), comments="")
    Path(path).write_text(buf.getvalue())
    return Path(path)


def read_gnss_csv(path: str | Path) -> GnssFixes:
    """Return the fixes of a ``gnss.csv`` as written (NO_FIX and NaN rows kept: :func:`clean_fixes`).

    Raises
    ------
    InputError
        Naming the file: unreadable, a required column missing, neither covariance nor std columns.
    """
    path = Path(path)
    data = read_csv_columns(path, ("t", "lat", "lon", "alt"))
    names = data.dtype.names
    n = data.size
    cov = np.zeros((n, 9))
    if all(c in names for c in COV_COLUMNS):
        for c, k in zip(COV_COLUMNS, _COV_INDEX):
            cov[:, k] = data[c]
        cov[:, [3, 6, 7]] = cov[:, [1, 2, 5]]
    elif all(c in names for c in STD_COLUMNS):
        cov[:, [0, 4, 8]] = np.column_stack([data[c] for c in STD_COLUMNS]) ** 2
    else:
        raise InputError(f"{path}: needs columns {','.join(COV_COLUMNS)} or {','.join(STD_COLUMNS)}")
    status = np.nan_to_num(data["status"], nan=-1).astype(int) if "status" in names else np.zeros(n, int)
    t_arr = data["t_arrival"] if "t_arrival" in names else data["t"]
    t_arr = np.where(np.isfinite(t_arr), t_arr, data["t"])
    return GnssFixes(data["t"].copy(), t_arr.copy(), np.column_stack([data["lat"], data["lon"], data["alt"]]),
                     cov.reshape(-1, 3, 3), status)


def overlapping(fixes: GnssFixes, t_pose: np.ndarray, source: str) -> GnssFixes:
    """Return the fixes inside the poses' time span; InputError naming ``source`` when none is."""
    t_pose = np.asarray(t_pose, float)
    t_pose = t_pose[np.isfinite(t_pose)]
    keep = (fixes.t >= t_pose.min()) & (fixes.t <= t_pose.max()) if t_pose.size else np.zeros(len(fixes.t), bool)
    if not keep.any():
        span = f"[{fixes.t.min():.3f}, {fixes.t.max():.3f}]" if len(fixes.t) else "none"
        raise InputError(f"{source}: no GNSS fix inside the poses' time span (fixes {span} s, poses "
                         f"[{t_pose.min():.3f}, {t_pose.max():.3f}] s)")
    return fixes.select(keep)


def write_run_gnss(campaign_dir: Path, out_dir: Path, runs: dict[str, np.ndarray]) -> dict:
    """Write ``gnss.csv`` of each preprocessed run from the tracker campaign's bags; return counts per run.

    ``runs`` maps each written run (a part ``<run>.k`` of a cut run included) to its pose times.
    Without a declared GNSS, the data contract's default topic is read where a run has it.
    """
    config = read_sensors_config(campaign_dir)
    spec, declared = config.sensor(GNSS)
    topic = spec.topic or CONTRACT_TOPICS[GNSS]
    out = {}
    for name, t_pose in runs.items():
        folder = name if (campaign_dir / "runs" / name).is_dir() else name.rsplit(".", 1)[0]
        fixes = undeclared_guard(lambda: read_navsat(find_bags(campaign_dir / "runs" / folder), topic, name),
                                 declared, name, topic)
        if fixes is None:
            if declared:
                log.warning("run %s: no GNSS topic %s", name, topic)
            continue
        fixes, counts = clean_fixes(fixes, f"run {name}: topic {topic}")
        fixes = overlapping(fixes, t_pose, f"run {name}: topic {topic}")
        counts["written"] = int(len(fixes.t))
        write_gnss_csv(out_dir / "runs" / name / GNSS_CSV, fixes)
        out[name] = counts
    return out


def undeclared_guard(read, declared: bool, run: str, topic: str):
    """Return ``read()``; for a topic read under its default name without a declaration, None
    (logged) where it holds another message type than the contract's (a declared one's
    :class:`InputError` passes), and an INFO line where it is found."""
    if declared:
        return read()
    try:
        got = read()
    except InputError as exc:
        log.warning("run %s: %s; not read (declare the sensor under sensors: in campaign.yaml)", run, exc)
        return None
    if got is not None:
        log.info("run %s: %s read under the data contract's default name (no sensors: declaration)", run, topic)
    return got


def with_cov_enu(fixes: GnssFixes, cov_enu: np.ndarray) -> GnssFixes:
    """Return the fixes with other covariances (tests and profiles)."""
    return replace(fixes, cov_enu=np.asarray(cov_enu, float))
