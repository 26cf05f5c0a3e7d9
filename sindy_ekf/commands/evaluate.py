"""``sindy-ekf evaluate CAMPAIGN --model MODEL.json``: 5 s multi-step prediction error on the test runs."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from groundfloor.files import atomic_write_json, check_outputs
from sindy_ekf.stages.evaluation import CV_PREDICTION_LEVEL, LAG, MODEL, Evaluation, evaluate_files
from sindy_ekf.stages.figures import write_evaluation_figures


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``evaluate`` arguments to its parser."""
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign")
    p.add_argument("--model", type=Path, required=True, metavar="MODEL.json", help="model file of identify")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--plots", type=Path, default=None, metavar="DIR", help="write fig. 5.11/7.8 curves into DIR")
    p.add_argument("--train", type=Path, default=None, metavar="CAMPAIGN",
                   help="campaign whose train runs fit the unicycle and lag baselines (default: CAMPAIGN's own; "
                        "for a campaign of test runs only, e.g. the one the model was identified on)")


def format_errors(ev: Evaluation) -> str:
    """Return the table of 5 s errors (every model with RK4, the identified one also with 2-step
    Euler), whether the model beats the lag baseline, its CV estimate and the score's
    sensitivity to the start-state smoothing."""
    lines = [f"{ev.n_test_runs} test runs of {ev.campaign}, {ev.model.n_windows} windows of 5 s (50 % overlap), "
             f"start states at the reference smoothing s = {ev.reference_smoothing:g}",
             f"{'model':20} {'pos 5s cm':>9} {'yaw 5s deg':>10}   (thesis model B on real data: 14.0 cm, 4.2 deg)"]
    for name, r in ev.results.items():
        for method, e in r.items():
            if method == "rk4" or name == MODEL:
                label = name if method == "rk4" else f"{name} (Euler 2-step)"
                lines.append(f"{label:20} {100 * e.pos_err_5s_m:9.2f} {e.yaw_err_5s_deg:10.2f}")
    if ev.beats_lag is False:
        lines.append(f"the identified model does NOT beat the lag baseline ({100 * ev.model.pos_err_5s_m:.2f} cm "
                     f"against {100 * ev.results[LAG]['rk4'].pos_err_5s_m:.2f} cm): use the lag model")
    elif ev.beats_lag:
        lines.append(f"the identified model beats the lag baseline "
                     f"({ev.model.pos_err_5s_m / ev.results[LAG]['rk4'].pos_err_5s_m:.2f}x its error)")
    if ev.cv is not None:
        spread = (f"+- {100 * ev.cv.interval_m:.2f} ({100 * CV_PREDICTION_LEVEL:.0f} % prediction interval of "
                  f"{ev.cv.n_folds} folds)" if np.isfinite(ev.cv.interval_m) else "(one fold: no spread)")
        lines.append(f"cross-validation estimate ({ev.cv.kind or 'from the model file'}): "
                     f"{100 * ev.cv.cv_pos_err_5s_m:.2f} cm {spread}, test {100 * ev.cv.test_pos_err_5s_m:.2f} cm"
                     + ("  WARNING: the test score lies outside it" if ev.cv.disagree else ""))
    else:
        lines.append("cross-validation estimate: none in the model file")
    for name in (MODEL, LAG):
        if name in ev.results and ev.sensitivity:
            cells = ", ".join(f"s = {s:g}: {100 * v[name]:.2f} cm" for s, v in ev.sensitivity.items())
            lines.append(f"start-state smoothing sensitivity, {name}: {cells}")
    return "\n".join(lines)


def run(args) -> int:
    """Evaluate model, baselines and (simulated campaigns) the oracle; print and write JSON."""
    check_outputs(args)
    ev = evaluate_files(args.campaign, args.model, methods=("rk4", "euler2"), train=args.train)
    print(format_errors(ev))
    if args.plots:
        write_evaluation_figures(ev, args.plots)
    if args.json:
        atomic_write_json(args.json, ev.to_json())
    return 0
