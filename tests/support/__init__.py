"""Builders shared by the tests and the bench scripts (small synthetic runs and campaigns)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]  # the checkout: examples/, docs/, simulation/data/
SHARED = REPO.parent / "shared"  # the sibling shared/ folder (data contract, thesis, real data)
