"""GNSS faults laid over a degraded GNSS series: what a receiver in the field does wrong.

:func:`simulation.gnss.simulate_gnss` gives a receiver that behaves as its error budget says
(white noise, a Gauss-Markov bias, rare outliers, latency). Issue 14 asks what the estimators
survive when it does not; this module adds, to a :class:`groundfloor.gnss.GnssSeries`:

- **outliers**: single fixes displaced by metres (multipath on one epoch);
- **multipath bursts**: every fix valid in ``[start, end)`` biased by one horizontal offset
  (several seconds of reflections near a wall or under trees);
- **position jumps**: from a time on, every later fix displaced by the same offset (a wrong RTK
  ambiguity fix, a datum or base-station change), jumps adding up;
- **stated covariance too small**: the reported variance multiplied by ``cov_scale`` (0.1: the
  receiver claims ten times the precision it has);
- **outages**: no fix valid in ``[start, end)``, up to 60 s.

:class:`GnssFaults` is one realisation (every offset and interval written out), drawn by
:func:`draw_gnss_faults` from a :class:`FaultMix` with ``np.random.default_rng(seed)`` and laid
over a series by :func:`apply_gnss_faults`, deterministically, so that a test can check each
fault against its definition. Offsets are horizontal (local x, y); heights are left alone since
the estimators use the horizontal position only. ``flags`` records what was done, for scoring
only (an estimator must not read it).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from groundfloor.errors import InputError
from groundfloor.gnss import FLAG_OUTLIER, GnssSeries

log = logging.getLogger(__name__)

FLAG_BURST = 2  # fix inside a multipath burst
FLAG_JUMPED = 4  # fix after a position jump
COV_TOO_SMALL = 0.1  # reported covariance over the true one in the "stated covariance" fault
OUTAGE_CHOICES_S = (5.0, 10.0, 30.0, 60.0)  # as the benchmark's scheduled outages


def _empty2() -> np.ndarray:
    return np.empty((0, 2))


@dataclass(frozen=True)
class GnssFaults:
    """One realisation of GNSS faults, every value written out (times on the series's time base, s)."""

    outlier_t: np.ndarray = field(default_factory=lambda: np.empty(0))  # (k,) times of validity hit
    outlier_offset_m: np.ndarray = field(default_factory=_empty2)  # (k, 2) horizontal offsets
    bursts: np.ndarray = field(default_factory=_empty2)  # (b, 2) [start, end) of each burst
    burst_offset_m: np.ndarray = field(default_factory=_empty2)  # (b, 2) bias during each burst
    jump_t: np.ndarray = field(default_factory=lambda: np.empty(0))  # (j,) time of each jump
    jump_offset_m: np.ndarray = field(default_factory=_empty2)  # (j, 2) offset from then on
    cov_scale: float = 1.0  # reported covariance multiplied by this (0.1: ten times too small)
    outages: np.ndarray = field(default_factory=_empty2)  # (m, 2) [start, end) without fixes

    def kinds(self) -> tuple[str, ...]:
        """Return the names of the fault types present."""
        present = {"outliers": self.outlier_t.size, "multipath": len(self.bursts), "jump": self.jump_t.size,
                   "cov_small": self.cov_scale != 1.0, "outage": len(self.outages)}
        return tuple(k for k, on in present.items() if on)


@dataclass(frozen=True)
class FaultMix:
    """Which faults a Monte-Carlo run draws and from which ranges (all offsets horizontal, m)."""

    outlier_prob: float = 0.0  # per fix
    outlier_m: tuple[float, float] = (2.0, 20.0)  # offset magnitude, uniform
    n_bursts: tuple[int, int] = (0, 0)  # number of bursts, uniform integers inclusive
    burst_s: tuple[float, float] = (2.0, 10.0)  # burst duration, uniform
    burst_m: tuple[float, float] = (1.0, 5.0)  # burst bias magnitude, uniform
    n_jumps: int = 0
    jump_m: tuple[float, float] = (0.5, 5.0)  # jump magnitude, uniform
    cov_scale: float = 1.0
    n_outages: int = 0
    outage_choices_s: tuple[float, ...] = OUTAGE_CHOICES_S
    warmup_s: float = 30.0  # no fault before this: the filters converge on clean fixes first
    margin_s: float = 10.0  # an outage ends at least this long before the series does


FAULT_MIXES: dict[str, FaultMix] = {
    "none": FaultMix(),
    "outliers": FaultMix(outlier_prob=0.05),
    "multipath": FaultMix(n_bursts=(1, 3)),
    "jump": FaultMix(n_jumps=1),
    "cov_small": FaultMix(cov_scale=COV_TOO_SMALL),
    "outage": FaultMix(n_outages=1),
    "all": FaultMix(outlier_prob=0.05, n_bursts=(1, 3), n_jumps=1, cov_scale=COV_TOO_SMALL, n_outages=1),
}


def _directions(rng: np.random.Generator, magnitude: np.ndarray) -> np.ndarray:
    """Return ``(k, 2)`` horizontal offsets of the given magnitudes in uniformly random directions."""
    ang = rng.uniform(0.0, 2.0 * np.pi, magnitude.size)
    return np.column_stack([magnitude * np.cos(ang), magnitude * np.sin(ang)])


def draw_gnss_faults(t_valid: np.ndarray, mix: FaultMix, seed: int) -> GnssFaults:
    """Return a fault realisation for fixes valid at ``t_valid`` drawn from ``mix`` with ``seed``.

    Faults start after ``mix.warmup_s`` from the first fix. An outage's length is drawn from
    ``mix.outage_choices_s`` and its start uniformly so that it ends ``mix.margin_s`` before the
    last fix; bursts and jumps start uniformly in the faulted span, bursts may overlap.
    """
    t = np.asarray(t_valid, float)
    if t.size < 2:
        raise InputError("GNSS faults: need at least two fixes to lay faults over")
    rng = np.random.default_rng(seed)
    t0, t1 = t[0] + mix.warmup_s, t[-1]
    if t1 <= t0:
        raise InputError(f"GNSS faults: series of {t[-1] - t[0]:.1f} s is shorter than the "
                         f"{mix.warmup_s:g} s warm-up")
    late = t[t >= t0]
    hit = late[rng.random(late.size) < mix.outlier_prob]
    n_b = int(rng.integers(mix.n_bursts[0], mix.n_bursts[1] + 1))
    b_start = rng.uniform(t0, t1, n_b)
    bursts = np.column_stack([b_start, b_start + rng.uniform(*mix.burst_s, n_b)])
    jump_t = np.sort(rng.uniform(t0, t1, mix.n_jumps))
    outages = []
    for _ in range(mix.n_outages):
        d = float(rng.choice(mix.outage_choices_s))
        latest = t1 - mix.margin_s - d
        if latest < t0:
            raise InputError(f"GNSS faults: a {d:g} s outage does not fit in {t[-1] - t[0]:.1f} s of fixes "
                             f"after {mix.warmup_s:g} s warm-up and {mix.margin_s:g} s margin")
        a = rng.uniform(t0, latest)
        outages.append((a, a + d))
    return GnssFaults(hit, _directions(rng, rng.uniform(*mix.outlier_m, hit.size)), bursts,
                      _directions(rng, rng.uniform(*mix.burst_m, n_b)), jump_t,
                      _directions(rng, rng.uniform(*mix.jump_m, jump_t.size)), float(mix.cov_scale),
                      np.array(outages, float).reshape(-1, 2))


def apply_gnss_faults(series: GnssSeries, faults: GnssFaults) -> GnssSeries:
    """Return ``series`` with ``faults`` laid over it.

    Offsets add up where faults overlap (an outlier inside a burst after a jump carries all
    three); fixes in an outage are removed and the outage appended to ``series.outages``;
    the reported std is multiplied by ``sqrt(cov_scale)`` on every axis, so the stated
    covariance is exactly ``cov_scale`` times the generator's.
    """
    if not (np.isfinite(faults.cov_scale) and faults.cov_scale > 0):
        raise InputError(f"GNSS faults: cov_scale must be finite and > 0, got {faults.cov_scale}")
    t = np.asarray(series.t_valid, float)
    p = np.array(series.p_local, float)
    flags = np.array(series.flags, np.uint8)
    idx = np.searchsorted(t, faults.outlier_t)
    if np.any(idx >= t.size) or np.any(t[np.minimum(idx, t.size - 1)] != faults.outlier_t):
        raise InputError("GNSS faults: an outlier time is not the time of validity of a fix")
    p[idx, :2] += faults.outlier_offset_m
    flags[idx] |= FLAG_OUTLIER
    for (a, b), off in zip(faults.bursts, faults.burst_offset_m):
        inside = (t >= a) & (t < b)
        p[inside, :2] += off
        flags[inside] |= FLAG_BURST
    for tj, off in zip(faults.jump_t, faults.jump_offset_m):
        after = t >= tj
        p[after, :2] += off
        flags[after] |= FLAG_JUMPED
    o = faults.outages
    keep = ~np.any((t[:, None] >= o[:, 0]) & (t[:, None] < o[:, 1]), axis=1) if len(o) else np.ones(t.size, bool)
    outages = np.concatenate([np.asarray(series.outages, float).reshape(-1, 2), o])
    outages = outages[np.argsort(outages[:, 0], kind="stable")]
    return replace(series, t_valid=t[keep], t_arrival=np.asarray(series.t_arrival)[keep], p_local=p[keep],
                   std=np.asarray(series.std, float)[keep] * np.sqrt(faults.cov_scale), flags=flags[keep],
                   outages=outages)
