"""The trigger schedule of the Raspberry Pi and the drifting internal clocks of the trackers.

Thesis section 4.2.1: a ROS node on a GNSS-disciplined Raspberry Pi raises a GPIO pin at 50 Hz,
reads its system clock (UTC, sub-microsecond through PPS) right after the rising edge and
publishes it on ``/rpi/trigger``; one pulse every 3 s is skipped on purpose. Section 5.2.2,
eq. 5.10: each tracker's internal clock follows the linear model
``t_rpi = k * t_tracker + d`` with drifts of tens of ppm (table 7.3) and an arbitrary start.

Absolute UTC instants are int64 nanoseconds (``*_ns``): a float64 UTC second has a resolution
of about 0.24 us, too coarse for the microsecond timing studied here. Within a run, times are
float64 seconds relative to the run's simulation start (``t_rel``), which keeps ~1e-15 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TRIGGER_PERIOD_S = 0.02  # 50 Hz trigger (thesis 4.2.1)
SKIP_EVERY = 150  # one slot in 150 (every 3 s) is left empty (thesis 4.2.1)
NS = 1_000_000_000


@dataclass(frozen=True)
class TrackerClock:
    """A tracker's internal clock: ``t_utc = k * t_tracker + d`` (eq. 5.10), ``d`` in int ns."""

    k: float  # rate, 1 + drift_ppm * 1e-6
    d_ns: int  # UTC instant (ns) at which the tracker clock reads zero (its boot)

    @property
    def drift_ppm(self) -> float:
        """Return the drift ``(k - 1) * 1e6`` in ppm (INTERFACES.md convention)."""
        return (self.k - 1.0) * 1e6

    def tracker_s_from_rel(self, t_rel: np.ndarray, t0_ns: int) -> np.ndarray:
        """Return tracker-clock seconds for run-relative times ``t_rel`` (s after ``t0_ns``).

        Implements the inverse of eq. 5.10, ``t_tracker = (t_utc - d) / k``; the large
        ``t0 - d`` is formed in exact integers first so that no precision is lost.
        """
        return ((int(t0_ns) - int(self.d_ns)) * 1e-9 + np.asarray(t_rel, dtype=float)) / self.k

    def rel_from_tracker_s(self, t_tracker: np.ndarray, t0_ns: int) -> np.ndarray:
        """Return run-relative UTC seconds for tracker-clock seconds (eq. 5.10)."""
        return self.k * np.asarray(t_tracker, dtype=float) - (int(t0_ns) - int(self.d_ns)) * 1e-9


@dataclass(frozen=True)
class Trigger:
    """The pulses the Raspberry Pi sent during one run (thesis 4.2.1)."""

    slot: np.ndarray  # (n,) int slot index of each sent pulse (skipped slots are absent)
    t_rise_rel: np.ndarray  # (n,) true rising edge, s after the run's t0
    time_ref_ns: np.ndarray  # (n,) int64 UTC ns the RPi read from its clock (time_ref)
    t_publish_rel: np.ndarray  # (n,) s after t0 when the message was published (header.stamp)
    skip_phase: int  # slot s is skipped when (s + skip_phase) % SKIP_EVERY == 0


def simulate_trigger(
    t_first_rel: float,
    duration_s: float,
    t0_ns: int,
    rng: np.random.Generator,
    *,
    loop_jitter_std_s: float = 20e-6,
    clock_std_s: float = 0.2e-6,
    publish_delay_s: tuple[float, float] = (150e-6, 600e-6),
) -> Trigger:
    """Return the trigger pulses of one run: 50 Hz with one slot in 150 left empty.

    The rising edges follow the nominal 20 ms grid with the jitter of a Python loop on a
    Raspberry Pi (``loop_jitter_std_s``); ``time_ref`` is the GNSS/PPS-disciplined system
    clock read right after the edge (``clock_std_s``, sub-microsecond, thesis 4.2.1); the
    message is published a few hundred microseconds later (uniform in ``publish_delay_s``).
    The skipped slot's phase is random per run, as the node started at an arbitrary time.
    """
    n_slots = int(round(duration_s / TRIGGER_PERIOD_S))
    skip_phase = int(rng.integers(0, SKIP_EVERY))
    slot = np.arange(n_slots)
    slot = slot[(slot + skip_phase) % SKIP_EVERY != 0]
    t_rise_rel = t_first_rel + slot * TRIGGER_PERIOD_S + rng.normal(0.0, loop_jitter_std_s, slot.size)
    t_read_ns = np.rint((t_rise_rel + rng.normal(0.0, clock_std_s, slot.size)) * NS).astype(np.int64)
    t_publish_rel = t_rise_rel + rng.uniform(*publish_delay_s, slot.size)
    return Trigger(slot, t_rise_rel, np.int64(t0_ns) + t_read_ns, t_publish_rel, skip_phase)


def simulate_tracker_clock(
    drift_ppm: float, t_boot_ns: int, rng: np.random.Generator, *, offset_std_s: float = 1e-3
) -> TrackerClock:
    """Return a tracker clock with the given drift that started counting near ``t_boot_ns``.

    The controller booted hours before the run (an arbitrary start value, thesis 5.2.2); a
    small random offset per run stands for the clock being re-set between runs.
    """
    d_ns = int(t_boot_ns) + int(round(rng.normal(0.0, offset_std_s) * NS))
    return TrackerClock(k=1.0 + drift_ppm * 1e-6, d_ns=d_ns)


def stamp_tracker(
    clock: TrackerClock,
    t_event_rel: np.ndarray,
    t0_ns: int,
    rng: np.random.Generator,
    *,
    timing_std_s: float,
    resolution_s: float,
) -> np.ndarray:
    """Return the tracker's time stamps (tracker-clock int ns) of events at ``t_event_rel``.

    Adds the trigger time accuracy (``timing_std_s``, table 3.2) and rounds to the clock
    resolution (``resolution_s``: 0.1 us AT960, 1 us LTD800, table 3.2).
    """
    t_event_rel = np.asarray(t_event_rel, dtype=float)
    t_tracker = clock.tracker_s_from_rel(t_event_rel + rng.normal(0.0, timing_std_s, t_event_rel.size), t0_ns)
    ticks = np.rint(t_tracker / resolution_s)
    return (ticks * int(round(resolution_s * NS))).astype(np.int64)
