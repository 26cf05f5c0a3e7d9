"""A run's messages in stamp order: reorderings sorted and counted, clock resets cut the run.

A bag stores messages in the order they were received, not in the order of their stamps (data
contract): with independent latencies, two measurements a few milliseconds apart (a spurious
AT960 pulse next to a real one) arrive the other way round, and so does anything a recorder
merges from several connections or a bag merged or re-recorded later. Per topic, in stored
order:

- a backward step of the stamps shorter than half a trigger period is a **reordering**: the
  topic is sorted by stamp and the steps counted (:func:`in_stamp_order`);
- a longer backward step is a **clock reset** (the instrument's clock restarted; data contract):
  no clock model fits across it (eq. 5.10 is linear), so the run is cut there
  (:func:`find_clock_resets`, :func:`cut_at_resets`).

Where to cut: the trackers count on their own clocks, the trigger and the robot on UTC, so a
tracker stamp says nothing about the UTC instant of its reset. The one time base every topic
shares is the bag (receive) time, UTC of the recording computer to a fraction of a second: every
topic is cut at the bag time of the first message after the jump. A trigger or tracker message
received within the latency of that instant may land on the other side of the cut, where the
synchroniser counts it as outside the trigger train or as a lost pulse; no stamp crosses a cut.

The half period comes from the trigger stamps themselves (the median positive step), not from a
constant: the data contract says only "about 50 Hz".

A header stamp of exactly zero is one its publisher never set (a ROS node leaves ``header.stamp``
at zero unless it fills it in; a joystick or odometry node republished by hand often does):
such a message of a UTC-stamped topic takes its bag time instead (:func:`unstamped_to_receive`),
counted per topic, before anything above is judged; otherwise every such run would start in 1970
or be cut at each unstamped message.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from identification.preprocessing.clock_sync import MIN_CLOCK_GAPS

log = logging.getLogger(__name__)

GAP_PERIOD_S = 3.0  # the trigger skips one pulse every 3 s (data contract)
# a part needs MIN_CLOCK_GAPS gaps of that pattern on every clock, plus one for its edges
MIN_PART_S = (MIN_CLOCK_GAPS + 1) * GAP_PERIOD_S


@dataclass(frozen=True)
class TopicColumns:
    """One topic's messages as columns, in stored (receive) order unless sorted."""

    stamp: np.ndarray  # (n,) the instrument's stamp, s (its own clock or UTC)
    values: np.ndarray  # (n, k) the message content the reader keeps
    t_receive: np.ndarray  # (n,) bag time, UTC s of the recording computer

    def __len__(self) -> int:
        return int(self.stamp.size)

    def take(self, index) -> TopicColumns:
        """Return the messages at ``index`` (a mask, slice or index array)."""
        return TopicColumns(self.stamp[index], self.values[index], self.t_receive[index])

    def received_in(self, t_lo: float, t_hi: float) -> TopicColumns:
        """Return the messages received in ``[t_lo, t_hi)`` (bag time)."""
        return self.take((self.t_receive >= t_lo) & (self.t_receive < t_hi))


@dataclass(frozen=True)
class ClockReset:
    """A backward jump of a topic's stamps longer than half a trigger period."""

    topic: str
    message: int  # index, in stored order, of the first message on the new clock
    stamp_before: float  # s
    stamp_after: float  # s
    t_receive_utc: float  # bag time of that message: where the run is cut

    @property
    def jump_s(self) -> float:
        """Return the stamp step across the reset (negative), s."""
        return self.stamp_after - self.stamp_before

    def describe(self) -> str:
        """Return ``topic T: clock jumps back ... at message i (... then ...)``, for messages."""
        return (f"topic {self.topic}: clock jumps back {-self.jump_s:.6f} s at message {self.message} "
                f"({self.stamp_before:.6f} then {self.stamp_after:.6f})")

    def to_dict(self) -> dict:
        """Return the reset as a plain dict for JSON."""
        return {"topic": self.topic, "message": self.message, "jump_s": self.jump_s,
                "stamp_before": self.stamp_before, "stamp_after": self.stamp_after,
                "t_receive_utc": self.t_receive_utc}


def half_trigger_period_s(t_trigger: np.ndarray) -> float:
    """Return half the trigger period: half the median positive step of the trigger stamps."""
    step = np.diff(np.asarray(t_trigger, dtype=float))
    step = step[step > 0]
    return 0.5 * float(np.median(step)) if step.size else np.inf


def find_clock_resets(topic: str, cols: TopicColumns, half_period_s: float) -> list[ClockReset]:
    """Return the clock resets of a topic: backward stamp steps longer than ``half_period_s``."""
    step = np.diff(cols.stamp)
    return [ClockReset(topic=topic, message=int(i), stamp_before=float(cols.stamp[i - 1]),
                       stamp_after=float(cols.stamp[i]), t_receive_utc=float(cols.t_receive[i]))
            for i in np.flatnonzero(step < -half_period_s) + 1]


def stamps_recover(cols: TopicColumns, reset: ClockReset, within_s: float = 1.0) -> bool:
    """Return whether a message received within ``within_s`` after a reset carries a stamp later
    than the one before the jump.

    A restarted clock needs as long as it jumped back to pass its old reading again (hours in a
    controller reboot); a message received late by more than half a trigger period is passed by
    the next one. The data contract calls both a clock reset; this only names the second kind in
    messages, so that a user with a recorder's latencies wider than the contract's knows why
    every run was cut.
    """
    i = reset.message
    later = (cols.t_receive[i:] < reset.t_receive_utc + within_s)
    return bool(np.any(cols.stamp[i:][later] > reset.stamp_before))


def unstamped_to_receive(stamp: np.ndarray, t_receive: np.ndarray) -> tuple[np.ndarray, int]:
    """Return ``stamp`` with its zeros (header stamps never set) replaced by the bag times
    ``t_receive`` (the recording computer's UTC, which the data contract's NTP-synchronised
    stamps agree with to the message's latency), and how many were replaced (a zero bag time
    replaces nothing: no receive time known)."""
    stamp = np.asarray(stamp, dtype=float)
    unset = (stamp == 0.0) & (np.asarray(t_receive, dtype=float) != 0.0)
    if not unset.any():
        return stamp, 0
    return np.where(unset, np.asarray(t_receive, dtype=float), stamp), int(unset.sum())


def in_stamp_order(cols: TopicColumns) -> tuple[TopicColumns, int]:
    """Return the topic sorted by stamp (stable) and the number of reorderings: messages stored
    right after one with a later stamp."""
    n_back = int(np.sum(np.diff(cols.stamp) < 0))
    if not n_back:
        return cols, 0
    return cols.take(np.argsort(cols.stamp, kind="stable")), n_back


@dataclass(frozen=True)
class RunPart:
    """The messages of one run received between two clock resets (or the run's ends)."""

    index: int  # 1-based position among all parts of the run, dropped ones included
    topics: dict[str, TopicColumns]
    span_s: float  # trigger stamps covered


def cut_at_resets(run: str, topics: dict[str, TopicColumns], resets: list[ClockReset],
                  trigger_topic: str, min_part_s: float = MIN_PART_S) -> tuple[list[RunPart], list[str]]:
    """Return the parts of a run between its clock resets and a reason for each part dropped.

    Every topic is cut at the bag time of each reset (module docstring). A part whose trigger
    stamps cover less than ``min_part_s`` cannot be synchronised and is dropped; its reason
    names the run, the reset's topic, message index and jump, and is logged as a warning. A
    run without resets is one part, whatever its length (the synchroniser judges it).
    """
    if not resets:
        trig = topics[trigger_topic].stamp
        return [RunPart(index=1, topics=topics, span_s=float(np.ptp(trig)) if trig.size else 0.0)], []
    cuts = sorted({r.t_receive_utc for r in resets})
    edges = [-np.inf, *cuts, np.inf]
    kept, dropped = [], []
    for k in range(len(edges) - 1):
        part = {t: c.received_in(edges[k], edges[k + 1]) for t, c in topics.items()}
        trig = part[trigger_topic].stamp
        span = float(trig.max() - trig.min()) if trig.size else 0.0
        if span >= min_part_s:
            kept.append(RunPart(index=k + 1, topics=part, span_s=span))
            continue
        # name the reset that bounds the part: the one after it, or for the last the one before
        after = k < len(cuts)
        reset = next(r for r in resets if r.t_receive_utc == cuts[k if after else k - 1])
        why = (f"run {run}: {reset.describe()}; the {span:.1f} s of trigger stamps "
               f"{'before' if after else 'after'} it are fewer than the {min_part_s:g} s a run "
               "needs and are dropped")
        log.warning("%s", why)
        dropped.append(why)
    return kept, dropped
