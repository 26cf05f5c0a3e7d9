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
