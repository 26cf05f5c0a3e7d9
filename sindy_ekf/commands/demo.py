"""``sindy-ekf demo``: the whole chain on a built-in simulated campaign (first step: simulate).

This first version simulates a short campaign (into a temporary folder, or ``--out``) and
prints what it holds: runs, durations, message counts per topic read back from the bags, and
the lost/spurious pulses and dropouts the simulator put in. Later stages append to ``run``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from sindy_ekf.io_utils import atomic_write_json

DEMO_MINUTES = 4.0


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``demo`` subcommand; return its parser."""
    p = sub.add_parser("demo", parents=[common], help="the whole chain on a built-in simulated campaign",
                       description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=None, help="folder for the campaign (default: temporary)")
    p.add_argument("--minutes", type=float, default=DEMO_MINUTES, help="driving time to simulate")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write a JSON summary")
    return p


def simulate_step(out: Path, args) -> dict:
    """Simulate the demo campaign into ``out``, print what it holds; return the summary."""
    from simulation.bags import count_messages
    from simulation.campaign import simulate_campaign
    from sindy_ekf.commands.simulate import summary

    truth = simulate_campaign(out, seed=args.seed, minutes=args.minutes, force=args.force)
    result = summary(truth)
    print(f"demo campaign {out}: {len(truth.runs)} runs, "
          f"{sum(r.duration_s for r in truth.runs) / 60:.1f} min of driving, seed {truth.seed}")
    print(f"{'run':8} {'split':5} {'dur s':>6} {'trigger':>7} {'at960':>6} {'ltd800':>6} {'joy':>5} {'hub':>5}"
          f" {'lost':>4} {'spur':>4} {'dropouts a/l':>12}")
    for r in truth.runs:
        counts = count_messages(out / "runs" / r.name)
        result["runs"][r.name]["messages"] = counts
        print(f"{r.name:8} {r.split:5} {r.duration_s:6.1f} {counts.get('/rpi/trigger', 0):7d} "
              f"{counts.get('/at960/measurement', 0):6d} {counts.get('/ltd800/measurement', 0):6d} "
              f"{counts.get('/joy_teleop/joy', 0):5d} {counts.get('/turning_hub/azimuth', 0):5d} "
              f"{r.at960['n_lost']:4d} {r.at960['n_spurious']:4d} "
              f"{len(r.at960['dropouts_utc']):>6d}/{len(r.ltd800['dropouts_utc']):<5d}")
    return result


def run(args) -> int:
    """Run the demo; return the exit code."""
    with tempfile.TemporaryDirectory(prefix="sindy-ekf-demo-") as tmp:
        out = args.out if args.out is not None else Path(tmp) / "campaign"
        result = {"simulate": simulate_step(out, args)}
        if args.json is not None:
            atomic_write_json(args.json, result)
    return 0
