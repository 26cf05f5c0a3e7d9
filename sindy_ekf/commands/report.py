"""``sindy-ekf report CAMPAIGN --out DIR``: the whole chain as one self-contained HTML report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``report`` subcommand; return its parser."""
    p = sub.add_parser("report", parents=[common], help="the whole chain as one HTML report with figures",
                       description=__doc__.splitlines()[0])
    p.add_argument("campaign", type=Path, help="tracker or trajectory campaign")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for report.html (and model.json)")
    p.add_argument("--model", type=Path, default=None, metavar="MODEL.json",
                   help="model file of identify (default: identify one on the train runs)")
    p.add_argument("--quick", action="store_true",
                   help="identify with the quick grid (18 points, 3 folds) instead of the full one")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the headline figures as JSON")
    return p


def format_headline(chain) -> str:
    """Return the lines printed after a report or the demo: the key numbers of the chain."""
    lines = [f"campaign {chain.campaign_path} ({chain.kind}): {len(chain.trajectory.split('train'))} train, "
             f"{len(chain.trajectory.split('test'))} test runs"]
    if chain.model is not None:
        hp = ", ".join(f"{k} {v:g}" for k, v in chain.model.hyperparameters.items())
        lines.append(f"model: {chain.model.complexity} active terms ({hp})")
    if chain.evaluation:
        lines.append("5 s prediction error on the test runs (thesis model B, real data: 14.0 cm, 4.2 deg):")
        lines += [f"  {n:18} {100 * r.pos_err_5s_m:7.2f} cm {r.yaw_err_5s_deg:7.2f} deg"
                  for n, r in chain.evaluation.items()]
    if chain.benchmark is not None:
        b = chain.benchmark
        lines.append(f"estimation on the test runs, GNSS profile {b.profile}: ATE position, heading; "
                     "error at the end of the outages")
        for n, sc in b.scores.items():
            ends = ", ".join(f"{k} s {v:.2f} m" for k, v in sc.outage_pos_err_m.items())
            lines.append(f"  {n:18} {sc.ate_pos_m:7.3f} m {sc.ate_yaw_deg:7.2f} deg   {ends}")
    if chain.diagnosis is not None:
        d = chain.diagnosis
        lines.append(f"diagnosis: {d.verdict}; 5 s position error {100 * d.before['pos_err_5s_m']:.2f} cm -> "
                     f"{100 * d.after['pos_err_5s_m']:.2f} cm")
    return "\n".join(lines)


def format_problems(chain) -> str:
    """Return one line per stage that failed or did not run (printed on stderr), or ''."""
    return "\n".join([f"stage {stage} failed: {why}" for stage, why in chain.errors.items()]
                     + [f"stage {stage} not run: {why}" for stage, why in chain.skipped.items()
                        if why != "stage not requested"])


def run(args) -> int:
    """Run the chain, write the report, print where it is and the headline figures."""
    from groundfloor.files import atomic_write_json
    from sindy_ekf.report.chain import QUICK, run_chain
    from sindy_ekf.report.html import check_report_dir, render_report

    check_report_dir(args.out)
    chain = run_chain(args.campaign, args.out, model=args.model, grid=QUICK if args.quick else None)
    path = render_report(chain, args.out)
    if not args.quiet:
        print(format_headline(chain))
    if format_problems(chain):
        print(format_problems(chain), file=sys.stderr)
    print(f"report written to {path}")
    if args.json:
        atomic_write_json(args.json, {"report": str(path), **chain.headline()})
    return 0
