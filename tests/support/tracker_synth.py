"""Synthetic tracker runs with known truth, and a tiny bag writer, for the preprocessing tests.

Independent of :mod:`simulation`: a smooth drive, a 50 Hz trigger skipping one pulse in 150,
an LTD800 on the rising edge, an AT960 on the falling edge with a varying duty cycle, lost and
spurious pulses, drifting clocks. The truth is returned beside the run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from groundfloor.types import PointSeries
from identification.preprocessing.io_tracker import BagRun

T0_UTC = 1_671_600_000.0


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


R_LT = rot_z(np.deg2rad(142.7))
T_LT = np.array([-2.05, -8.76, -0.09])


def prisms(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return front and rear prism positions (local frame) at times ``s`` of a smooth drive."""
    g = np.arange(0.0, s.max() + 1.0, 1e-3)
    v = 0.8 * np.sin(2 * np.pi * g / 17.0) + 0.3 * np.sin(2 * np.pi * g / 5.3)
    psi = 0.6 * np.sin(2 * np.pi * g / 23.0) + 0.02 * g
    x, y = np.cumsum(v * np.cos(psi)) * 1e-3, np.cumsum(v * np.sin(psi)) * 1e-3
    xs, ys, ps = np.interp(s, g, x), np.interp(s, g, y), np.interp(s, g, psi)
    head = np.column_stack([np.cos(ps), np.sin(ps), 0 * ps])
    left = np.column_stack([-np.sin(ps), np.cos(ps), 0 * ps])
    base = np.column_stack([xs + 3.0, ys + 2.0, 0.3 + 0 * xs])
    return base + 0.25 * head + 0.05 * left, base - 0.25 * head - 0.04 * left + [0, 0, 0.05]


def synth_run(seed: int = 0, minutes: float = 1.0, drift_ltd_ppm: float = 16.2,
              drift_at_ppm: float = -28.5, duty_s: tuple[float, float] = (1.3e-3, 1.5e-3),
              p_lost: float = 0.01, p_spur: float = 0.005, noise_m: float = 10e-6,
              name: str = "run_01", receive: bool = True, R_at960_ltd800: np.ndarray = R_LT,
              t_at960_ltd800: np.ndarray = T_LT) -> tuple[BagRun, dict]:
    """Return a synthetic raw run and its truth (drifts in ppm, mean duty, lost/spurious).

    The LTD800 sees the front prism through ``x_at960 = t + R x_ltd800`` (eq. 5.1).
    """
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * 50)
    slot = np.arange(int(n * 1.01) + 2)
    slot = slot[(slot + 37) % 150 != 0][:n]
    s = slot * 0.02 + rng.normal(0, 10e-6, slot.size)
    k_l, k_a = 1 + drift_ltd_ppm * 1e-6, 1 + drift_at_ppm * 1e-6
    duty = rng.uniform(*duty_s, s.size)

    def tracker(s_meas, k, t_boot, jitter, lose, spur):
        keep = rng.random(s_meas.size) > lose
        extra = rng.uniform(s_meas[0], s_meas[-1], rng.poisson(spur * s_meas.size))
        sm = np.sort(np.concatenate([s_meas[keep], extra]))
        return sm, t_boot + sm / k + rng.normal(0, jitter, sm.size), int((~keep).sum()), extra.size

    sm_l, t_l, lost_l, spur_l = tracker(s, k_l, 5000.0, 0.2e-6, 0.0, 0.0)
    sm_a, t_a, lost_a, spur_a = tracker(s + duty, k_a, 77.7, 2e-6, p_lost, p_spur)
    front, _ = prisms(sm_l)
    _, rear = prisms(sm_a)
    front += rng.normal(0, noise_m, front.shape)
    rear += rng.normal(0, noise_m, rear.shape)
    x_ltd = (front - t_at960_ltd800) @ R_at960_ltd800  # R^T (x - t)
    t_joy = T0_UTC + np.sort(rng.uniform(0, s[-1], 400))
    rx = {"at960": T0_UTC + sm_a + 0.004, "ltd800": T0_UTC + sm_l + 0.004} if receive else {}
    raw = BagRun(name=name, split="train", t_trigger_utc=T0_UTC + s,
                 at960=PointSeries(t_tracker=t_a, xyz=rear), ltd800=PointSeries(t_tracker=t_l, xyz=x_ltd),
                 t_joy_utc=t_joy, u_joy=rng.uniform(-1, 1, (400, 2)),
                 t_hub_utc=T0_UTC + s[::25], hub_azimuth=rng.uniform(-3, 3, (s[::25].size, 2)),
                 t_receive_utc=rx)
    truth = {"drift_ltd_ppm": drift_ltd_ppm, "drift_at_ppm": drift_at_ppm,
             "mean_duty_s": float(np.mean(duty)), "lost_at960": lost_a, "spurious_at960": spur_a}
    return raw, truth


# --- bags -----------------------------------------------------------------------------------

def _messages(raw: BagRun, store, header_stamps=None):
    """Yield ``(topic, msgtype, bag_time_ns, message)`` of a raw run for a rosbags typestore;
    ``header_stamps`` (topic -> f): the Joy or hub message ``i`` of UTC ``t`` stamped ``f(i, t)``
    (received at ``t`` all the same), e.g. 0 for a stamp its publisher never set."""
    header_stamps = header_stamps or {}
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]

    def tm(sec):
        ns = int(round(sec * 1e9))
        return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def hd(sec, frame=""):
        return Header(stamp=tm(sec), frame_id=frame) if "seq" not in Header.__dataclass_fields__ \
            else Header(seq=0, stamp=tm(sec), frame_id=frame)

    TR, PS, P = T["sensor_msgs/msg/TimeReference"], T["geometry_msgs/msg/PointStamped"], T["geometry_msgs/msg/Point"]
    Joy, JS = T["sensor_msgs/msg/Joy"], T["sensor_msgs/msg/JointState"]
    # bag times: 0.3 ms after time_ref, or as given (a trigger clock that jumped: issue 14)
    rx_trigger = raw.t_receive_utc.get("trigger", raw.t_trigger_utc + 3e-4)
    for t, r in zip(raw.t_trigger_utc, rx_trigger):
        yield "/rpi/trigger", TR.__msgtype__, r, TR(header=hd(r), time_ref=tm(t), source="rpi")
    for tracker in ("at960", "ltd800"):
        ps = getattr(raw, tracker)
        rx = raw.t_receive_utc.get(tracker, raw.t_trigger_utc[0] + ps.t_tracker - ps.t_tracker[0])
        for t, p, r in zip(ps.t_tracker, ps.xyz, rx):
            yield (f"/{tracker}/measurement", PS.__msgtype__, r,
                   PS(header=hd(t, tracker), point=P(x=p[0], y=p[1], z=p[2])))
    def stamp(topic, i, t):
        return header_stamps[topic](i, t) if topic in header_stamps else t

    for i, (t, u) in enumerate(zip(raw.t_joy_utc, raw.u_joy)):
        axes = np.array([u[1], u[0], 0, 0], dtype=np.float32)
        yield "/joy_teleop/joy", Joy.__msgtype__, t, Joy(header=hd(stamp("/joy_teleop/joy", i, t)), axes=axes,
                                                          buttons=np.zeros(4, dtype=np.int32))
    for i, (t, a) in enumerate(zip(raw.t_hub_utc, raw.hub_azimuth)):
        yield "/turning_hub/azimuth", JS.__msgtype__, t, JS(
            header=hd(stamp("/turning_hub/azimuth", i, t)), name=["front", "rear"], position=np.asarray(a, float),
            velocity=np.zeros(0), effort=np.zeros(0))


def write_run_bags(run_dir: Path, raw: BagRun, ros2: bool = False, drop_topics=(), header_stamps=None) -> Path:
    """Write a raw run as bags: ROS1 split into a robot and a tracker bag, or one ROS2 folder
    (``header_stamps``: as :func:`_messages`)."""
    from rosbags.typesys import Stores, get_typestore

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    msgs = sorted((m for m in _messages(raw, store, header_stamps) if m[0] not in drop_topics), key=lambda m: m[2])
    if ros2:
        from rosbags.rosbag2 import Writer

        with Writer(run_dir / "bag_ros2", version=9) as w:
            conns = {}
            for topic, typ, t, msg in msgs:
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, typ, typestore=store)
                w.write(conns[topic], int(t * 1e9), store.serialize_cdr(msg, typ))
        return run_dir
    from rosbags.rosbag1 import Writer

    robot = [m for m in msgs if not m[0].endswith("/measurement")]
    trackers = [m for m in msgs if m[0].endswith("/measurement")]
    for fname, part in (("robot.bag", robot), ("trackers.bag", trackers)):
        with Writer(run_dir / fname) as w:
            conns = {}
            for topic, typ, t, msg in part:
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, typ, typestore=store)
                w.write(conns[topic], int(t * 1e9), store.serialize_ros1(msg, typ))
    return run_dir


def write_campaign(root: Path, raws: list[BagRun], calibration_text: str) -> Path:
    """Write a tracker campaign of the given runs (campaign.yaml, calibration.yaml, bags)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    meta = {"name": "synthetic", "runs": [{"name": r.name, "split": r.split} for r in raws]}
    (root / "campaign.yaml").write_text(yaml.safe_dump(meta))
    (root / "calibration.yaml").write_text(calibration_text)
    for r in raws:
        write_run_bags(root / "runs" / r.name, r)
    return root
