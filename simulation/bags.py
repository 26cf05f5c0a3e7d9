"""ROS1 Noetic bags of a simulated run, written with rosbags (data contract part 1, topics).

Messages are built as rosbags ``ROS1_NOETIC`` typestore classes and serialised with
``typestore.serialize_ros1``; the bag container is ``rosbags.rosbag1.Writer`` (uncompressed
chunks, as ``rosbag record`` writes them). A bag's messages are written in order of their bag
time, the instant the recorder received them. Nothing in a bag depends on the wall clock:
the same inputs give the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

NS = 1_000_000_000
JOY_N_AXES = 8  # Logitech F710 in X-mode as used with the Husky teleop
JOY_N_BUTTONS = 11
JOY_ENABLE_BUTTON = 4  # LB: the Husky teleop's dead-man button


@lru_cache(maxsize=1)
def typestore():
    """Return the ROS1 Noetic typestore (cached)."""
    return get_typestore(Stores.ROS1_NOETIC)


@dataclass(frozen=True)
class TopicData:
    """Serialised messages of one topic and their bag (receive) times."""

    topic: str
    msgtype: str  # rosbags name, e.g. "geometry_msgs/msg/PointStamped"
    callerid: str  # publishing node, stored in the connection header
    t_receive_ns: np.ndarray  # (n,) int64 UTC ns
    raw: list[bytes]


def _time(ns: int):
    T = typestore().types["builtin_interfaces/msg/Time"]
    return T(sec=int(ns // NS), nanosec=int(ns % NS))


def _header(seq: int, stamp_ns: int, frame_id: str):
    H = typestore().types["std_msgs/msg/Header"]
    return H(seq=seq, stamp=_time(stamp_ns), frame_id=frame_id)


def serialize_time_reference(stamp_ns: np.ndarray, time_ref_ns: np.ndarray, source: str) -> list[bytes]:
    """Return serialised ``sensor_msgs/TimeReference`` messages (``/rpi/trigger``)."""
    ts = typestore()
    M = ts.types["sensor_msgs/msg/TimeReference"]
    return [
        bytes(ts.serialize_ros1(M(_header(i, s, ""), _time(r), source), M.__msgtype__))
        for i, (s, r) in enumerate(zip(stamp_ns.tolist(), time_ref_ns.tolist()))
    ]


def serialize_point_stamped(stamp_ns: np.ndarray, xyz: np.ndarray, frame_id: str) -> list[bytes]:
    """Return serialised ``geometry_msgs/PointStamped`` messages (tracker measurements)."""
    ts = typestore()
    M = ts.types["geometry_msgs/msg/PointStamped"]
    P = ts.types["geometry_msgs/msg/Point"]
    return [
        bytes(ts.serialize_ros1(M(_header(i, s, frame_id), P(x=p[0], y=p[1], z=p[2])), M.__msgtype__))
        for i, (s, p) in enumerate(zip(stamp_ns.tolist(), xyz.tolist()))
    ]


def serialize_joy(stamp_ns: np.ndarray, u_joy: np.ndarray) -> list[bytes]:
    """Return serialised ``sensor_msgs/Joy`` messages: ``axes[1]`` = u1, ``axes[0]`` = u2.

    The dead-man button is held whenever a stick is off centre, as the Husky teleop needs.
    """
    ts = typestore()
    M = ts.types["sensor_msgs/msg/Joy"]
    axes = np.zeros((len(u_joy), JOY_N_AXES), dtype=np.float32)
    axes[:, 1], axes[:, 0] = u_joy[:, 0], u_joy[:, 1]
    buttons = np.zeros((len(u_joy), JOY_N_BUTTONS), dtype=np.int32)
    buttons[:, JOY_ENABLE_BUTTON] = np.any(u_joy != 0.0, axis=1)
    return [
        bytes(ts.serialize_ros1(M(_header(i, s, ""), axes[i], buttons[i]), M.__msgtype__))
        for i, s in enumerate(stamp_ns.tolist())
    ]


def serialize_joint_state(stamp_ns: np.ndarray, names: list[str], position: np.ndarray) -> list[bytes]:
    """Return serialised ``sensor_msgs/JointState`` messages (``/turning_hub/azimuth``)."""
    ts = typestore()
    M = ts.types["sensor_msgs/msg/JointState"]
    empty = np.zeros(0, dtype=np.float64)
    pos = np.ascontiguousarray(position, dtype=np.float64)
    return [
        bytes(ts.serialize_ros1(M(_header(i, s, ""), list(names), pos[i], empty, empty), M.__msgtype__))
        for i, s in enumerate(stamp_ns.tolist())
    ]


def write_bag(path: str | Path, topics: list[TopicData]) -> Path:
    """Write one ROS1 bag holding ``topics``, messages in order of bag time; return its path.

    Ties in bag time keep the order of ``topics`` and of the messages within a topic, so the
    output is a pure function of the input.
    """
    path = Path(path)
    ts = typestore()
    t_all = np.concatenate([np.asarray(t.t_receive_ns, dtype=np.int64) for t in topics])
    which = np.concatenate([np.full(len(t.raw), k) for k, t in enumerate(topics)])
    index = np.concatenate([np.arange(len(t.raw)) for t in topics])
    order = np.lexsort((index, which, t_all))
    writer = Writer(path)
    writer.open()
    try:
        conns = [
            writer.add_connection(t.topic, t.msgtype, typestore=ts, callerid=t.callerid, latching=0)
            for t in topics
        ]
        raws = [t.raw for t in topics]
        for k, i, tns in zip(which[order].tolist(), index[order].tolist(), t_all[order].tolist()):
            writer.write(conns[k], tns, raws[k][i])
    finally:
        writer.close()
    return path


def count_messages(run_dir: str | Path) -> dict[str, int]:
    """Return the number of messages per topic over all ROS1 bags of a run folder."""
    from rosbags.rosbag1 import Reader

    counts: dict[str, int] = {}
    for path in sorted(Path(run_dir).glob("*.bag")):
        with Reader(path) as reader:
            for conn in reader.connections:
                counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
    return dict(sorted(counts.items()))
