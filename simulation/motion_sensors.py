"""Recorded IMU gyro and wheel odometry of a simulated run (issue 16), from the true states.

IMU (``sensor_msgs/Imu``): ``angular_velocity.z`` is the true yaw rate plus a bias and white
noise, ``wz = omega + b(t) + n``; the bias is a constant drawn per run (std
``bias_std_rad_s``) plus a slow random walk (density ``bias_walk_rad_s_sqrt_s``), the noise has
std ``noise_std_rad_s`` per sample. ``linear_acceleration`` x, y is the body acceleration
(``vx_dot - vy omega``, ``vy_dot + vx omega``) plus white noise; no orientation
(``orientation_covariance[0] = -1``, the ROS convention). The stated
``angular_velocity_covariance`` is the white noise's variance: the bias is not stated (a
receiver of the message has to estimate it).

Wheel odometry (``nav_msgs/Odometry``, twist only): the two track speeds a skid-steered robot
needs for its motion, ``v_r,l = vx +- omega B_eff / 2``, read by the encoders with longitudinal
slip ``s = slip_const + slip_per_rad_s |omega|`` (the tracks turn faster than the ground moves)
plus white noise, and turned into ``v = (v_r + v_l) / 2`` and ``omega = (v_r - v_l) / B_cal`` with
the calibrated effective track width ``B_cal = B_eff / (1 + width_error)``. So ``v`` is ``vx``
scaled by ``1 + s`` and ``omega`` is the yaw rate scaled by ``(1 + s)(1 + width_error)``: not the
body velocity exactly. ``twist.covariance`` states the white noise only.

Both go into their own bag per run (``motion_<stamp>.bag``, or a ROS2 folder), so the tracker
bags keep their bytes; the generator's truth (bias per run, sampled at 1 Hz, slip and width
error) goes to ``truth/motion_sensors.yaml``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from simulation import bags

IMU_MSGTYPE = "sensor_msgs/msg/Imu"
ODOMETRY_MSGTYPE = "nav_msgs/msg/Odometry"
IMU_TYPE, ODOMETRY_TYPE = "sensor_msgs/Imu", "nav_msgs/Odometry"
BIAS_TRUTH_STEP_S = 1.0  # the true bias is recorded at this step (truth/motion_sensors.yaml)


@dataclass(frozen=True)
class ImuSpec:
    """What the simulator records as IMU: topic, rate, gyro bias and noise, accelerometer noise."""

    topic: str = "/imu/data"
    rate_hz: float = 100.0
    noise_std_rad_s: float = 0.005  # white gyro noise per sample
    bias_std_rad_s: float = 0.01  # the constant bias of a run is drawn with this std (0.57 deg/s)
    bias_rad_s: float | None = None  # a given constant bias instead of a drawn one
    bias_walk_rad_s_sqrt_s: float = 2e-4  # random-walk density of the bias
    accel_noise_std_m_s2: float = 0.05
    ros2: bool = False

    def campaign_entry(self) -> dict:
        """Return the ``sensors:`` entry of ``campaign.yaml``."""
        return {"name": "imu", "topic": self.topic, "type": IMU_TYPE}


@dataclass(frozen=True)
class OdometrySpec:
    """What the simulator records as wheel odometry: topic, rate, slip, track-width error, noise."""

    topic: str = "/wheel_odom"
    rate_hz: float = 50.0
    track_width_eff_m: float = 0.87  # effective track width of a skid-steered Husky (1.5 x 0.58 m)
    width_error: float = 0.03  # calibration error of the track width the odometry is computed with
    slip_const: float = 0.02
    slip_per_rad_s: float = 0.03
    noise_std_m_s: float = 0.01  # white noise per track speed
    ros2: bool = False

    def campaign_entry(self) -> dict:
        """Return the ``sensors:`` entry of ``campaign.yaml``."""
        return {"name": "odometry", "topic": self.topic, "type": ODOMETRY_TYPE}

    @property
    def track_width_cal_m(self) -> float:
        """Return the track width the odometry is computed with."""
        return self.track_width_eff_m / (1.0 + self.width_error)

    @property
    def stated_std(self) -> tuple[float, float]:
        """Return the stated std of ``v`` (m/s) and ``omega`` (rad/s) from the track-speed noise."""
        s = self.noise_std_m_s
        return s / np.sqrt(2.0), s * np.sqrt(2.0) / self.track_width_cal_m


@dataclass(frozen=True)
class ImuSamples:
    """One run's IMU messages and the true bias."""

    t_ns: np.ndarray  # (n,) int64 header stamps = bag times
    wz: np.ndarray  # (n,) rad/s
    a_xy: np.ndarray  # (n, 2) m/s^2
    bias: np.ndarray  # (n,) true gyro bias, rad/s
    noise_std_rad_s: float
    accel_noise_std_m_s2: float


@dataclass(frozen=True)
class OdometrySamples:
    """One run's wheel-odometry messages and their true slip."""

    t_ns: np.ndarray  # (n,) int64
    v: np.ndarray  # (n,) m/s
    omega: np.ndarray  # (n,) rad/s
    slip: np.ndarray  # (n,) true longitudinal slip
    std: tuple[float, float]  # stated std of v, omega


def _grid_ns(t_utc_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    step = int(round(1e9 / rate_hz))
    t = np.asarray(t_utc_ns, np.int64)
    return np.arange(t[0] - t[0] % step + step, t[-1], step, dtype=np.int64)


def record_imu(t_utc_ns, vx, vy, omega, spec: ImuSpec, rng: np.random.Generator) -> ImuSamples:
    """Return the IMU samples of one run from its true body velocities at ``t_utc_ns``."""
    t_true = (np.asarray(t_utc_ns, np.int64) - int(t_utc_ns[0])) * 1e-9
    t_ns = _grid_ns(t_utc_ns, spec.rate_hz)
    t = (t_ns - int(t_utc_ns[0])) * 1e-9
    om, v_x, v_y = (np.interp(t, t_true, np.asarray(a, float)) for a in (omega, vx, vy))
    dt = 1.0 / spec.rate_hz
    walk = np.cumsum(rng.normal(0.0, spec.bias_walk_rad_s_sqrt_s * np.sqrt(dt), t.size))
    b0 = rng.normal(0.0, spec.bias_std_rad_s)
    bias = (b0 if spec.bias_rad_s is None else spec.bias_rad_s) + walk
    wz = om + bias + rng.normal(0.0, spec.noise_std_rad_s, t.size)
    a_body = np.column_stack([np.gradient(v_x, t) - v_y * om, np.gradient(v_y, t) + v_x * om])
    a_xy = a_body + rng.normal(0.0, spec.accel_noise_std_m_s2, a_body.shape)
    return ImuSamples(t_ns, wz, a_xy, bias, spec.noise_std_rad_s, spec.accel_noise_std_m_s2)


def record_odometry(t_utc_ns, vx, omega, spec: OdometrySpec, rng: np.random.Generator) -> OdometrySamples:
    """Return the wheel odometry of one run from its true ``vx``, ``omega`` (module docstring)."""
    t_true = (np.asarray(t_utc_ns, np.int64) - int(t_utc_ns[0])) * 1e-9
    t_ns = _grid_ns(t_utc_ns, spec.rate_hz)
    t = (t_ns - int(t_utc_ns[0])) * 1e-9
    v_x, om = np.interp(t, t_true, np.asarray(vx, float)), np.interp(t, t_true, np.asarray(omega, float))
    slip = spec.slip_const + spec.slip_per_rad_s * np.abs(om)
    half = 0.5 * spec.track_width_eff_m * om
    v_r = (v_x + half) * (1.0 + slip) + rng.normal(0.0, spec.noise_std_m_s, t.size)
    v_l = (v_x - half) * (1.0 + slip) + rng.normal(0.0, spec.noise_std_m_s, t.size)
    return OdometrySamples(t_ns, 0.5 * (v_r + v_l), (v_r - v_l) / spec.track_width_cal_m, slip, spec.stated_std)


def _header(ts, seq: int, stamp: int, frame: str):
    H, T = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    stamp_msg = T(sec=stamp // bags.NS, nanosec=stamp % bags.NS)
    return H(seq=seq, stamp=stamp_msg, frame_id=frame) if "seq" in H.__dataclass_fields__ \
        else H(stamp=stamp_msg, frame_id=frame)  # ROS2 headers have no seq


def _imu_messages(s: ImuSamples, ts) -> list:
    M, V, Q = (ts.types[k] for k in ("sensor_msgs/msg/Imu", "geometry_msgs/msg/Vector3",
                                     "geometry_msgs/msg/Quaternion"))
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0
    cov_w = np.diag([1e6, 1e6, s.noise_std_rad_s ** 2]).ravel()  # only z is measured
    cov_a = np.diag([s.accel_noise_std_m_s2 ** 2] * 2 + [1e6]).ravel()
    return [M(_header(ts, i, stamp, "imu"), Q(x=0.0, y=0.0, z=0.0, w=1.0), no_orientation,
              V(x=0.0, y=0.0, z=float(s.wz[i])), cov_w, V(x=float(s.a_xy[i, 0]), y=float(s.a_xy[i, 1]), z=0.0),
              cov_a) for i, stamp in enumerate(s.t_ns.tolist())]


def _odometry_messages(s: OdometrySamples, ts) -> list:
    M, V = ts.types["nav_msgs/msg/Odometry"], ts.types["geometry_msgs/msg/Vector3"]
    PC, P, Pt, Q = (ts.types[k] for k in ("geometry_msgs/msg/PoseWithCovariance", "geometry_msgs/msg/Pose",
                                          "geometry_msgs/msg/Point", "geometry_msgs/msg/Quaternion"))
    TC, Tw = ts.types["geometry_msgs/msg/TwistWithCovariance"], ts.types["geometry_msgs/msg/Twist"]
    pose = PC(P(Pt(x=0.0, y=0.0, z=0.0), Q(x=0.0, y=0.0, z=0.0, w=1.0)), np.diag([1e6] * 6).ravel())
    cov = np.diag([s.std[0] ** 2, 1e6, 1e6, 1e6, 1e6, s.std[1] ** 2]).ravel()  # v_y unobserved
    return [M(_header(ts, i, stamp, "odom"), "base_link", pose,
              TC(Tw(V(x=float(s.v[i]), y=0.0, z=0.0), V(x=0.0, y=0.0, z=float(s.omega[i]))), cov))
            for i, stamp in enumerate(s.t_ns.tolist())]


def write_motion_bag(path: str | Path, imu: ImuSamples | None, odometry: OdometrySamples | None,
                     imu_topic: str = ImuSpec.topic, odometry_topic: str = OdometrySpec.topic,
                     ros2: bool = False) -> Path:
    """Write the IMU and/or odometry messages (bag time = stamp): a ROS1 bag or a ROS2 folder."""
    path = Path(path)
    ts = bags.typestore() if not ros2 else get_typestore(Stores.ROS2_HUMBLE)
    parts = []
    if imu is not None:
        parts.append((imu_topic, IMU_MSGTYPE, "/imu_driver", imu.t_ns, _imu_messages(imu, ts)))
    if odometry is not None:
        parts.append((odometry_topic, ODOMETRY_MSGTYPE, "/husky_velocity_controller", odometry.t_ns,
                      _odometry_messages(odometry, ts)))
    if not ros2:
        return bags.write_bag(path, [bags.TopicData(topic, mt, caller, t_ns,
                                                    [bytes(ts.serialize_ros1(m, mt)) for m in msgs])
                                     for topic, mt, caller, t_ns, msgs in parts])
    with Writer2(path, version=8) as writer:
        conns = [writer.add_connection(topic, mt, typestore=ts) for topic, mt, *_ in parts]
        t_all = np.concatenate([p[3] for p in parts])
        which = np.concatenate([np.full(len(p[3]), k) for k, p in enumerate(parts)])
        index = np.concatenate([np.arange(len(p[3])) for p in parts])
        for k, i, tns in zip(*(a[np.lexsort((index, which, t_all))].tolist() for a in (which, index, t_all))):
            mt = parts[k][1]
            writer.write(conns[k], tns, bytes(ts.serialize_cdr(parts[k][4][i], mt)))
    return path


def motion_truth(imu: ImuSpec | None, odometry: OdometrySpec | None, per_run: dict) -> dict:
    """Return the content of ``truth/motion_sensors.yaml``: the specs and, per run, the true bias and slip.

    ``per_run`` maps a run to ``(ImuSamples | None, OdometrySamples | None)``.
    """
    runs = {}
    for name, (im, od) in per_run.items():
        entry = {}
        if im is not None:
            t = (im.t_ns - im.t_ns[0]) * 1e-9
            t_s = np.arange(0.0, t[-1], BIAS_TRUTH_STEP_S)
            entry["imu"] = {"n_samples": int(t.size), "t0_utc_ns": int(im.t_ns[0]),
                            "bias_step_s": BIAS_TRUTH_STEP_S,
                            "bias_rad_s": [round(float(b), 9) for b in np.interp(t_s, t, im.bias)],
                            "bias_mean_rad_s": float(im.bias.mean())}
        if od is not None:
            entry["odometry"] = {"n_samples": int(od.t_ns.size), "slip_mean": float(od.slip.mean()),
                                 "v_scale_mean": float(1.0 + od.slip.mean())}
        runs[name] = entry
    return {"imu": None if imu is None else asdict(imu), "odometry": None if odometry is None else asdict(odometry),
            "runs": runs}


def write_motion_truth(campaign_dir: str | Path, truth: dict) -> Path:
    """Write ``truth/motion_sensors.yaml``; return its path."""
    path = Path(campaign_dir) / "truth" / "motion_sensors.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(truth, sort_keys=False, default_flow_style=None, width=100))
    return path


def true_bias(truth: dict, run: str, t_utc: np.ndarray) -> np.ndarray:
    """Return the true gyro bias of ``run`` at UTC seconds ``t_utc`` from ``truth/motion_sensors.yaml``."""
    im = truth["runs"][run]["imu"]
    b = np.asarray(im["bias_rad_s"], float)
    t = im["t0_utc_ns"] * 1e-9 + np.arange(b.size) * im["bias_step_s"]
    return np.interp(np.asarray(t_utc, float), t, b)
