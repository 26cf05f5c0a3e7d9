"""ROS1 Noetic bags of a simulated run, written with rosbags (data contract part 1, topics).

Messages are serialised in bulk: every topic here has a fixed wire layout (constant frame ids,
names and array lengths), so all of a run's messages of a topic are packed into one numpy
structured array and cut into messages, about 30 times faster than one
``typestore.serialize_ros1`` call per message. Each batch is checked against the rosbags
``ROS1_NOETIC`` typestore serialiser (first and last message byte for byte, and the test suite
compares whole batches). The bag container is ``rosbags.rosbag1.Writer`` (uncompressed chunks,
as ``rosbag record`` writes them). A bag's messages are written in order of their bag
time, the instant the recorder received them. Nothing in a bag depends on the wall clock:
the same inputs give the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Reader, Writer
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


def _string(text: str) -> list[tuple[str, str, object]]:
    """ROS1 string fields: uint32 length + bytes (as structured-array fields)."""
    raw = text.encode()
    return [("len", "<u4", len(raw))] + ([("str", f"S{len(raw)}", raw)] if raw else [])


def _pack(n: int, fields: list[tuple[str, str, object]]) -> list[bytes]:
    """Return ``n`` messages of a fixed layout, packed field by field into one buffer.

    ``fields`` are ``(name, numpy format, value)`` in wire order (ROS1: little endian, no
    padding); a value is a constant or an (n,)/(n, k) array. One ``tobytes`` for all messages
    replaces n Python-level serialisations; callers check the result against
    ``typestore.serialize_ros1`` (``_check``).
    """
    dtype = np.dtype([(f"{i}_{name}", fmt) for i, (name, fmt, _) in enumerate(fields)])
    table = np.zeros(n, dtype=dtype)
    for i, (name, _, value) in enumerate(fields):
        table[f"{i}_{name}"] = value
    raw = table.tobytes()
    size = dtype.itemsize
    return [raw[i * size:(i + 1) * size] for i in range(n)]


def _header_fields(stamp_ns: np.ndarray, frame_id: str) -> list[tuple[str, str, object]]:
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    return [("seq", "<u4", np.arange(stamp_ns.size, dtype=np.uint32)), ("sec", "<u4", stamp_ns // NS),
            ("nsec", "<u4", stamp_ns % NS)] + _string(frame_id)


def _check(raw: list[bytes], build, msgtype: str) -> list[bytes]:
    """Return ``raw`` after checking its first and last message against rosbags' serialiser."""
    ts = typestore()
    for i in {0, len(raw) - 1} if raw else ():
        expected = bytes(ts.serialize_ros1(build(i), msgtype))
        if raw[i] != expected:  # a layout bug must never reach a bag
            raise AssertionError(f"bulk serialisation of {msgtype} differs from rosbags at message {i}")
    return raw


def serialize_time_reference(stamp_ns: np.ndarray, time_ref_ns: np.ndarray, source: str) -> list[bytes]:
    """Return serialised ``sensor_msgs/TimeReference`` messages (``/rpi/trigger``)."""
    M = typestore().types["sensor_msgs/msg/TimeReference"]
    ref = np.asarray(time_ref_ns, dtype=np.int64)
    raw = _pack(ref.size, _header_fields(stamp_ns, "") + [("rsec", "<u4", ref // NS), ("rnsec", "<u4", ref % NS)]
                + _string(source))
    return _check(raw, lambda i: M(_header(i, int(stamp_ns[i]), ""), _time(int(ref[i])), source), M.__msgtype__)


def serialize_point_stamped(stamp_ns: np.ndarray, xyz: np.ndarray, frame_id: str) -> list[bytes]:
    """Return serialised ``geometry_msgs/PointStamped`` messages (tracker measurements)."""
    ts = typestore()
    M, P = ts.types["geometry_msgs/msg/PointStamped"], ts.types["geometry_msgs/msg/Point"]
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    raw = _pack(len(xyz), _header_fields(stamp_ns, frame_id) + [("xyz", "(3,)<f8", xyz)])
    return _check(raw, lambda i: M(_header(i, int(stamp_ns[i]), frame_id), P(*map(float, xyz[i]))), M.__msgtype__)


def serialize_joy(stamp_ns: np.ndarray, u_joy: np.ndarray) -> list[bytes]:
    """Return serialised ``sensor_msgs/Joy`` messages: ``axes[1]`` = u1, ``axes[0]`` = u2.

    The dead-man button is held whenever a stick is off centre, as the Husky teleop needs.
    """
    M = typestore().types["sensor_msgs/msg/Joy"]
    u_joy = np.asarray(u_joy, dtype=float).reshape(-1, 2)
    axes = np.zeros((len(u_joy), JOY_N_AXES), dtype=np.float32)
    axes[:, 1], axes[:, 0] = u_joy[:, 0], u_joy[:, 1]
    buttons = np.zeros((len(u_joy), JOY_N_BUTTONS), dtype=np.int32)
    buttons[:, JOY_ENABLE_BUTTON] = np.any(u_joy != 0.0, axis=1)
    raw = _pack(len(u_joy), _header_fields(stamp_ns, "") + [
        ("n_axes", "<u4", JOY_N_AXES), ("axes", f"({JOY_N_AXES},)<f4", axes),
        ("n_buttons", "<u4", JOY_N_BUTTONS), ("buttons", f"({JOY_N_BUTTONS},)<i4", buttons)])
    return _check(raw, lambda i: M(_header(i, int(stamp_ns[i]), ""), axes[i], buttons[i]), M.__msgtype__)


def serialize_joint_state(stamp_ns: np.ndarray, names: list[str], position: np.ndarray) -> list[bytes]:
    """Return serialised ``sensor_msgs/JointState`` messages (``/turning_hub/azimuth``)."""
    M = typestore().types["sensor_msgs/msg/JointState"]
    pos = np.ascontiguousarray(position, dtype=np.float64).reshape(len(stamp_ns), len(names))
    name_fields = [("n_names", "<u4", len(names))]
    for k, name in enumerate(names):
        name_fields += [(f"{f}{k}", fmt, v) for f, fmt, v in _string(name)]
    raw = _pack(len(pos), _header_fields(stamp_ns, "") + name_fields + [
        ("n_pos", "<u4", len(names)), ("pos", f"({len(names)},)<f8", pos),
        ("n_vel", "<u4", 0), ("n_eff", "<u4", 0)])
    empty = np.zeros(0, dtype=np.float64)
    return _check(raw, lambda i: M(_header(i, int(stamp_ns[i]), ""), list(names), pos[i], empty, empty),
                  M.__msgtype__)


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
    counts: dict[str, int] = {}
    for path in sorted(Path(run_dir).glob("*.bag")):
        with Reader(path) as reader:
            for conn in reader.connections:
                counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
    return dict(sorted(counts.items()))
