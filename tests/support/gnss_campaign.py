"""A small simulated campaign with recorded GNSS and its preprocessed form, built once per test
session (the GNSS tests of simulation, preprocessing and benchmark share it). Seed and length are
those of the session fixture ``small_campaign``: that campaign is its twin without GNSS."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from identification.preprocessing.preprocess import PreprocessResult, preprocess_campaign
from simulation.campaign import simulate_campaign

SEED, MINUTES = 1, 4.0  # as tests/conftest.py small_campaign
_BUILT: dict[str, "GnssCampaign"] = {}


@dataclass(frozen=True)
class GnssCampaign:
    """Paths of the campaign with recorded dgnss fixes and of its trajectory campaign."""

    tracker: Path
    trajectory: Path
    preprocessed: PreprocessResult


def gnss_campaign(tmp_path_factory) -> GnssCampaign:
    """Return the session's GNSS campaign (simulated and preprocessed on first use)."""
    if "c" not in _BUILT:
        root = tmp_path_factory.mktemp("gnss_campaign")
        simulate_campaign(root / "tracker", seed=SEED, minutes=MINUTES, gnss="dgnss")
        result = preprocess_campaign(root / "tracker", root / "trajectory")
        _BUILT["c"] = GnssCampaign(root / "tracker", root / "trajectory", result)
    return _BUILT["c"]
