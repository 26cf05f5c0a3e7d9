"""The known topics of a run's bags as columns of numbers, in stored (receive) order.

A run's topics may be spread over several bags (ROS1 ``.bag`` files and/or ROS2 bag folders);
every topic is looked up by name across all of them, with rosbags. A known topic recorded with
another message type is a one-line :class:`InputError` naming the topic and both types, raised
before a single message is decoded. A ROS1 bag that rosbags cannot open or read to its end (cut
off, no index) is read up to the damage (:mod:`identification.preprocessing.io_bag_salvage`)
and the damage reported as a :class:`Truncation`.

Nothing here orders, checks or interprets the stamps: that is
:mod:`identification.preprocessing.stamp_order` and :mod:`identification.preprocessing.io_tracker`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from groundfloor.errors import InputError
from identification.preprocessing.io_bag_salvage import salvage_ros1
from identification.preprocessing.stamp_order import TopicColumns

log = logging.getLogger(__name__)

TOPIC_TRIGGER = "/rpi/trigger"
TOPIC_AT960 = "/at960/measurement"
TOPIC_LTD800 = "/ltd800/measurement"
TOPIC_JOY = "/joy_teleop/joy"
TOPIC_HUB = "/turning_hub/azimuth"
# the message type of each known topic (data contract), as rosbags names them
TOPIC_TYPES = {TOPIC_TRIGGER: "sensor_msgs/msg/TimeReference",
               TOPIC_AT960: "geometry_msgs/msg/PointStamped",
               TOPIC_LTD800: "geometry_msgs/msg/PointStamped",
               TOPIC_JOY: "sensor_msgs/msg/Joy",
               TOPIC_HUB: "sensor_msgs/msg/JointState"}

# ROS1 md5sums of the standard definitions: only these take the vectorised byte-level path
_FAST_ROS1 = {"geometry_msgs/msg/PointStamped": "c63aecb41bfdfd6b7e1fac37c7cbe7bf",
              "sensor_msgs/msg/TimeReference": "fded64a0265108ba86c3d38fb11c0c16",
              "sensor_msgs/msg/Joy": "5a9ea5f83505693b71e785041e67a8bb",
              "sensor_msgs/msg/JointState": "3066dcd76a6cfaef579bd0f34173e9fd"}


@dataclass(frozen=True)
class Truncation:
    """A bag read only up to its damage."""

    bag: str  # file name
    messages: int  # messages of the known topics read from it
    stopped_at_byte: int
    size_bytes: int
    reason: str

    def describe(self) -> str:
        """Return ``bag B truncated: ...; N messages read`` for messages and summaries."""
        return (f"bag {self.bag} truncated ({self.reason}); read up to byte {self.stopped_at_byte} "
                f"of {self.size_bytes}: {self.messages} messages")

    def to_dict(self) -> dict:
        """Return the truncation as a plain dict for JSON."""
        return dict(self.__dict__)


@dataclass
class _Topic:
    """Messages of one topic gathered across bags: raw ROS1 bytes (fast path) or deserialised."""

    msgtype: str = ""
    entries: list = field(default_factory=list)
    t_bag_ns: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.entries)


def _check_type(run: str, topic: str, msgtype: str) -> None:
    expected = TOPIC_TYPES[topic]
    if msgtype != expected:
        raise InputError(f"run {run}: topic {topic}: type {msgtype}, expected {expected}")


def _read_group(group: list[Path], run: str) -> dict[str, _Topic]:
    """Return the known topics of bags rosbags reads as one recording (several ROS1 bags or one
    ROS2 folder); a damaged bag raises whatever rosbags raises."""
    out = {t: _Topic() for t in TOPIC_TYPES}
    with AnyReader(group, default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        conns = [c for c in reader.connections if c.topic in out]
        for conn in conns:
            _check_type(run, conn.topic, conn.msgtype)
        fast = {c.id for c in conns if not reader.is2 and _FAST_ROS1.get(c.msgtype) == c.digest}
        # rosbags reads every connection when given none: a recording without a known topic
        for conn, t_bag_ns, raw in reader.messages(connections=conns) if conns else ():
            topic = out[conn.topic]
            topic.msgtype = conn.msgtype
            topic.entries.append(bytes(raw) if conn.id in fast else reader.deserialize(raw, conn.msgtype))
            topic.t_bag_ns.append(t_bag_ns)
    return out


def _salvage(bag: Path, run: str, error: str) -> tuple[dict[str, _Topic], Truncation]:
    """Return the known topics of a damaged ROS1 bag up to the damage, and the damage; a bag with
    nothing readable (empty, not a bag, its header damaged) gives no topics, with a warning: a
    recorder killed at its start leaves such a file beside the run's good bags."""
    try:
        found = salvage_ros1(bag, set(TOPIC_TYPES))
    except InputError as exc:  # not a ROS1 bag at all
        return _unreadable(bag, run, str(exc).split(": ", 1)[-1])
    if not found.messages:
        return _unreadable(bag, run, f"cannot read bag ({error})")
    out = {t: _Topic() for t in TOPIC_TYPES}
    for m in found.messages:
        _check_type(run, m.topic, m.msgtype)
        if m.md5sum != _FAST_ROS1[m.msgtype]:
            raise InputError(f"{bag}: topic {m.topic}: message definition of {m.msgtype} differs from "
                             "ROS Noetic's; a damaged bag of it cannot be read")
        topic = out[m.topic]
        topic.msgtype = m.msgtype
        topic.entries.append(m.raw)
        topic.t_bag_ns.append(m.t_bag_ns)
    cut = Truncation(bag=bag.name, messages=len(found.messages), stopped_at_byte=found.stopped_at_byte,
                     size_bytes=found.size_bytes, reason=found.reason or f"no readable index: {error}")
    log.warning("run %s: %s", run, cut.describe())
    return out, cut


def _unreadable(bag: Path, run: str, reason: str) -> tuple[dict[str, _Topic], Truncation]:
    """Return no topics and the record of a bag (file or ROS2 folder) of which nothing could be read (logged)."""
    size = bag.stat().st_size if bag.is_file() else sum(f.stat().st_size for f in bag.rglob("*") if f.is_file())
    cut = Truncation(bag=bag.name, messages=0, stopped_at_byte=0, size_bytes=size, reason=reason)
    log.warning("run %s: bag %s unreadable (%s): 0 messages; the run's other bags are read", run, bag.name, reason)
    return {t: _Topic() for t in TOPIC_TYPES}, cut


def read_topics(bags: list[Path], run: str) -> tuple[dict[str, _Topic], list[Truncation]]:
    """Return the known topics gathered across all bags of a run, and the bags read only in part.

    Raises
    ------
    InputError
        A known topic with another message type (names topic and both types). A bag of which
        nothing can be read is left out (a warning, and a record of 0 messages among the returned).
    """
    # AnyReader opens several ROS1 bags together but reads ROS2 folders one recording at a time.
    ros1 = [b for b in bags if b.suffix == ".bag"]
    groups = [ros1] + [[b] for b in bags if b.suffix != ".bag"]
    found, truncated = [], []
    for group in (g for g in groups if g):
        try:
            found.append(_read_group(group, run))
            continue
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged bag is bad input, named by file
            error = f"{type(exc).__name__}: {exc}"
            if group is not ros1:  # a ROS2 recording rosbags cannot open: the run's other bags are read
                topics, cut = _unreadable(group[0], run, f"cannot read bag ({error})")
                found.append(topics)
                truncated.append(cut)
                continue
        for bag in group:  # find the damaged ROS1 bag(s) and read the rest of them whole
            try:
                found.append(_read_group([bag], run))
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001
                topics, cut = _salvage(bag, run, f"{type(exc).__name__}: {exc}")
                found.append(topics)
                truncated.append(cut)
    out = {t: _Topic() for t in TOPIC_TYPES}
    for topics in found:
        for name, topic in topics.items():
            out[name].msgtype = topic.msgtype or out[name].msgtype
            out[name].entries += topic.entries
            out[name].t_bag_ns += topic.t_bag_ns
    return out, truncated


def topics_of_type(bags: list[Path], msgtype: str) -> list[str]:
    """Return the topics of ``msgtype`` recorded in ``bags`` (their connections only; a bag that
    cannot be opened is passed over), sorted: where a required topic went under another name."""
    names: set[str] = set()
    for bag in bags:
        try:
            with AnyReader([bag], default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
                names |= {c.topic for c in reader.connections if c.msgtype == msgtype}
        except Exception:  # noqa: BLE001 - only a hint: the caller's error stands without it
            continue
    return sorted(names)


def _stamp(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _ros1_columns(raw: list[bytes], msgtype: str) -> np.ndarray | None:
    """Return (n, k) float64 columns parsed from uniform ROS1 messages, or None if not uniform.

    PointStamped -> [stamp, x, y, z]; TimeReference -> [time_ref]; Joy -> [stamp, axes[1],
    axes[0]]; JointState -> [stamp, position of "front", position of "rear"]. One
    ``np.frombuffer`` over all messages instead of one Python deserialisation per message (the
    bags hold ~10^5). Messages of differing layout (lengths, names) return None: the caller then
    takes the generic rosbags path, which also reports what is wrong with them.
    """
    size = len(raw[0])
    if any(len(r) != size for r in raw):
        return None
    buf = np.frombuffer(b"".join(raw), dtype=np.uint8).reshape(len(raw), size)

    def u4(col: int) -> np.ndarray:
        return buf[:, col:col + 4].copy().view("<u4")[:, 0]

    flen = u4(12)  # header: seq, sec, nsec, frame_id length
    if np.any(flen != flen[0]):
        return None
    off = 16 + int(flen[0])
    stamp = u4(4) + u4(8) * 1e-9
    if msgtype == "geometry_msgs/msg/PointStamped":
        return np.column_stack([stamp, buf[:, off:off + 24].copy().view("<f8")])
    if msgtype == "sensor_msgs/msg/TimeReference":
        return (u4(off) + u4(off + 4) * 1e-9)[:, None]
    if msgtype == "sensor_msgs/msg/Joy":
        n_axes = u4(off)
        if np.any(n_axes != n_axes[0]) or n_axes[0] < 2:
            return None
        axes = buf[:, off + 4:off + 12].copy().view("<f4").astype(float)
        return np.column_stack([stamp, axes[:, 1], axes[:, 0]])
    if msgtype == "sensor_msgs/msg/JointState":
        head = bytes(buf[0])
        n_names, pos = int.from_bytes(head[off:off + 4], "little"), off + 4
        names = []
        for _ in range(n_names):
            length = int.from_bytes(head[pos:pos + 4], "little")
            names.append(head[pos + 4:pos + 4 + length].decode(errors="replace"))
            pos += 4 + length
        if (np.any(buf[:, off:pos] != buf[0, off:pos]) or "front" not in names
                or "rear" not in names or int.from_bytes(head[pos:pos + 4], "little") != n_names):
            return None
        position = buf[:, pos + 4:pos + 4 + 8 * n_names].copy().view("<f8")
        return np.column_stack([stamp, position[:, names.index("front")],
                                position[:, names.index("rear")]])
    return None


def _messages(topic: _Topic) -> list:
    """Return the topic's messages deserialised (for the generic path), in stored order."""
    if any(isinstance(e, bytes) for e in topic.entries):
        store = get_typestore(Stores.ROS1_NOETIC)
        topic.entries = [store.deserialize_ros1(e, topic.msgtype) if isinstance(e, bytes) else e
                         for e in topic.entries]
    return topic.entries


def _generic_columns(name: str, msgs: list, run: str) -> np.ndarray:
    """Return the columns of :func:`_ros1_columns` from deserialised messages, checked."""
    if name == TOPIC_TRIGGER:
        return np.array([_stamp(m.time_ref) for m in msgs], dtype=float).reshape(-1, 1)
    if name in (TOPIC_AT960, TOPIC_LTD800):
        return np.array([(_stamp(m.header.stamp), m.point.x, m.point.y, m.point.z) for m in msgs],
                        dtype=float).reshape(-1, 4)
    if name == TOPIC_JOY:
        if any(len(m.axes) < 2 for m in msgs):
            raise InputError(f"run {run}: topic {TOPIC_JOY}: a message has fewer than 2 axes")
        return np.array([(_stamp(m.header.stamp), m.axes[1], m.axes[0]) for m in msgs],
                        dtype=float).reshape(-1, 3)
    rows = []
    for i, m in enumerate(msgs):
        names = list(m.name)
        try:
            rows.append((_stamp(m.header.stamp), m.position[names.index("front")],
                         m.position[names.index("rear")]))
        except (ValueError, IndexError):
            raise InputError(f"run {run}: topic {TOPIC_HUB}: message {i} lacks 'front'/'rear' "
                             f"(name={names})") from None
    return np.array(rows, dtype=float).reshape(-1, 3)


def topic_columns(name: str, topic: _Topic, run: str) -> TopicColumns:
    """Return a known topic as columns in stored (receive) order: stamp, values, bag time.

    Stamps: ``time_ref`` of the trigger (UTC), ``header.stamp`` else. Values: the point
    ``[x, y, z]``, the Joy inputs ``[u1, u2] = [axes[1], axes[0]]`` (data contract) or the hub
    azimuths ``[front, rear]`` looked up by name.
    """
    t_bag = np.asarray(topic.t_bag_ns, dtype=np.int64)
    cols = None
    if topic.entries and all(isinstance(e, bytes) for e in topic.entries):
        cols = _ros1_columns(topic.entries, topic.msgtype)
    if cols is None:
        cols = _generic_columns(name, _messages(topic), run)
    # messages of one topic from several bags: bag time is receive time, the stored order
    order = np.argsort(t_bag, kind="stable")
    return TopicColumns(stamp=cols[order, 0].copy(), values=cols[order, 1:].copy(),
                        t_receive=t_bag[order] * 1e-9)
