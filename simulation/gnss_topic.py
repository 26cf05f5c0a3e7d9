"""Recorded GNSS of a simulated run: ``sensor_msgs/NavSatFix`` around a geodetic origin (issue 16).

The fixes are those of :func:`simulation.gnss.simulate_gnss` (a profile's noise, bias, multipath
and latency; no scheduled outage: a recording has none) of the antenna on the true trajectory,
taken from the local frame to east-north-up by the inverse of the true ENU -> local transform
(:class:`groundfloor.geodetic.EnuToLocal`, yaw ``enu_to_local_yaw_deg``, the geodetic origin at
the local origin) and to WGS84 with pymap3d. ``header.stamp`` is the fix's time of validity, the
bag time its arrival; ``position_covariance`` is the profile's reported variance in ENU
(``COVARIANCE_TYPE_DIAGONAL_KNOWN``). A fraction ``bad_fraction`` of the fixes is spoilt, half
with status ``NO_FIX`` and half with NaN coordinates, so that readers' drop-and-count rule is
tested. The fixes go into their own bag per run (``gnss_<stamp>.bag``, or a ROS2 folder), so the
tracker bags keep their bytes; truth goes to ``truth/gnss.yaml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from groundfloor.errors import InputError
from groundfloor.geodetic import EnuToLocal, GeodeticOrigin, enu_to_geodetic
from simulation import bags
from simulation.gnss import PROFILES, simulate_gnss

NAVSAT_MSGTYPE = "sensor_msgs/msg/NavSatFix"
DEFAULT_TOPIC = "/gnss/fix"
SENSOR_TYPE = "sensor_msgs/NavSatFix"
# Vienna, TU Wien Karlsplatz: the campaign's site; ellipsoidal height in metres
DEFAULT_ORIGIN = GeodeticOrigin(48.19864, 16.36985, 220.0)
DEFAULT_ENU_TO_LOCAL_YAW_DEG = 27.5  # leveled AT960 x axis 27.5 deg north of east
DEFAULT_LEVER_ARM_BODY_M = (-0.2, 0.1, 0.5)  # as simulation.gnss.simulate_gnss
BAD_FRACTION = 0.01
STATUS_NO_FIX, STATUS_FIX = -1, 0
COVARIANCE_TYPE_DIAGONAL_KNOWN = 2


@dataclass(frozen=True)
class GnssTopicSpec:
    """What the simulator records as GNSS: profile, topic, origin, true transform, lever arm."""

    profile: str = "dgnss"
    topic: str = DEFAULT_TOPIC
    origin: GeodeticOrigin = DEFAULT_ORIGIN
    enu_to_local_yaw_deg: float = DEFAULT_ENU_TO_LOCAL_YAW_DEG
    lever_arm_body_m: tuple = DEFAULT_LEVER_ARM_BODY_M
    bad_fraction: float = BAD_FRACTION
    ros2: bool = False  # a ROS2 bag folder instead of a ROS1 bag

    @property
    def transform(self) -> EnuToLocal:
        """Return the true ENU -> local transform (origin at the local origin)."""
        return EnuToLocal(float(np.radians(self.enu_to_local_yaw_deg)), np.zeros(3))

    def campaign_entry(self) -> dict:
        """Return the ``sensors:`` entry of ``campaign.yaml``."""
        return {"name": "gnss", "topic": self.topic, "type": SENSOR_TYPE,
                "lever_arm_body_m": [float(v) for v in self.lever_arm_body_m]}


@dataclass(frozen=True)
class RecordedFixes:
    """One run's recorded fixes as the receiver published them."""

    t_valid_ns: np.ndarray  # (n,) int64 header stamps
    t_arrival_ns: np.ndarray  # (n,) int64 bag times
    lla: np.ndarray  # (n, 3) lat_deg, lon_deg, alt_m (NaN where spoilt)
    cov_enu: np.ndarray  # (n, 9) position_covariance, row-major ENU
    status: np.ndarray  # (n,) int8
    n_outliers: int  # fixes hit by multipath (generator truth)


def _to_ns(t_s: np.ndarray) -> np.ndarray:
    """Return UTC seconds as int64 ns, rounded to the microsecond (float64 holds ~0.2 us at 1.7e9 s)."""
    return np.round(np.asarray(t_s) * 1e6).astype(np.int64) * 1000


def record_fixes(t_utc_ns: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray, yaw: np.ndarray,
                 spec: GnssTopicSpec, seed: int) -> RecordedFixes:
    """Return the NavSatFix contents of one run from its true poses (local frame, UTC ns)."""
    t = np.asarray(t_utc_ns, np.int64)
    # epochs on the UTC time base, as the benchmark's internal simulation puts them: with the same
    # seed, the recorded fixes are the internal ones (bench/bench_recorded_gnss.py pairs them)
    t_s = t * 1e-9
    series = simulate_gnss(t_s, x, y, yaw, spec.profile, seed=seed, z=z, lever_arm_body=spec.lever_arm_body_m,
                           outages=np.empty((0, 2)))
    lla = enu_to_geodetic(spec.transform.inverse(series.p_local), spec.origin)
    n = len(series.t_valid)
    cov = np.zeros((n, 9))
    cov[:, [0, 4, 8]] = series.std ** 2
    status = np.full(n, STATUS_FIX, np.int8)
    rng = np.random.default_rng([seed, 16])
    n_bad = min(n, max(2, int(round(spec.bad_fraction * n)))) if spec.bad_fraction > 0 else 0
    bad = rng.choice(n, size=n_bad, replace=False)  # at least one NO_FIX and one NaN fix per run
    status[bad[::2]] = STATUS_NO_FIX
    lla[bad[1::2], :2] = np.nan
    return RecordedFixes(_to_ns(series.t_valid), _to_ns(series.t_arrival), lla, cov, status,
                         int(np.count_nonzero(series.flags)))


def _messages(fixes: RecordedFixes, ts) -> list:
    M, S = ts.types["sensor_msgs/msg/NavSatFix"], ts.types["sensor_msgs/msg/NavSatStatus"]
    H, T = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    out = []
    for i, stamp in enumerate(fixes.t_valid_ns.tolist()):
        stamp_msg = T(sec=stamp // bags.NS, nanosec=stamp % bags.NS)
        header = H(seq=i, stamp=stamp_msg, frame_id="gnss") if "seq" in H.__dataclass_fields__ \
            else H(stamp=stamp_msg, frame_id="gnss")  # ROS2 headers have no seq
        lat, lon, alt = (float(v) for v in fixes.lla[i])
        out.append(M(header, S(status=int(fixes.status[i]), service=1), lat, lon, alt,
                     fixes.cov_enu[i].astype(np.float64), COVARIANCE_TYPE_DIAGONAL_KNOWN))
    return out


def write_gnss_bag(path: str | Path, fixes: RecordedFixes, topic: str = DEFAULT_TOPIC, ros2: bool = False) -> Path:
    """Write the fixes as ``sensor_msgs/NavSatFix`` on ``topic``: a ROS1 bag, or a ROS2 folder."""
    path = Path(path)
    if not ros2:
        ts = bags.typestore()
        raw = [bytes(ts.serialize_ros1(m, NAVSAT_MSGTYPE)) for m in _messages(fixes, ts)]
        return bags.write_bag(path, [bags.TopicData(topic, NAVSAT_MSGTYPE, "/gnss_driver",
                                                    fixes.t_arrival_ns, raw)])
    ts = get_typestore(Stores.ROS2_HUMBLE)
    order = np.argsort(fixes.t_arrival_ns, kind="stable")
    msgs = _messages(fixes, ts)
    with Writer2(path, version=8) as writer:
        conn = writer.add_connection(topic, NAVSAT_MSGTYPE, typestore=ts)
        for i in order.tolist():
            writer.write(conn, int(fixes.t_arrival_ns[i]), bytes(ts.serialize_cdr(msgs[i], NAVSAT_MSGTYPE)))
    return path


def gnss_truth(spec: GnssTopicSpec, per_run: dict[str, RecordedFixes]) -> dict:
    """Return the content of ``truth/gnss.yaml``: the true origin, transform and what was spoilt."""
    return {"profile": spec.profile, "topic": spec.topic, "origin": spec.origin.to_yaml(),
            "enu_to_local_yaw_deg": float(spec.enu_to_local_yaw_deg), "enu_to_local_t_m": [0.0, 0.0, 0.0],
            "lever_arm_body_m": [float(v) for v in spec.lever_arm_body_m],
            "runs": {name: {"n_fixes": int(len(f.status)), "n_no_fix": int(np.sum(f.status == STATUS_NO_FIX)),
                            "n_nan": int(np.sum(np.isnan(f.lla[:, 0]) & (f.status != STATUS_NO_FIX))),
                            "n_outliers": f.n_outliers} for name, f in per_run.items()}}


def write_gnss_truth(campaign_dir: str | Path, truth: dict) -> Path:
    """Write ``truth/gnss.yaml``; return its path."""
    path = Path(campaign_dir) / "truth" / "gnss.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(truth, sort_keys=False, default_flow_style=None, width=100))
    return path


def check_gnss_spec(value) -> GnssTopicSpec | None:
    """Return the spec of ``simulate_campaign(gnss=...)``: None, a profile name or a spec."""
    if value is None or isinstance(value, GnssTopicSpec):
        return value
    if value not in PROFILES:
        raise InputError(f"gnss {value!r}: unknown GNSS profile (choose from {', '.join(PROFILES)})")
    return GnssTopicSpec(profile=value)
