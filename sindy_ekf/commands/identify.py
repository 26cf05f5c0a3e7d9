"""``sindy-ekf identify CAMPAIGN --out MODEL.json``: integral SINDy with the full hyperparameter search."""

from __future__ import annotations

import argparse
from pathlib import Path

from sindy_ekf.errors import InputError


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``identify`` subcommand; return its parser."""
    p = sub.add_parser("identify", parents=[common], help="identify a SINDy model on the train runs",
                       description=__doc__.splitlines()[0])
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign")
    p.add_argument("--out", type=Path, required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write a JSON summary")
    p.add_argument("--quick", action="store_true", help="a small grid (s=0.0005, 2 tau, 3 alpha, 3 T, 3 folds)")
    p.add_argument("--library", nargs="+", default=["poly3"], metavar="NAME",
                   help="candidate libraries to search (poly3, poly3_absu, poly3_signsq, ...)")
    p.add_argument("--jobs", type=int, default=1, help="worker processes for the grid")
    p.add_argument("--plots", type=Path, default=None, metavar="DIR",
                   help="write figs. 7.4-7.7, 7.10, 7.11, 7.12 as PNG into DIR")
    return p


def run(args) -> int:
    """Search, write the model and print its equations and the ranking; return the exit code."""
    import dataclasses

    from identification.campaigns import open_campaign
    from identification.search import QUICK_GRID, SearchGrid, search
    from sindy_ekf.io_utils import atomic_write_json

    campaign = open_campaign(args.campaign)
    train = campaign.split("train")
    if not train:
        raise InputError(f"{args.campaign}: campaign.yaml marks no run as train")
    grid = QUICK_GRID if args.quick else SearchGrid()
    grid = dataclasses.replace(grid, library=tuple(args.library))
    result = search(runs=train, grid=grid, n_jobs=args.jobs)
    model = result.model
    best = result.row(result.selected)
    model.training.update({"cv_pos_err_5s_m": best["pos_err_5s_m"], "cv_yaw_err_5s_deg": best["yaw_err_5s_deg"],
                           "grid_size": grid.size, "folds": result.folds, "campaign": str(args.campaign)})
    model.to_json(args.out)
    print(f"identified on {len(train)} train runs of {campaign.name}; grid of {grid.size} points, "
          f"{len(result.folds)}-fold CV by run")
    print(model.equations())
    print(f"\nselected: rank {result.selected + 1}, the sparsest within 5 % of the best CV error")
    print(f"{'rank':>4} {'s':>7} {'tau':>4} {'alpha':>5} {'T':>5} {'terms':>5} {'pos 5s cm':>9} {'yaw 5s deg':>10}")
    for i, r in enumerate(result.ranking(10), 1):
        print(f"{i:4d} {r['s']:7g} {r['tau']:4g} {r['alpha']:5g} {r['T']:5g} {r['complexity']:5.0f} "
              f"{100 * r['pos_err_5s_m']:9.2f} {r['yaw_err_5s_deg']:10.2f}")
    print(f"model written to {args.out}")
    if args.plots:
        _plots(result, args.plots, train, model)
    if args.json:
        atomic_write_json(args.json, {
            "model": str(args.out), "hyperparameters": model.hyperparameters, "library": model.library.name,
            "complexity": model.complexity, "equations": model.equations().splitlines(),
            "cv_pos_err_5s_m": best["pos_err_5s_m"], "cv_yaw_err_5s_deg": best["yaw_err_5s_deg"],
            "condition_number": model.training.get("condition_number"), "grid_size": grid.size,
            "selected_rank": result.selected + 1, "ranking": result.ranking(14),
        })
    return 0


def _plots(result, out_dir: Path, train, model) -> None:
    """Write the search figures (7.4-7.7, 7.10, 7.11) and the adjustment's correlations (7.12)."""
    import numpy as np

    from identification.adjust import adjust_coefficients, plot_correlation
    from identification.model import plot_term_prevalence
    from identification.search import plot_error_vs_complexity, plot_grid, states_of_runs
    from identification.sindy import integral_problem

    out_dir.mkdir(parents=True, exist_ok=True)
    for s in np.unique(result.table["s"]):
        plot_grid(result, float(s), path=out_dir / f"grid_s{s:g}.png")
    plot_error_vs_complexity(result, path=out_dir / "error_vs_complexity.png")
    plot_term_prevalence(result.top_models, path=out_dir / "term_prevalence.png")
    segs, names, _ = states_of_runs(train, model.hyperparameters["s"])
    problem = integral_problem(segs, model.library, model.hyperparameters["tau"], names)
    plot_correlation(adjust_coefficients(model, problem), path=out_dir / "correlation.png")
