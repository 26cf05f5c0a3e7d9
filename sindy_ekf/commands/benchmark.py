"""``sindy-ekf benchmark CAMPAIGN --model MODEL.json``: estimators against laser-tracker truth under degraded GNSS."""

from __future__ import annotations

import argparse
from pathlib import Path

from groundfloor.files import atomic_write_json
from simulation.gnss import PROFILES
from sindy_ekf.benchmark.figures import write_benchmark_figures
from sindy_ekf.benchmark.files import write_benchmark
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.stages.estimation import benchmark_files


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``benchmark`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign (test runs are scored)")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--gnss", default="dgnss", choices=sorted(PROFILES), help="GNSS profile (default dgnss)")
    p.add_argument("--seed", type=int, default=0, help="seed of the GNSS errors (default 0)")
    p.add_argument("--estimators", default=None, metavar="A,B,...",
                   help="comma-separated subset (default: all available: dead_reckoning, cv_ekf, unicycle_ekf, "
                        "lag_ekf, sindy_ekf, sindy_ekf_lateral (with the v_y = 0 pseudo-measurement), oracle_ekf "
                        "on simulated campaigns, sindy_graph, sindy_graph_lateral, sindy_isam2)")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write TUM files of every estimate, the JSON and the plots into DIR")


def format_scores(result: BenchmarkResult) -> str:
    """Return the table of scores: ATE, error at the end of each outage length, NEES, runtime."""
    durations = sorted({k for s in result.scores.values() for k in s.outage_pos_err_m}, key=float)
    head = f"{'estimator':<16}{'ATE m':>8}{'ATE deg':>9}" + "".join(f"{'out ' + d + 's m':>11}" for d in durations)
    lines = [f"benchmark of {result.campaign} ({len(result.truth)} test runs), GNSS {result.profile}, "
             f"alignment {result.alignment}", head + f"{'NEES':>8}{'runtime s':>11}"]
    for name, s in result.scores.items():
        cells = "".join(f"{s.outage_pos_err_m.get(d, float('nan')):>11.3f}" for d in durations)
        lines.append(f"{name:<16}{s.ate_pos_m:>8.3f}{s.ate_yaw_deg:>9.2f}{cells}{s.nees_mean:>8.2f}"
                     f"{s.runtime_s:>11.1f}")
    return "\n".join(lines)


def run(args) -> int:
    """Run the benchmark, print a table, write JSON / TUM / plots when asked."""
    estimators = None if args.estimators is None else tuple(n.strip() for n in args.estimators.split(","))
    result = benchmark_files(args.campaign, args.model, profile=args.gnss, seed=args.seed, estimators=estimators)
    if args.out is not None:
        write_benchmark(result, args.out)
        write_benchmark_figures(result, args.out)
    if args.json is not None:
        atomic_write_json(args.json, result.to_json())
    print(format_scores(result))
    return 0
