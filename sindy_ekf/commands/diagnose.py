"""``sindy-ekf diagnose CAMPAIGN --model MODEL.json``: what the model gets wrong, its cause, the gain of the fix."""

from __future__ import annotations

import argparse
from pathlib import Path

from groundfloor.files import atomic_write_json, check_outputs
from groundfloor.numbers import format_sig
from identification.preprocessing.campaigns import train_campaign_of
from sindy_ekf.cli_workers import add_worker_arguments, workers_of
from sindy_ekf.diagnose import Diagnosis, diagnose_campaign
from sindy_ekf.diagnose.figures import write_diagnosis_figures
from sindy_ekf.diagnose.gain_profile import shown_estimate
from sindy_ekf.diagnose.residuals import top_structure


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``diagnose`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign (train runs fit, test runs score)")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--train", type=Path, default=None, metavar="CAMPAIGN",
                   help="campaign whose train runs fit the mechanisms (default: CAMPAIGN's own; for a campaign of "
                        "test runs only, e.g. the one the model was identified on)")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--plots", type=Path, default=None, metavar="DIR",
                   help="write residual structure, lag, family profiles and error curves into DIR")
    p.add_argument("--no-ekf", action="store_true", help="skip the EKF dead-reckoning through 10 s GNSS outages")
    p.add_argument("--extended-model", type=Path, default=None, metavar="PATH",
                   help="write the extended model (JSON) when a cause is found; diagnose scores it "
                        "itself, evaluate and benchmark take the model files of identify (an unexplained verdict's "
                        "refit of the model's own terms is one)")
    add_worker_arguments(p, 1, "families")


def format_diagnosis(d: Diagnosis, model: Path, campaign: Path) -> str:
    """Return the ranking of the families, the gain of the extension and the measurement findings."""
    lines = [f"diagnosis of {model.name} on {campaign}: most likely cause: {d.verdict}",
             f"{'family':20} {'test gain %':>11} {'threshold %':>11}  estimate"]
    for c in d.ranked:
        est = ", ".join(f"{k}={format_sig(v, 4)}" for k, v in shown_estimate(c.score.estimate).items())
        flag = "*" if c.significant else " "
        lines.append(f"{c.name:20} {100 * c.gain:11.2f} {100 * c.threshold:11.2f} {flag} {est}")
        if c.note:
            lines.append(f"{'':20} note: {c.note}")
        if "gain_profile_monotone" in c.score.estimate:  # a named decay's shape, relative to its first bin
            e = c.score.estimate
            lines.append(f"{'':20} gain over time since the run start (monotone fit): " + ", ".join(
                f"{t:.0f} s {g / e['gain_profile_monotone'][0]:.3f}"
                for t, g in zip(e["gain_profile_t_s"], e["gain_profile_monotone"])))
    lines += d.unexplained_notes()
    b, a = d.before, d.after
    lines.append(f"5 s error on the test runs ({b.n_windows} windows): position {100 * b.pos_err_5s_m:.2f} -> "
                 f"{100 * a.pos_err_5s_m:.2f} cm, heading {b.yaw_err_5s_deg:.2f} -> {a.yaw_err_5s_deg:.2f} deg")
    if d.extension_warning():
        lines.append(f"warning: {d.extension_warning()}")
    if d.missing_law_warning():
        lines.append(f"warning: {d.missing_law_warning()}")
    if d.outage.get("n"):
        lines.append(f"EKF after {d.outage['outage_s']:g} s GNSS outages (RMS of {d.outage['n']}): "
                     f"{d.outage['before_m']:.3f} -> {d.outage['after_m']:.3f} m")
    lines.append("strongest residual structure: " + "; ".join(f"{eq} vs {r} eta2={e:.2f}" for eq, r, e, _ in
                                                              top_structure(d.structure, 3)))
    for f in d.measurement:
        g = f.gain["baseline_rms_m"]
        lines.append(f"measurement: {f.name}: {f.cause}; correction: {f.correction}; baseline RMS "
                     f"{1e6 * g['before']:.0f} -> {1e6 * g['after']:.0f} um ({f.runs} runs)")
    return "\n".join(lines)


def run(args) -> int:
    """Diagnose, print the ranking and the gain, write JSON, plots and the extended model on request."""
    check_outputs(args)
    train = train_campaign_of(args.train)
    d = diagnose_campaign(args.campaign, args.model, ekf=not args.no_ekf, workers=workers_of(args),
                          train_runs=None if train is None else train.split("train"))
    print(format_diagnosis(d, args.model, args.campaign))
    if args.plots:
        write_diagnosis_figures(d, args.plots)
    if args.extended_model and d.extended is not None:
        d.extended.to_json(args.extended_model)
    if args.json:
        atomic_write_json(args.json, d.to_json())
    return 0
