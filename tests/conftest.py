"""Shared, session-scoped fixtures: small simulated campaigns, made once per test session.

Keep them small: the whole suite must run in a few minutes on 2 cores. A test that needs a
special campaign (an effect, another seed) simulates its own, as short as it can.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support import SHARED


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The sibling ``shared/`` folder (data contract, thesis, real campaigns)."""
    if not SHARED.is_dir():
        pytest.skip("shared/ folder beside the repository is missing")
    return SHARED


@pytest.fixture(scope="session")
def small_campaign(tmp_path_factory) -> Path:
    """A small simulated tracker campaign (seed 1, about 4 minutes of driving, 9 runs)."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("campaign") / "small"
    simulate_campaign(out, seed=1, minutes=4.0)
    return out


@pytest.fixture(scope="session")
def small_trajectory(small_campaign, tmp_path_factory) -> Path:
    """``small_campaign`` preprocessed into a trajectory campaign (preprocess --out)."""
    from identification.preprocessing.preprocess import preprocess_campaign

    out = tmp_path_factory.mktemp("trajectory") / "small"
    preprocess_campaign(small_campaign, out)
    return out


# A campaign as independently generated tracker campaigns are recorded (issue 14): every message
# its own 2-12 ms receive latency, so spurious AT960 pulses next to real ones are stored out of
# stamp order (seed 4: in five runs), plus two tracker clock resets, one half-way through run_06
# (two parts of ~19 s) and one 15 % into run_09 (a part too short to keep).
FIELD_SEED, FIELD_MINUTES = 4, 4.0
FIELD_RESETS = {"run_06": ("at960", 0.5), "run_09": ("ltd800", 0.15)}


@pytest.fixture(scope="session")
def field_campaign(tmp_path_factory) -> Path:
    """The campaign of issue 14: receive jitter and two clock resets (see FIELD_RESETS)."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("field") / "jitter"
    simulate_campaign(out, seed=FIELD_SEED, minutes=FIELD_MINUTES, receive_jitter_s=True,
                      clock_resets=FIELD_RESETS)
    return out


@pytest.fixture(scope="session")
def field_twin(tmp_path_factory) -> Path:
    """``field_campaign`` without the receive jitter: every topic stored in stamp order."""
    from simulation.campaign import simulate_campaign

    out = tmp_path_factory.mktemp("field") / "twin"
    simulate_campaign(out, seed=FIELD_SEED, minutes=FIELD_MINUTES, clock_resets=FIELD_RESETS)
    return out
