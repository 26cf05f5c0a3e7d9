"""Reading tracker campaigns (data contract, part 1) with rosbags into typed raw runs.

A run's topics may be spread over several bags (ROS1 ``.bag`` files and/or ROS2 bag folders);
every topic is looked up by name across all of them. Nothing here interprets the data beyond
typing and validating it: synchronisation is :mod:`identification.preprocessing.sync`.

Validation follows the contract: a run that cannot go on (no bags, a required topic missing or
empty, stamps going backwards, non-finite stamps) raises :class:`InputError` from
:func:`read_tracker_run`; :func:`read_tracker_campaign` skips such a run with a warning and lists
it in ``TrackerCampaign.skipped`` so that the other runs can go on. Tracker samples with NaN
coordinates are kept (their stamps still carry clock information); the synchroniser drops and
counts them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from groundfloor.errors import InputError
from groundfloor.types import PointSeries, RawRun, TrackerCampaign

log = logging.getLogger(__name__)

TOPIC_TRIGGER = "/rpi/trigger"
TOPIC_AT960 = "/at960/measurement"
TOPIC_LTD800 = "/ltd800/measurement"
TOPIC_JOY = "/joy_teleop/joy"
TOPIC_HUB = "/turning_hub/azimuth"
REQUIRED_TOPICS = (TOPIC_TRIGGER, TOPIC_AT960, TOPIC_LTD800, TOPIC_JOY)
OPTIONAL_TOPICS = (TOPIC_HUB,)  # without it the hub model (eq. 5.25) is skipped, poses are not
SPLITS = ("train", "test")


@dataclass(frozen=True)
class BagRun(RawRun):
    """A :class:`RawRun` plus the bag (receive) times of the tracker messages, UTC s.

    The receive times are the recording computer's clock, good to a fraction of a second; the
    synchroniser uses them only to break a tie between cross-correlation peaks that the
    periodic gap pattern (one skipped pulse every 3 s) leaves 3 s apart.
    """

    t_receive_utc: dict[str, np.ndarray] = field(default_factory=dict)  # tracker -> (n,)


def find_bags(run_dir: Path) -> list[Path]:
    """Return the bags of a run folder: ``*.bag`` files and ROS2 bag folders (with metadata.yaml)."""
    run_dir = Path(run_dir)
    bags = sorted(p for p in run_dir.glob("*.bag") if p.is_file())
    bags += sorted(p for p in run_dir.iterdir() if p.is_dir() and (p / "metadata.yaml").is_file())
    return bags


def read_campaign_yaml(path: Path) -> tuple[str, list[tuple[str, str]]]:
    """Return the campaign name and its ``(run, split)`` list from ``campaign.yaml``."""
    file = Path(path) / "campaign.yaml"
    if not file.is_file():
        raise InputError(f"{path}: not a campaign (no campaign.yaml)")
    try:
        doc = yaml.safe_load(file.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{file}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("runs"), list) or not doc["runs"]:
        raise InputError(f"{file}: key 'runs' missing or not a non-empty list")
    runs = []
    for i, entry in enumerate(doc["runs"]):
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise InputError(f"{file}: runs[{i}] has no 'name'")
        split = entry.get("split")
        if split not in SPLITS:
            raise InputError(f"{file}: runs[{i}] ({entry['name']}): key 'split' must be train or "
                             f"test, got {split!r}")
        runs.append((entry["name"], split))
    names = [r[0] for r in runs]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{file}: run {dup!r} listed twice under 'runs'")
    return str(doc.get("name", Path(path).name)), runs


def _stamp(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


# ROS1 md5sums of the standard definitions: only these take the vectorised byte-level path
_FAST_ROS1 = {"geometry_msgs/msg/PointStamped": "c63aecb41bfdfd6b7e1fac37c7cbe7bf",
              "sensor_msgs/msg/TimeReference": "fded64a0265108ba86c3d38fb11c0c16",
              "sensor_msgs/msg/Joy": "5a9ea5f83505693b71e785041e67a8bb",
              "sensor_msgs/msg/JointState": "3066dcd76a6cfaef579bd0f34173e9fd"}


@dataclass
class _Topic:
    """Messages of one topic gathered across bags: deserialised, or raw ROS1 bytes (fast path)."""

    msgtype: str = ""
    msgs: list = field(default_factory=list)
    raw: list = field(default_factory=list)
    t_bag_ns: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.msgs) + len(self.raw)


def _read_topics(bags: list[Path], topics: tuple[str, ...]) -> dict[str, _Topic]:
    """Return the messages per topic, gathered across all bags of a run (ROS1 and ROS2)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # AnyReader opens several ROS1 bags together but reads ROS2 folders one recording at a time.
    groups = [[b for b in bags if b.suffix == ".bag"]] + [[b] for b in bags if b.suffix != ".bag"]
    out = {t: _Topic() for t in topics}
    typestore = get_typestore(Stores.ROS1_NOETIC)
    for group in (g for g in groups if g):
        try:
            with AnyReader(group, default_typestore=typestore) as reader:
                conns = [c for c in reader.connections if c.topic in out]
                fast = {c.id for c in conns
                        if not reader.is2 and _FAST_ROS1.get(c.msgtype) == c.digest}
                for conn, t_bag_ns, raw in reader.messages(connections=conns):
                    topic = out[conn.topic]
                    topic.msgtype = conn.msgtype
                    if conn.id in fast and not topic.msgs:
                        topic.raw.append(raw)
                    else:
                        topic.msgs.append(reader.deserialize(raw, conn.msgtype))
                    topic.t_bag_ns.append(t_bag_ns)
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a corrupt bag is bad input, named by file
            raise InputError(f"{group[0]}: cannot read bag ({type(exc).__name__}: {exc})") from None
    return out


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
    """Return the topic's messages deserialised (for the generic path)."""
    if topic.raw:
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS1_NOETIC)
        topic.msgs = [store.deserialize_ros1(r, topic.msgtype) for r in topic.raw] + topic.msgs
        topic.raw = []
    return topic.msgs


def _check_stamps(t: np.ndarray, run: str, topic: str, strict: bool) -> None:
    """Raise InputError unless the stamps are finite and increasing (strictly if ``strict``)."""
    if not np.all(np.isfinite(t)):
        i = int(np.argmin(np.isfinite(t)))
        raise InputError(f"run {run}: topic {topic}: non-finite stamp at message {i}")
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0 if strict else dt < 0)
    if bad.size:
        i = int(bad[0])
        raise InputError(f"run {run}: topic {topic}: stamps not monotonic at message {i + 1} "
                         f"({t[i]:.6f} then {t[i + 1]:.6f}; {bad.size} such steps)")


def _trigger_times(topic: _Topic) -> np.ndarray:
    cols = _fast(topic)
    if cols is not None:
        return cols[:, 0]
    return np.array([_stamp(m.time_ref) for m in _messages(topic)], dtype=float)


def _points(topic: _Topic, run: str, name: str) -> tuple[PointSeries, np.ndarray]:
    cols = _fast(topic)
    if cols is None:
        msgs = _messages(topic)
        cols = np.array([(_stamp(m.header.stamp), m.point.x, m.point.y, m.point.z) for m in msgs],
                        dtype=float).reshape(-1, 4)
    t, xyz = cols[:, 0].copy(), cols[:, 1:].copy()
    t_bag = np.asarray(topic.t_bag_ns, dtype=np.int64) * 1e-9
    # not sorted: stamps going backwards mean a clock reset, which no linear clock model fits
    _check_stamps(t, run, name, strict=False)
    # Two measurements on one clock tick (a spurious pulse on the tick of a real one): a tracker
    # registers one instant once, so the later message is dropped, and said so.
    repeat = np.flatnonzero(np.diff(t) == 0) + 1
    if repeat.size:
        log.warning("run %s: topic %s: %d message(s) repeat the previous stamp; dropped",
                       run, name, repeat.size)
        keep = np.ones(t.size, dtype=bool)
        keep[repeat] = False
        t, xyz, t_bag = t[keep], xyz[keep], t_bag[keep]
    return PointSeries(t_tracker=t, xyz=xyz), t_bag


def _fast(topic: _Topic) -> np.ndarray | None:
    return _ros1_columns(topic.raw, topic.msgtype) if topic.raw and not topic.msgs else None


def _joy(topic: _Topic, run: str) -> tuple[np.ndarray, np.ndarray]:
    """Return Joy stamps and ``[u1, u2] = [axes[1], axes[0]]`` (data contract)."""
    cols = _fast(topic)
    if cols is None:
        joy = _messages(topic)
        if any(len(m.axes) < 2 for m in joy):
            raise InputError(f"run {run}: topic {TOPIC_JOY}: a message has fewer than 2 axes")
        cols = np.array([(_stamp(m.header.stamp), m.axes[1], m.axes[0]) for m in joy],
                        dtype=float).reshape(-1, 3)
    return cols[:, 0].copy(), cols[:, 1:].copy()


def _hub(topic: _Topic, run: str) -> tuple[np.ndarray, np.ndarray]:
    """Return JointState stamps and the commanded azimuths ``[front, rear]``, looked up by name."""
    cols = _fast(topic)
    if cols is None:
        rows = []
        for i, m in enumerate(_messages(topic)):
            names = list(m.name)
            try:
                rows.append((_stamp(m.header.stamp), m.position[names.index("front")],
                             m.position[names.index("rear")]))
            except (ValueError, IndexError):
                raise InputError(f"run {run}: topic {TOPIC_HUB}: message {i} lacks 'front'/'rear' "
                                 f"(name={names})") from None
        cols = np.array(rows, dtype=float).reshape(-1, 3)
    return cols[:, 0].copy(), cols[:, 1:].copy()


def read_tracker_run(run_dir: str | Path, name: str | None = None, split: str = "train") -> BagRun:
    """Return one run of a tracker campaign as a :class:`BagRun` (a :class:`RawRun` with bag
    receive times), validated against the contract.

    Raises
    ------
    InputError
        Naming the run and topic: no bags, a required topic missing or empty, stamps going
        backwards or non-finite, a Joy or JointState message too short.
    """
    run_dir = Path(run_dir)
    name = name or run_dir.name
    if not run_dir.is_dir():
        raise InputError(f"run {name}: folder {run_dir} missing")
    bags = find_bags(run_dir)
    if not bags:
        raise InputError(f"run {name}: no bags (*.bag or ROS2 folders) in {run_dir}")
    topics = _read_topics(bags, REQUIRED_TOPICS + OPTIONAL_TOPICS)
    for topic in REQUIRED_TOPICS:
        if not len(topics[topic]):
            raise InputError(f"run {name}: topic {topic} missing or empty")

    t_trigger = _trigger_times(topics[TOPIC_TRIGGER])
    _check_stamps(t_trigger, name, TOPIC_TRIGGER, strict=True)
    at960, rx_at960 = _points(topics[TOPIC_AT960], name, TOPIC_AT960)
    ltd800, rx_ltd800 = _points(topics[TOPIC_LTD800], name, TOPIC_LTD800)

    t_joy, u_joy = _joy(topics[TOPIC_JOY], name)
    _check_stamps(t_joy, name, TOPIC_JOY, strict=False)
    if not np.all(np.isfinite(u_joy)):
        raise InputError(f"run {name}: topic {TOPIC_JOY}: non-finite axes")

    t_hub, az = _hub(topics[TOPIC_HUB], name)
    _check_stamps(t_hub, name, TOPIC_HUB, strict=False)
    if not t_hub.size:
        log.warning("run %s: topic %s missing: no turning-hub model for this run", name, TOPIC_HUB)

    return BagRun(name=name, split=split, t_trigger_utc=t_trigger, at960=at960, ltd800=ltd800,
                  t_joy_utc=t_joy, u_joy=u_joy, t_hub_utc=t_hub, hub_azimuth=az,
                  t_receive_utc={"at960": rx_at960, "ltd800": rx_ltd800})


def read_tracker_campaign(path: str | Path) -> TrackerCampaign:
    """Return a tracker campaign read from disk: survey plus every run that can be used.

    Runs that cannot go on are skipped with a warning and listed in ``skipped`` (run -> one-line
    reason). ``calibration.yaml`` is read by :func:`identification.preprocessing.io_survey.read_survey`.

    Raises
    ------
    InputError
        If ``path`` is not a campaign, ``campaign.yaml`` or ``calibration.yaml`` is invalid, or
        no run can be used.
    """
    from identification.preprocessing.io_survey import read_survey

    root = Path(path)
    name, runs = read_campaign_yaml(root)
    calib = root / "calibration.yaml"
    if not calib.is_file():
        raise InputError(f"{root}: calibration.yaml missing")
    survey = read_survey(calib)
    good, skipped = [], {}
    for run_name, split in runs:
        try:
            good.append(read_tracker_run(root / "runs" / run_name, run_name, split))
        except InputError as exc:
            log.warning("skipping %s", exc)
            skipped[run_name] = str(exc)
    if not good:
        first = next(iter(skipped.values()))
        raise InputError(f"{root}: no usable run ({len(skipped)} skipped; first: {first})")
    return TrackerCampaign(root=root, name=name, survey=survey, runs=tuple(good), skipped=skipped)
