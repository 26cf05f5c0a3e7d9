"""``sindy-ekf inject CAMPAIGN OUT --effect NAME=VALUE``: hide an input-side effect in a real campaign's recorded inputs."""

from __future__ import annotations

import argparse
from pathlib import Path

from sindy_ekf.diagnose.inject import INJECTABLE, inject_campaign, injected_path, parse_effect


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``inject`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="trajectory campaign whose recorded inputs are rewritten")
    p.add_argument("out", type=Path, help="missing or empty output folder")
    p.add_argument("--effect", required=True, metavar="NAME=VALUE",
                   help="one of " + ", ".join(f"{k}={v.parameter}" for k, v in INJECTABLE.items()))


def run(args) -> int:
    """Check the effect, write the campaign with it hidden in the inputs, say where the truth is."""
    family, value = parse_effect(args.effect)
    out = inject_campaign(args.campaign, args.out, family, value)
    spec = INJECTABLE[family]
    print(f"{out}: {family} ({spec.mechanism}, {spec.parameter}={value:g}) hidden in the recorded inputs; "
          f"poses unchanged; truth in {injected_path(out)}")
    return 0
