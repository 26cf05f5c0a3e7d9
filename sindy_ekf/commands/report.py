"""``sindy-ekf report CAMPAIGN --out DIR``: the whole chain as one self-contained HTML report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from groundfloor.files import atomic_write_json, check_outputs
from identification.sindy.search import QUICK_GRID
from sindy_ekf.cli_workers import add_worker_arguments, workers_of
from sindy_ekf.config import load_config
from sindy_ekf.report.html import build_report
from sindy_ekf.stages.chain import ChainResult


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``report`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="tracker or trajectory campaign")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for report.html (and model.json)")
    p.add_argument("--model", type=Path, default=None, metavar="MODEL.json",
                   help="model file of identify (default: identify one on the train runs)")
    p.add_argument("--train", type=Path, default=None, metavar="CAMPAIGN",
                   help="campaign whose train runs every stage fits on (default: CAMPAIGN's own; for a campaign of "
                        "test runs only, e.g. the one the model was identified on)")
    p.add_argument("--quick", action="store_true",
                   help=f"identify with the quick grid ({QUICK_GRID.size} points, {QUICK_GRID.n_folds} folds) "
                        "instead of the full one")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the benchmark's filter settings (YAML over the defaults of `sindy-ekf config --defaults`)")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the headline figures as JSON")
    add_worker_arguments(p, 1, "grid points, smoother runs and diagnosis families")


def format_headline(chain: ChainResult) -> str:
    """Return the lines printed after a report or the demo: the key numbers of the chain."""
    lines = [f"campaign {chain.campaign_path} ({chain.kind}): {len(chain.trajectory.split('train'))} train, "
             f"{len(chain.trajectory.split('test'))} test runs"]
    if chain.model is not None:
        # numbers as %g; the library name, the lag structure's name and the dead times as they are
        hp = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else f"{k} {v}"
                       for k, v in chain.model.hyperparameters.items() if k not in ("dead_time_s", "input_lag_s"))
        m = chain.model  # the input chain in milliseconds, as `identify` prints it (not 1e-12 s of round-off)
        lines.append(f"model: {m.complexity} active terms ({hp}); dead time u1 {1000 * m.dead_time_s[0]:.0f} ms, "
                     f"u2 {1000 * m.dead_time_s[1]:.0f} ms; input lag u1 {1000 * m.input_lag_s[0]:.0f} ms, "
                     f"u2 {1000 * m.input_lag_s[1]:.0f} ms")
    errors = chain.prediction_errors()
    if errors:
        lines.append("5 s prediction error on the test runs (thesis model B, real data: 14.0 cm, 4.2 deg):")
        lines += [f"  {n:18} {100 * e.pos_err_5s_m:7.2f} cm {e.yaw_err_5s_deg:7.2f} deg" for n, e in errors.items()]
    if chain.benchmark is not None:
        b = chain.benchmark
        lines.append(f"estimation on the test runs, GNSS profile {b.profile}: ATE position, heading; "
                     "error at the end of the outages")
        width = max(18, *(len(n) for n in b.scores))
        for n, sc in b.scores.items():
            ends = ", ".join(f"{k} s {v:.2f} m" for k, v in sc.outage_pos_err_m.items())
            lines.append(f"  {n:{width}} {sc.ate_pos_m:7.3f} m {sc.ate_yaw_deg:7.2f} deg   {ends}")
    if chain.diagnosis is not None:
        d = chain.diagnosis
        lines.append(f"diagnosis: {d.verdict}; 5 s position error {100 * d.before.pos_err_5s_m:.2f} cm -> "
                     f"{100 * d.after.pos_err_5s_m:.2f} cm")
    return "\n".join(lines)


def format_problems(chain: ChainResult) -> str:
    """Return one line per stage that failed or did not run (printed on stderr), or ''."""
    return "\n".join([f"stage {stage} failed: {why}" for stage, why in chain.errors.items()]
                     + [f"stage {stage} not run: {why}" for stage, why in chain.skipped.items()
                        if why != "stage not requested"])


def run(args) -> int:
    """Run the chain, write the report, print where it is and the headline figures."""
    check_outputs(args, folders=("out",))
    config = load_config(args.config)  # a bad file fails here, before the work
    report = build_report(args.campaign, args.out, model=args.model, quick=args.quick, config=config,
                          workers=workers_of(args), train=args.train)
    if not args.quiet:
        print(format_headline(report.chain))
    if format_problems(report.chain):
        print(format_problems(report.chain), file=sys.stderr)
    print(f"report written to {report.path}")
    if args.json:
        atomic_write_json(args.json, report.to_json())
    return 0
