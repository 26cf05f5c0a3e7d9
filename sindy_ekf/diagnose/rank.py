"""Ranking the families by their out-of-sample gain, with thresholds calibrated on effect-free data.

A family's gain is the relative drop of the weighted window-residual sum of squares on the test
runs (:func:`sindy_ekf.diagnose.families.score_family`). Even without any effect a flexible
mechanism buys a little on the test runs by chance (or by fitting what the model gets slightly
wrong everywhere), so each family has its own significance threshold, calibrated on effect-free
simulated campaigns: the threshold is a margin times the largest gain that family reached on
any of them (see :data:`THRESHOLD_PROVENANCE`). A family counts only above its threshold; the
most likely cause is the significant family with the largest gain;
none significant gives ``none``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from sindy_ekf.diagnose.families import FAMILIES, FamilyScore

# Largest test-run gain per family over the effect-free calibration campaigns, times MARGIN.
NULL_MAX_GAIN = {
    "input_delay": 0.004, "heading_dependence": 0.012, "position_dependence": 0.03,
    "time_dependence": 0.012, "asymmetry": 0.006, "deadband": 0.004, "lateral_slip": 0.01,
}
MARGIN = 2.0
MIN_THRESHOLD = 0.01
THRESHOLDS = {f: max(MARGIN * NULL_MAX_GAIN[f], MIN_THRESHOLD) for f in FAMILIES}
THRESHOLD_PROVENANCE = (
    "provisional values from a first effect-free study; "
    "replace by `python bench/bench_diagnose.py --calibrate` output"
)


@dataclass(frozen=True)
class RankedCause:
    """One family in the ranking: its score, threshold and whether it is significant."""

    name: str
    gain: float
    threshold: float
    significant: bool
    score: FamilyScore

    @property
    def strength(self) -> float:
        """Gain in units of the family's threshold (what the ranking sorts by)."""
        return self.gain / self.threshold


def rank_families(scores: Sequence[FamilyScore], thresholds: dict[str, float] | None = None) -> list[RankedCause]:
    """Return the families sorted most likely first: significant ones by gain over threshold, then the rest."""
    thresholds = THRESHOLDS if thresholds is None else thresholds
    ranked = [RankedCause(s.family, s.gain, thresholds[s.family], s.gain > thresholds[s.family], s)
              for s in scores]
    # among the significant, the largest out-of-sample gain wins: the gain is comparable across
    # families (same residual, same weights), the threshold only says whether it is real
    return sorted(ranked, key=lambda c: (not c.significant, -c.gain))


def verdict(ranked: Sequence[RankedCause]) -> str:
    """Return the most likely family, or ``"none"`` when no family is significant."""
    return ranked[0].name if ranked and ranked[0].significant else "none"
