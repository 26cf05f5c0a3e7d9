"""``sindy-ekf evaluate CAMPAIGN --model MODEL.json``: 5 s multi-step prediction error on the test runs."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from groundfloor.errors import InputError

log = logging.getLogger(__name__)


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``evaluate`` subcommand; return its parser."""
    p = sub.add_parser("evaluate", parents=[common], help="multi-step prediction error on the test runs",
                       description=__doc__.splitlines()[0])
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--plots", type=Path, default=None, metavar="DIR", help="write fig. 5.11/7.8 curves into DIR")
    return p


def oracle_for(campaign_dir: Path):
    """Return the simulator's true dynamics of a simulated campaign as a model, or None.

    Only the truth's dynamics effect is used (to score against the best any model can do);
    input-side effects (delay, deadband, ...) are not applied to the recorded inputs.
    """
    if not (Path(campaign_dir) / "truth" / "truth.yaml").is_file():
        return None
    from simulation.effects import Effect
    from simulation.robot import TrueDynamics
    from simulation.truth import read_truth

    truth = read_truth(campaign_dir, states=False)
    effect = Effect(*truth.effects[0]) if truth.effects else None
    return TrueDynamics(effect=effect)


def run(args) -> int:
    """Evaluate model, baselines and (simulated campaigns) the oracle; print and write JSON."""
    from groundfloor.files import atomic_write_json
    from identification.preprocessing.campaigns import open_campaign
    from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel
    from identification.sindy.evaluate import evaluate_on_runs
    from identification.sindy.model import SindyModel
    from identification.sindy.data import states_of_runs

    model = SindyModel.load(args.model)
    campaign = open_campaign(args.campaign)
    test = campaign.split("test")
    if not test:
        raise InputError(f"{args.campaign}: campaign.yaml marks no run as test")
    s = model.hyperparameters.get("s")
    s = 0.0 if s is None else float(s)
    models = {"sindy": model, "constant_velocity": ConstantVelocityModel()}
    train = campaign.split("train")
    if train:
        segs, _, _ = states_of_runs(train, s)
        models["unicycle"] = UnicycleModel().fit(segs)
    oracle = oracle_for(args.campaign)
    if oracle is not None:
        models["oracle"] = oracle
    res = evaluate_on_runs(models, test, s, methods=("rk4", "euler2"))
    main = res["sindy"]["rk4"]
    out = main.summary()
    out["euler2"] = res["sindy"]["euler2"].summary()
    out["baselines"] = {n: r["rk4"].summary() for n, r in res.items() if n not in ("sindy", "oracle")}
    if "oracle" in res:
        out["oracle"] = res["oracle"]["rk4"].summary()
    print(f"{len(test)} test runs of {campaign.name}, {main.n_windows} windows of 5 s (50 % overlap)")
    print(f"{'model':18} {'pos 5s cm':>9} {'yaw 5s deg':>10}   (thesis model B on real data: 14.0 cm, 4.2 deg)")
    for name, r in res.items():
        for method, e in r.items():
            if method == "rk4" or name == "sindy":
                label = name if method == "rk4" else f"{name} (Euler 2-step)"
                print(f"{label:18} {100 * e.pos_err_5s_m:9.2f} {e.yaw_err_5s_deg:10.2f}")
    if args.plots:
        from identification.sindy.figures import plot_error_curves

        args.plots.mkdir(parents=True, exist_ok=True)
        plot_error_curves([main], path=args.plots / "prediction_errors_sindy.png")
        plot_error_curves([r["rk4"] for r in res.values()], path=args.plots / "prediction_errors_all.png",
                          stacked=False)
    if args.json:
        atomic_write_json(args.json, out)
    return 0
