"""``sindy-ekf benchmark CAMPAIGN --model MODEL.json``: estimators against laser-tracker truth under degraded GNSS."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``benchmark`` subcommand; return its parser."""
    from simulation.gnss import PROFILES

    p = sub.add_parser("benchmark", parents=[common], help="EKFs, factor graph and dead reckoning "
                       "against the laser-tracker poses with degraded GNSS and outages",
                       description=__doc__.splitlines()[0])
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign (test runs are scored)")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--gnss", default="dgnss", choices=sorted(PROFILES), help="GNSS profile (default dgnss)")
    p.add_argument("--seed", type=int, default=0, help="seed of the GNSS errors (default 0)")
    p.add_argument("--estimators", default=None, metavar="A,B,...",
                   help="comma-separated subset (default: all available: dead_reckoning, cv_ekf, unicycle_ekf, "
                        "sindy_ekf, sindy_ekf_lateral (with the v_y = 0 pseudo-measurement), oracle_ekf on "
                        "simulated campaigns, sindy_graph, sindy_graph_lateral, sindy_isam2)")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write TUM files of every estimate, the JSON and the plots into DIR")
    return p


def oracle_dynamics_for(campaign_dir: Path):
    """Return ``simulation.robot.TrueDynamics`` of a simulated campaign (with its effect), or None."""
    if not (Path(campaign_dir) / "truth" / "truth.yaml").is_file():
        return None
    from simulation.effects import Effect
    from simulation.robot import TrueDynamics
    from simulation.truth import read_truth

    truth = read_truth(campaign_dir, states=False)
    effect = Effect(*truth.effects[0]) if truth.effects else None
    return TrueDynamics(effect=effect)


def run(args) -> int:
    """Run the benchmark, print a table, write JSON / TUM / plots when asked."""
    from groundfloor.errors import InputError
    from groundfloor.files import atomic_write_json
    from identification.preprocessing.campaigns import open_campaign
    from identification.sindy.model import SindyModel
    from sindy_ekf.benchmark.run import ESTIMATORS, benchmark_campaign, write_benchmark

    model = SindyModel.load(args.model)
    campaign = open_campaign(args.campaign)
    oracle = oracle_dynamics_for(args.campaign)
    names = ESTIMATORS if args.estimators is None else tuple(n.strip() for n in args.estimators.split(","))
    if oracle is None and args.estimators is None:
        names = tuple(n for n in names if n != "oracle_ekf")
    if "oracle_ekf" in names and oracle is None:
        raise InputError(f"{args.campaign}: oracle_ekf needs a simulated campaign (truth/truth.yaml)")
    s = model.hyperparameters.get("s")  # Q and the unicycle from states at the model's own smoothing
    result = benchmark_campaign(campaign, model, profile=args.gnss, seed=args.seed,
                                oracle_dynamics=oracle, estimators=names, smoothing=None if s is None else float(s))
    if args.out is not None:
        from sindy_ekf.benchmark.figures import write_benchmark_figures

        write_benchmark(result, args.out)
        write_benchmark_figures(result, args.out)
    if args.json is not None:
        atomic_write_json(args.json, result.to_json())
    durations = sorted({k for s in result.scores.values() for k in s.outage_pos_err_m}, key=float)
    print(f"benchmark of {campaign.name} ({len(result.truth)} test runs), GNSS {result.profile}, "
          f"alignment {result.alignment}")
    head = f"{'estimator':<16}{'ATE m':>8}{'ATE deg':>9}" + "".join(f"{'out ' + d + 's m':>11}" for d in durations)
    print(head + f"{'NEES':>8}{'runtime s':>11}")
    for name, s in result.scores.items():
        cells = "".join(f"{s.outage_pos_err_m.get(d, float('nan')):>11.3f}" for d in durations)
        print(f"{name:<16}{s.ate_pos_m:>8.3f}{s.ate_yaw_deg:>9.2f}{cells}{s.nees_mean:>8.2f}{s.runtime_s:>11.1f}")
    return 0
