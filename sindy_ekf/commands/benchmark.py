"""``sindy-ekf benchmark CAMPAIGN --model MODEL.json``: estimators against laser-tracker truth under degraded GNSS."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from groundfloor.files import atomic_write_json, check_outputs
from simulation.gnss import PROFILES
from sindy_ekf.benchmark.figures import write_benchmark_figures
from sindy_ekf.benchmark.files import write_benchmark
from sindy_ekf.benchmark.gnss_source import RECORDED
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.cli_workers import add_worker_arguments, workers_of
from sindy_ekf.config import load_config
from sindy_ekf.stages.estimation import benchmark_files


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``benchmark`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign (test runs are scored)")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="filter settings (YAML) merged over the defaults that `sindy-ekf config --defaults` prints; "
                        "--gnss, --seed and --estimators win over it")
    p.add_argument("--gnss", default=None, choices=sorted(PROFILES) + [RECORDED],
                   help="GNSS profile (default: the config's, dgnss); recorded: the campaign's own fixes "
                        "(gnss.csv or NavSatFix)")
    p.add_argument("--seed", type=int, default=None, help="seed of the GNSS errors (default: the config's, 0)")
    p.add_argument("--estimators", default=None, metavar="A,B,...",
                   help="comma-separated subset (default: those the config enables, all available: dead_reckoning, "
                        "cv_ekf, unicycle_ekf, lag_ekf, sindy_ekf, sindy_ekf_lateral (with the v_y = 0 pseudo-measurement), "
                        "oracle_ekf on simulated campaigns, sindy_graph, sindy_graph_lateral, sindy_isam2)")
    p.add_argument("--train", type=Path, default=None, metavar="CAMPAIGN",
                   help="campaign whose train runs fit the process noise, the unicycle gains and the lag (default: "
                        "CAMPAIGN's own; for a campaign of test runs only, e.g. the one the model was identified on)")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write TUM files of every estimate, the JSON and the plots into DIR")
    add_worker_arguments(p, 1, "smoothers' runs (sindy_graph, sindy_graph_lateral, sindy_isam2; the EKFs run "
                               "all runs in lockstep in one process)")


def _cell(value: float, width: int, decimals: int) -> str:
    """Return ``value`` right-aligned in ``width`` characters, in exponent form when too long."""
    text = f"{value:.{decimals}f}"
    return f"{text:>{width}}" if len(text) < width else f"{value:>{width}.1e}"


def format_scores(result: BenchmarkResult) -> str:
    """Return the table of scores: ATE, error at the end of each outage length, NEES, NIS, runtime,
    status (issue 14: ``diverged`` or ``failed`` rows are scored up to their time, see the notes)."""
    durations = sorted({k for s in result.scores.values() for k in s.outage_pos_err_m}, key=float)
    head = f"{'estimator':<20}{'ATE m':>8}{'ATE deg':>9}" + "".join(f"{'out ' + d + 's m':>11}" for d in durations)
    skipped = f", {len(result.skipped_runs)} skipped as too short" if result.skipped_runs else ""
    lines = [f"benchmark of {result.campaign} ({len(result.truth)} test runs{skipped}), GNSS {result.profile}, "
             f"alignment {result.alignment}", head + f"{'NEES':>8}{'NIS':>7}{'runtime s':>11}  status"]
    for name, s in result.scores.items():
        cells = "".join(_cell(s.outage_pos_err_m.get(d, float("nan")), 11, 3) for d in durations)
        lines.append(f"{name:<20}{_cell(s.ate_pos_m, 8, 3)}{_cell(s.ate_yaw_deg, 9, 2)}{cells}"
                     f"{_cell(s.nees_mean, 8, 2)}{_cell(s.nis_mean, 7, 2)}{s.runtime_s:>11.1f}  {s.status_text()}")
    return "\n".join(lines)


def status_warnings(result: BenchmarkResult) -> list[str]:
    """Return one line per test run skipped as too short and per estimator that did not finish
    (name, status, time and reason)."""
    return ([f"warning: {why}" for why in result.skipped_runs.values()]
            + [f"warning: {name} {s.status} at t={s.t_s:.2f} s, scored up to then: {s.reason}"
               for name, s in result.scores.items() if s.status != "ok"])


def run(args) -> int:
    """Run the benchmark, print a table, write JSON / TUM / plots when asked.

    Exit 0 when at least one estimator finished (each one that did not is a warning on stderr),
    1 when none did (the files are written all the same).
    """
    check_outputs(args, folders=("out",))
    config = load_config(args.config)  # a bad file fails here, before the work
    estimators = None if args.estimators is None else tuple(n.strip() for n in args.estimators.split(","))
    result = benchmark_files(args.campaign, args.model, profile=args.gnss, seed=args.seed, estimators=estimators,
                             config=config, workers=workers_of(args), train=args.train)
    if args.out is not None:
        write_benchmark(result, args.out)
        write_benchmark_figures(result, args.out)
    if args.json is not None:
        atomic_write_json(args.json, result.to_json())
    print(format_scores(result))
    if result.recorded_gnss:
        tr = result.recorded_gnss["enu_to_local"]
        std = f" +- {tr['yaw_std_deg']:.3f}" if tr["estimated"] else " (given)"
        print(f"recorded GNSS: ENU -> local yaw {tr['enu_to_local_yaw_deg']:.3f}{std} deg, t "
              f"({tr['enu_to_local_t_m'][0]:.3f}, {tr['enu_to_local_t_m'][1]:.3f}) m")
    for line in status_warnings(result):
        print(line, file=sys.stderr)
    if all(s.status != "ok" for s in result.scores.values()):
        print("sindy-ekf benchmark: error: no estimator finished (see the warnings)", file=sys.stderr)
        return 1
    return 0
