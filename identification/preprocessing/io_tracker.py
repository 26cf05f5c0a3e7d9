"""Reading tracker campaigns (data contract, part 1) into typed raw runs, taking bags as they are.

A run's topics are gathered across its bags as columns in stored order
(:mod:`identification.preprocessing.io_bags`, which also reads a damaged bag up to the damage).
Then, per topic (:mod:`identification.preprocessing.stamp_order`): a clock reset (a backward
step of the stamps longer than half a trigger period) cuts the run, at the bag time of the
first message after it, into parts ``<run>.1``, ``<run>.2``, ... (a part too short to be
synchronised is dropped with a warning); within each part the messages are put in stamp order
and the reorderings counted; a tracker message repeating the previous stamp is dropped and
counted. Before all that, a Joy or hub message whose header stamp was never set (zero) takes its bag
time (counted); Joy stamps that miss both the trigger's UTC span and their own bag times by more than
:data:`UTC_SLACK_S` are on another clock (seconds since boot) and an error. What was found is in each run's :class:`ReadFacts`.

A run that cannot go on (no bags, a required topic missing or empty, a known topic of another
message type, no part long enough) raises :class:`InputError` from :func:`read_tracker_parts`;
:func:`read_tracker_campaign` skips such a run with a warning and lists it in
``TrackerCampaign.skipped`` so that the other runs can go on. Tracker samples with NaN
coordinates are kept (their stamps still carry clock information); the synchroniser drops them
from the positions and counts them.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from groundfloor.errors import InputError
from groundfloor.files import unlisted_runs
from groundfloor.types import PointSeries, RawRun, TrackerCampaign, check_input_range
from identification.preprocessing.io_bags import (
    TOPIC_AT960,
    TOPIC_HUB,
    TOPIC_JOY,
    TOPIC_LTD800,
    TOPIC_TRIGGER,
    TOPIC_TYPES,
    Truncation,
    read_topics,
    topic_columns,
    topics_of_type,
)
from identification.preprocessing.io_survey import read_survey
from identification.preprocessing.stamp_order import (
    MIN_PART_S,
    ClockReset,
    TopicColumns,
    cut_at_resets,
    find_clock_resets,
    half_trigger_period_s,
    in_stamp_order,
    stamps_recover,
    unstamped_to_receive,
)

log = logging.getLogger(__name__)

REQUIRED_TOPICS = (TOPIC_TRIGGER, TOPIC_AT960, TOPIC_LTD800, TOPIC_JOY)
#: topics whose header stamps are UTC (data contract): an unset (zero) stamp takes the bag time
UTC_HEADER_TOPICS = (TOPIC_JOY, TOPIC_HUB)
#: the Joy stamps must come this close to the trigger's UTC span or to their own bag times, or they
#: are on another clock (a trigger clock that jumped, or a bag re-recorded later, moves only one of them)
UTC_SLACK_S = 60.0
OPTIONAL_TOPICS = (TOPIC_HUB,)  # without it the hub model (eq. 5.25) is skipped, poses are not
SPLITS = ("train", "test")
RECOVERS_HINT = (" (the stamps pass the jump's start again within 1 s: a message received more than half a "
                 "trigger period late rather than a restarted clock?)")


@dataclass(frozen=True)
class ReadFacts:
    """What reading a run found in its bags and did about it."""

    reordered: dict[str, int]  # topic -> messages stored right after one with a later stamp
    repeated_dropped: dict[str, int]  # topic -> messages repeating the previous stamp, dropped
    truncated: tuple[Truncation, ...] = ()  # bags read only up to their damage
    clock_resets: tuple[ClockReset, ...] = ()  # of the whole run the part was cut from
    part_of: str | None = None  # the run a part was cut from (None: the run is whole)
    parts_dropped: tuple[str, ...] = ()  # why each part too short was dropped
    unstamped: dict[str, int] = field(default_factory=dict)  # topic -> header stamps never set, bag time taken

    def to_json_dict(self) -> dict:
        """Return the facts under the keys of a run in the preprocess JSON."""
        return {"reordered": dict(self.reordered),
                "repeated_stamps_dropped": dict(self.repeated_dropped),
                "truncated": [t.to_dict() for t in self.truncated],
                "clock_resets": [r.to_dict() for r in self.clock_resets],
                "part_of": self.part_of, "parts_dropped": list(self.parts_dropped),
                "unstamped_receive_time": dict(self.unstamped)}


@dataclass(frozen=True)
class BagRun(RawRun):
    """A :class:`RawRun` plus the bag (receive) times of the tracker messages, UTC s, and the
    facts of reading it.

    The receive times are the recording computer's clock, good to a fraction of a second; the
    synchroniser uses them only to break a tie between cross-correlation peaks that the
    periodic gap pattern (one skipped pulse every 3 s) leaves 3 s apart.
    """

    t_receive_utc: dict[str, np.ndarray] = field(default_factory=dict)  # tracker -> (n,)
    facts: ReadFacts | None = None


def find_bags(run_dir: Path) -> list[Path]:
    """Return the bags of a run folder: ``*.bag`` files and ROS2 bag folders (with metadata.yaml),
    the run folder itself when it is one (``ros2 bag record -o runs/<run>`` writes that)."""
    run_dir = Path(run_dir)
    bags = sorted(p for p in run_dir.glob("*.bag") if p.is_file())
    bags += [run_dir] if (run_dir / "metadata.yaml").is_file() else []
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


def read_run_groups(path: Path) -> dict[str, str]:
    """Return the ``group`` (day or session) given per run in ``campaign.yaml``, where given.

    Part 1 of the data contract names runs and splits only; a raw campaign that also gives a
    run's group (as part 2 allows) keeps it through preprocessing. Call after
    :func:`read_campaign_yaml` has validated the file.
    """
    doc = yaml.safe_load((Path(path) / "campaign.yaml").read_text())
    return {e["name"]: str(e["group"]) for e in doc["runs"] if e.get("group") not in (None, "")}


def _without_repeats(run: str, topic: str, cols: TopicColumns) -> tuple[TopicColumns, int]:
    """Return the sorted topic without messages repeating the previous stamp, and how many.

    Two messages on one clock tick (a spurious pulse on the tick of a real one): an instrument
    registers one instant once, so the later message is dropped, and said so.
    """
    repeat = np.flatnonzero(np.diff(cols.stamp) == 0) + 1
    if not repeat.size:
        return cols, 0
    log.warning("run %s: topic %s: %d message(s) repeat the previous stamp; dropped", run, topic,
                repeat.size)
    keep = np.ones(len(cols), dtype=bool)
    keep[repeat] = False
    return cols.take(keep), int(repeat.size)


def _bag_run(name: str, split: str, topics: dict[str, TopicColumns]) -> BagRun:
    """Return one run (or part) from its topics in stored order: sorted, checked, counted."""
    for topic in REQUIRED_TOPICS:
        if not len(topics.get(topic, ())):
            raise InputError(f"run {name}: topic {topic} missing or empty")
    cols, reordered, repeated = {}, {}, {}
    for topic, c in topics.items():
        c, reordered[topic] = in_stamp_order(c)
        if reordered[topic]:
            log.info("run %s: topic %s: %d message(s) stored out of stamp order; sorted", name, topic,
                     reordered[topic])
        if topic in (TOPIC_TRIGGER, TOPIC_AT960, TOPIC_LTD800):
            c, repeated[topic] = _without_repeats(name, topic, c)
        cols[topic] = c
    joy, trig = cols[TOPIC_JOY].stamp, cols[TOPIC_TRIGGER].stamp
    off_trigger = joy.max() < trig.min() - UTC_SLACK_S or joy.min() > trig.max() + UTC_SLACK_S
    if off_trigger and np.median(np.abs(joy - cols[TOPIC_JOY].t_receive)) > UTC_SLACK_S:
        raise InputError(f"run {name}: topic {TOPIC_JOY}: header stamps {joy.min():.3f} to {joy.max():.3f} s are "
                         f"not on the trigger's UTC ({trig.min():.3f} to {trig.max():.3f} s); the data contract "
                         "stamps the joystick with the robot's UTC clock (NTP)")
    if not np.all(np.isfinite(cols[TOPIC_JOY].values)):
        raise InputError(f"run {name}: topic {TOPIC_JOY}: non-finite axes")
    for j, column in enumerate(("axes[1] (u1)", "axes[0] (u2)")):
        check_input_range(cols[TOPIC_JOY].values[:, j], f"run {name}: topic {TOPIC_JOY}", column)
    hub = cols.get(TOPIC_HUB, TopicColumns(np.zeros(0), np.zeros((0, 2)), np.zeros(0)))
    if not len(hub):
        log.warning("run %s: topic %s missing: no turning-hub model for this run", name, TOPIC_HUB)
    at, ltd = cols[TOPIC_AT960], cols[TOPIC_LTD800]
    return BagRun(name=name, split=split, t_trigger_utc=cols[TOPIC_TRIGGER].stamp,
                  at960=PointSeries(t_tracker=at.stamp, xyz=at.values),
                  ltd800=PointSeries(t_tracker=ltd.stamp, xyz=ltd.values),
                  t_joy_utc=cols[TOPIC_JOY].stamp, u_joy=cols[TOPIC_JOY].values,
                  t_hub_utc=hub.stamp, hub_azimuth=hub.values,
                  t_receive_utc={"at960": at.t_receive, "ltd800": ltd.t_receive},
                  facts=ReadFacts(reordered=reordered, repeated_dropped=repeated))


def read_tracker_parts(run_dir: str | Path, name: str | None = None,
                       split: str = "train") -> tuple[BagRun, ...]:
    """Return a run of a tracker campaign as read from its bags: one :class:`BagRun`, or one per
    part between clock resets (named ``<run>.1``, ``<run>.2``, ...), validated against the
    contract and in stamp order.

    Raises
    ------
    InputError
        Naming the run and topic: no bags, a bag that cannot be read at all, a required topic
        missing or empty, a known topic of another message type (with both types), no part
        between clock resets long enough, a Joy or JointState message too short.
    """
    run_dir = Path(run_dir)
    name = name or run_dir.name
    if not run_dir.is_dir():
        raise InputError(f"run {name}: folder {run_dir} missing")
    bags = find_bags(run_dir)
    if not bags:
        raise InputError(f"run {name}: no bags (*.bag or ROS2 folders) in {run_dir}")
    found, truncated = read_topics(bags, name)
    for topic in REQUIRED_TOPICS:
        if not len(found[topic]):
            elsewhere = [t for t in topics_of_type(bags, TOPIC_TYPES[topic]) if t not in TOPIC_TYPES]
            hint = (f"; {TOPIC_TYPES[topic]} is recorded on {', '.join(elsewhere)} instead: the data contract "
                    f"names that topic {topic}" if elsewhere else "")
            raise InputError(f"run {name}: topic {topic} missing or empty{hint}")
    topics = {t: topic_columns(t, found[t], name) for t in TOPIC_TYPES if len(found[t])}
    unstamped = {}
    for t in UTC_HEADER_TOPICS:
        if t in topics:
            stamp, n = unstamped_to_receive(topics[t].stamp, topics[t].t_receive)
            if n:
                unstamped[t] = n
                topics[t] = replace(topics[t], stamp=stamp)
                log.warning("run %s: topic %s: %d of %d messages have no header stamp (zero); their bag times "
                            "are taken", name, t, n, len(stamp))

    half_period = half_trigger_period_s(topics[TOPIC_TRIGGER].stamp)
    resets = sorted((r for t, c in topics.items() for r in find_clock_resets(t, c, half_period)),
                    key=lambda r: r.t_receive_utc)
    late = [stamps_recover(topics[r.topic], r) for r in resets]
    for r, is_late in zip(resets, late):
        log.warning("run %s: %s: a clock reset; the run is cut there%s", name, r.describe(),
                    RECOVERS_HINT if is_late else "")
    parts, dropped = cut_at_resets(name, topics, resets, TOPIC_TRIGGER)
    if not parts:
        n_late = sum(late)
        hint = (f"; {n_late} of its {len(resets)} clock resets are passed again by the stamps within 1 s: messages "
                "received more than half a trigger period late, which the data contract reads as "
                "clock resets" if n_late else "")
        raise InputError(f"run {name}: no part between its clock resets lasts {MIN_PART_S:g} s "
                         f"(first: {resets[0].describe()}){hint}")
    runs = []
    for k, part in enumerate(parts, 1):
        part_name = name if len(parts) == 1 else f"{name}.{k}"
        try:
            runs.append(_bag_run(part_name, split, part.topics))
        except InputError as exc:
            if len(parts) == 1:
                raise
            log.warning("%s; part dropped", exc)
            dropped.append(str(exc))
    if not runs:
        raise InputError(dropped[-1])
    return tuple(replace(r, facts=replace(r.facts, truncated=tuple(truncated), clock_resets=tuple(resets),
                                          part_of=name if r.name != name else None,
                                          parts_dropped=tuple(dropped), unstamped=unstamped))
                 for r in runs)


def read_tracker_run(run_dir: str | Path, name: str | None = None, split: str = "train") -> BagRun:
    """Return one run of a tracker campaign as a :class:`BagRun` (a :class:`RawRun` with bag
    receive times), validated against the contract and in stamp order.

    ``runs/<run>.<k>`` (a folder that does not exist) is part ``k`` of ``runs/<run>`` cut at a
    clock reset, as preprocessing names it; a run cut into several parts must be read by part.

    Raises
    ------
    InputError
        As :func:`read_tracker_parts`, or if the run has several parts, or no part ``k``.
    """
    run_dir = Path(run_dir)
    name = name or run_dir.name
    whole = re.fullmatch(r"(.+)\.(\d+)", name)
    if not run_dir.is_dir() and whole and (run_dir.parent / whole[1]).is_dir():
        parts = read_tracker_parts(run_dir.parent / whole[1], whole[1], split)
        for part in parts:
            if part.name == name:
                return part
        raise InputError(f"run {name}: run {whole[1]} has no such part "
                         f"({', '.join(p.name for p in parts)})")
    parts = read_tracker_parts(run_dir, name, split)
    if len(parts) > 1:
        raise InputError(f"run {name}: clock resets cut it into {', '.join(p.name for p in parts)}; "
                         "read one of them")
    return parts[0]


#: a tracker's points this many times farther from it than its network points (or nearer) are in
#: another unit than the survey's: 0.34 to 1.32 (median distances, per run and tracker) on the default
#: and the ten variant campaigns, 1000 for millimetres; the geometric middle of 1 and 1000
UNIT_RATIO = 30.0


def check_point_units(run: BagRun, survey) -> None:
    """Raise a one-line InputError naming run and topic when a tracker's measured points and its
    network points in ``calibration.yaml`` are not in the same unit (median distances from the
    tracker more than :data:`UNIT_RATIO` apart: millimetres, which laser-tracker software exports by
    default, against the data contract's metres)."""
    for tracker in ("at960", "ltd800"):
        net = getattr(survey, f"network_{tracker}")
        xyz = getattr(run, tracker).xyz
        d_net = float(np.median([np.linalg.norm(np.asarray(v, float)[:3]) for v in net.values()])) if net else np.nan
        d_run = float(np.nanmedian(np.linalg.norm(xyz, axis=1))) if np.isfinite(xyz).any() else np.nan
        if np.isfinite(d_net) and np.isfinite(d_run) and d_net > 0 and d_run > 0 \
                and not 1.0 / UNIT_RATIO < d_run / d_net < UNIT_RATIO:
            raise InputError(f"run {run.name}: topic /{tracker}/measurement: points a median {d_run:.6g} from the "
                             f"tracker, its network points in calibration.yaml {d_net:.6g}: one of them is not in "
                             "metres (millimetres?)")


def read_tracker_campaign(path: str | Path) -> TrackerCampaign:
    """Return a tracker campaign read from disk: survey plus every run that can be used.

    Runs that cannot go on are skipped with a warning and listed in ``skipped`` (run -> one-line
    reason); a run cut at clock resets gives one raw run per part. ``calibration.yaml`` is read
    by :func:`identification.preprocessing.io_survey.read_survey`.

    Raises
    ------
    InputError
        If ``path`` is not a campaign, ``campaign.yaml`` or ``calibration.yaml`` is invalid, or
        no run can be used.
    """
    root = Path(path)
    name, runs = read_campaign_yaml(root)
    calib = root / "calibration.yaml"
    if not calib.is_file():
        raise InputError(f"{root}: calibration.yaml missing")
    survey = read_survey(calib)
    extra = unlisted_runs(root, (r for r, _ in runs))
    if extra:
        log.warning("%s: run folder%s %s not listed in campaign.yaml; not read", root / "runs",
                    "s" if len(extra) > 1 else "", ", ".join(extra) + (" are" if len(extra) > 1 else " is"))
    good, skipped = [], {}
    for run_name, split in runs:
        try:
            parts = read_tracker_parts(root / "runs" / run_name, run_name, split)
            for part in parts:
                check_point_units(part, survey)
            good += parts
        except InputError as exc:
            log.warning("skipping %s", exc)
            skipped[run_name] = str(exc)
    if not good:
        first = next(iter(skipped.values()))
        raise InputError(f"{root}: no usable run ({len(skipped)} skipped; first: {first})")
    return TrackerCampaign(root=root, name=name, survey=survey, runs=tuple(good), skipped=skipped)
