"""``sindy-ekf demo``: the whole chain on a built-in simulated campaign, ending in an HTML report.

Simulates a short campaign (seed 0, 4 minutes of driving in the 9 runs of thesis table 6.4),
preprocesses it (synchronisation, hub model, poses, body states), identifies a SINDy model with
a reduced but real grid search (2 tau x 3 alpha x 3 T, 3-fold CV by run), evaluates it against
the baselines and the simulator's true dynamics, benchmarks the estimators and diagnoses the
model, and writes ``OUT/report/report.html``. ``OUT`` itself is the simulated tracker campaign
(with ``truth/``; readers ignore the ``report/`` folder beside ``runs/``), so every other command
can be pointed at it. Prints what the campaign holds, the headline figures and where the report
is; stages that failed are named on stderr and make the exit code 1 (the report is still
written). The default output folder ``./demo-out`` is
replaced on every run; any other non-empty folder needs ``--force``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from groundfloor.errors import InputError

DEMO_MINUTES = 4.0
DEFAULT_OUT = Path("demo-out")
MARKER = ".sindy-ekf-demo"  # marks a folder the demo wrote, so a rerun may replace it


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``demo`` subcommand; return its parser."""
    p = sub.add_parser("demo", parents=[common], help="the whole chain on a built-in simulated campaign",
                       description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (default: ./demo-out)")
    p.add_argument("--minutes", type=float, default=DEMO_MINUTES, help="driving time to simulate")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="a dynamics effect for the simulator to hide (e.g. input_delay=0.15)")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the headline figures as JSON")
    return p


def check_out(out: Path, force: bool) -> Path:
    """Return ``out`` if the demo may (re)write it, else raise InputError naming it.

    A missing or empty folder, one the demo wrote before (it holds the marker file) or any
    folder with ``force`` is fine; the parent must be writable.
    """
    from sindy_ekf.report.html import check_report_dir

    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: output exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (force or (out / MARKER).is_file()):
        raise InputError(f"{out}: output folder is not empty and not a demo folder (use --force to replace it)")
    check_report_dir(out.parent if out.parent != Path("") else Path("."))
    return out


def run(args) -> int:
    """Simulate, run the chain, write the report; print where it is and the headline figures."""
    from groundfloor.files import atomic_write_json
    from simulation.campaign import simulate_campaign
    from sindy_ekf.commands.report import format_headline, format_problems
    from sindy_ekf.commands.simulate import format_table
    from sindy_ekf.report.chain import QUICK, run_chain
    from sindy_ekf.report.html import render_report

    tic = time.perf_counter()
    campaign = check_out(args.out, args.force)
    # the simulator writes the campaign atomically (a temporary sibling renamed into place)
    truth = simulate_campaign(campaign, seed=args.seed, minutes=args.minutes, effects=args.effect, force=True)
    (campaign / MARKER).write_text("written by sindy-ekf demo; rerunning the demo replaces this folder\n")
    t_simulate = time.perf_counter() - tic
    effect = ", ".join(f"{n}={v:g}" for n, v in truth.effects) or "none"
    print(f"simulated campaign {campaign}: {len(truth.runs)} runs, {sum(r.duration_s for r in truth.runs) / 60:.1f} "
          f"min, seed {truth.seed}, hidden effect: {effect}")
    print(format_table(truth))
    chain = run_chain(campaign, campaign / "report", grid=QUICK)
    tic_render = time.perf_counter()
    path = render_report(chain, campaign / "report")
    chain.seconds = {"simulate": t_simulate, **chain.seconds, "render": time.perf_counter() - tic_render}
    print(format_headline(chain))
    if format_problems(chain):
        print(format_problems(chain), file=sys.stderr)
    print(f"report written to {path} ({time.perf_counter() - tic:.0f} s in all)")
    if args.json is not None:
        atomic_write_json(args.json, {"report": str(path), "seed": truth.seed, "minutes": truth.minutes,
                                      "effects": [{"name": n, "value": v} for n, v in truth.effects],
                                      "wall_s": time.perf_counter() - tic, **chain.headline()})
    if chain.errors:  # the report is written and names them; the exit code says the chain is broken
        print(f"demo: {len(chain.errors)} stage(s) failed: {', '.join(chain.errors)}", file=sys.stderr)
        return 1
    return 0
