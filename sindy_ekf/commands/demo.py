"""``sindy-ekf demo``: the whole chain on a built-in simulated campaign, ending in an HTML report.

Simulates a short campaign (seed 0, 8 minutes of driving in the 9 runs of thesis table 6.4),
preprocesses it (synchronisation, hub model, poses, body states), identifies a SINDy model with
a reduced but real grid search (the search's quick grid, 3-fold CV by run), evaluates it against
the baselines and the simulator's true dynamics, benchmarks the estimators through several
GNSS outages of 5 and 10 s and diagnoses the model, and writes ``OUT/report/report.html`` (:mod:`sindy_ekf.report.demo`). ``OUT`` itself is
the simulated tracker campaign (with ``truth/``; readers ignore the ``report/`` folder beside
``runs/``), so every other command can be pointed at it. Prints what the campaign holds, the
headline figures and where the report is; stages that failed are named on stderr and make the
exit code 1 (the report is still written). The default output folder ``./demo-out`` is
replaced on every run; any other non-empty folder needs ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from groundfloor.files import atomic_write_json, check_outputs
from sindy_ekf.cli_workers import add_worker_arguments, workers_of
from sindy_ekf.commands.report import format_headline, format_problems
from sindy_ekf.commands.simulate import format_table
from sindy_ekf.report.demo import (
    DEFAULT_OUT,
    DEMO_MINUTES,
    demo_report,
    simulate_demo_campaign,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``demo`` arguments to its parser."""
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (default: ./demo-out)")
    p.add_argument("--minutes", type=float, default=DEMO_MINUTES, help=f"driving time to simulate (default {DEMO_MINUTES:g})")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="a dynamics effect for the simulator to hide (e.g. input_delay=0.15)")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the headline figures as JSON")
    add_worker_arguments(p, 1, "grid points, smoother runs and diagnosis families")


def run(args) -> int:
    """Simulate, run the chain, write the report; print where it is and the headline figures."""
    check_outputs(args)
    campaign = simulate_demo_campaign(args.out, seed=args.seed, minutes=args.minutes, effects=args.effect,
                                      force=args.force)
    truth = campaign.truth
    effect = ", ".join(f"{n}={v:g}" for n, v in truth.effects) or "none"
    print(f"simulated campaign {campaign.path}: {len(truth.runs)} runs, "
          f"{sum(r.duration_s for r in truth.runs) / 60:.1f} min, seed {truth.seed}, hidden effect: {effect}")
    print(format_table(truth))
    demo = demo_report(campaign, workers_of(args))
    chain = demo.report.chain
    print(format_headline(chain))
    if format_problems(chain):
        print(format_problems(chain), file=sys.stderr)
    print(f"report written to {demo.report.path} ({demo.wall_s:.0f} s in all)")
    if args.json is not None:
        atomic_write_json(args.json, demo.to_json())
    if chain.errors:  # the report is written and names them; the exit code says the chain is broken
        print(f"demo: {len(chain.errors)} stage(s) failed: {', '.join(chain.errors)}", file=sys.stderr)
        return 1
    return 0
