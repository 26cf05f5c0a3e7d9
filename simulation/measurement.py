"""What the two laser trackers register: edges, lost and spurious pulses, dropouts and noise.

Thesis sections 4.2.1 and 4.2.2: the LTD800 is triggered on the rising edge of the trigger
pulse, the AT960 (by a configuration error) on the falling edge, one duty cycle later; the duty
cycle is 1 ms of sleep plus the varying run time of the publishing script (table 7.4: 1.32 to
1.47 ms per run). The AT960's 15 m single-wire cable picks up interference: some pulses are
lost, some spurious measurements are triggered in between. Either tracker loses its prism now
and then (line of sight). Point noise follows table 3.2.

Noise model (table 3.2 gives maximum permissible errors, read here as 2 sigma): each coordinate
gets independent Gaussian noise with ``std = a + b * range``:

- AT960: repeatability 7.5 um + 3 um/m  ->  a = 3.75 um, b = 1.5 um/m (about 8-15 um at 3-7 m);
- LTD800: 12 um near, 5 um/m far        ->  a = 3.0 um,  b = 2.5 um/m (about 10-20 um).

Timing: AT960 trigger time accuracy 5 us (read as ~2.5 sigma: 2 us) with a 0.1 us clock; the
LTD800 0.2 us with a 1 us clock (table 3.2; table 7.3's sub-microsecond offset STDs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundfloor.errors import InputError


@dataclass(frozen=True)
class TrackerSpec:
    """Noise and timing figures of one laser tracker (thesis table 3.2)."""

    name: str
    noise_a_m: float  # constant part of the per-coordinate noise std
    noise_b: float  # range-proportional part (m per m)
    timing_std_s: float  # trigger time accuracy (std)
    resolution_s: float  # internal clock resolution


DUTY_JITTER_STD_S = 30e-6  # per-pulse scatter of the script's run time (thesis 4.2.1)
AT960 = TrackerSpec("at960", 3.75e-6, 1.5e-6, 2e-6, 0.1e-6)
LTD800 = TrackerSpec("ltd800", 3.0e-6, 2.5e-6, 0.2e-6, 1e-6)
TRACKERS = {"at960": AT960, "ltd800": LTD800}


def simulate_duty_cycle(
    n: int, mean_s: float, rng: np.random.Generator, *, jitter_std_s: float = DUTY_JITTER_STD_S,
    min_s: float = 1.05e-3
) -> np.ndarray:
    """Return ``n`` per-pulse duty cycles (s): AT960 falling-edge delays after the rising edge.

    1 ms of sleep plus the script's run time (thesis 4.2.1): Gaussian around ``mean_s`` with
    ``jitter_std_s``, never shorter than ``min_s``. Table 7.4 lists the per-run means.
    """
    return np.maximum(rng.normal(mean_s, jitter_std_s, n), min_s)


def simulate_lost(n: int, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Return an (n,) bool mask of pulses the AT960 did not register (interference, 4.2.1)."""
    return rng.random(n) < fraction


def simulate_spurious(t_rise_rel: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Return sorted instants (s) of spurious AT960 triggers, uniform over the pulse train.

    Their number is Poisson with mean ``fraction * len(t_rise_rel)`` (thesis 4.2.1:
    "some erroneously triggered measurements").
    """
    n = rng.poisson(fraction * t_rise_rel.size)
    return np.sort(rng.uniform(t_rise_rel[0], t_rise_rel[-1], n))


def simulate_dropouts(
    t_start: float,
    t_end: float,
    rng: np.random.Generator,
    *,
    per_minute: float = 0.4,
    length_s: tuple[float, float] = (0.5, 5.0),
    p_at_start: float = 0.2,
    p_at_end: float = 0.15,
) -> np.ndarray:
    """Return (k, 2) line-of-sight dropout intervals ``[start, end)`` (s) within a run.

    At least one per run, ``1 + Poisson(per_minute * minutes)`` in all, each 0.5-5 s long and
    not overlapping; with probabilities ``p_at_start``/``p_at_end`` one covers the run's start
    or end, so that a run may begin or end with only some topics present (data contract).
    Dropouts never take more than a fifth of the run.
    """
    span = t_end - t_start
    n = 1 + rng.poisson(per_minute * span / 60.0)
    lengths = rng.uniform(*length_s, n)
    lengths *= min(1.0, 0.2 * span / lengths.sum())
    # place them in the free time by splitting it at sorted uniform points: no overlap by
    # construction (stick-breaking over the time not covered by dropouts)
    free = span - lengths.sum()
    cuts = np.sort(rng.uniform(0.0, free, n))
    starts = t_start + cuts + np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    if rng.random() < p_at_start:
        starts[0] = t_start - 0.5  # starts before the first pulse
    if rng.random() < p_at_end and n > 1:
        starts[-1] = t_end - lengths[-1] + 0.5  # lasts beyond the last pulse
    return np.column_stack([starts, starts + lengths])


def in_intervals(t: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    """Return a bool mask of the times ``t`` that fall inside any ``[start, end)`` interval."""
    if len(intervals) == 0:
        return np.zeros(np.shape(t), dtype=bool)
    order = np.argsort(intervals[:, 0])
    starts, ends = intervals[order, 0], intervals[order, 1]
    i = np.searchsorted(starts, t, side="right") - 1
    return (i >= 0) & (t < ends[np.clip(i, 0, None)])


def add_point_noise(
    p_tracker: np.ndarray, spec: TrackerSpec, rng: np.random.Generator
) -> np.ndarray:
    """Return tracker points (n, 3) with table-3.2 noise: per-coordinate std ``a + b * range``."""
    range_m = np.linalg.norm(p_tracker, axis=-1, keepdims=True)
    return p_tracker + rng.normal(size=p_tracker.shape) * (spec.noise_a_m + spec.noise_b * range_m)


def check_fraction(name: str, value: float, high: float = 0.2) -> float:
    """Return ``value`` if it is a fraction in [0, high], else raise InputError naming ``name``."""
    if not np.isfinite(value) or not 0.0 <= value <= high:
        raise InputError(f"{name}={value}: out of range [0, {high}]")
    return float(value)
