"""``sindy-ekf identify CAMPAIGN --out MODEL.json``: integral SINDy with the full hyperparameter search."""

from __future__ import annotations

import argparse
from pathlib import Path

from groundfloor.errors import InputError


def add_parser(sub, common) -> argparse.ArgumentParser:
    """Register the ``identify`` subcommand; return its parser."""
    p = sub.add_parser("identify", parents=[common], help="identify a SINDy model on the train runs",
                       description=__doc__.splitlines()[0])
    p.add_argument("campaign", type=Path, help="trajectory or tracker campaign")
    p.add_argument("--out", type=Path, required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write a JSON summary")
    p.add_argument("--quick", action="store_true", help="a small grid (tracker: s=0.0005, 2 tau, 2 alpha, 3 T, "
                   "3 folds; low-rate: s=20, 2 tau, 2 T, poly1)")
    p.add_argument("--grid", choices=("auto", "tracker", "low-rate"), default="auto",
                   help="base grid: tracker (50 Hz laser-tracker poses), low-rate (10-20 Hz lidar, mocap or "
                        "RTK poses: larger spline smoothing, shorter windows, poly1/poly3/poly3_absu), or auto "
                        "(low-rate when the median pose interval exceeds 30 ms; default)")
    p.add_argument("--library", nargs="+", default=None, metavar="NAME",
                   help="candidate libraries to search (poly1, poly2, poly3, poly3_absu, poly3_signsq; default the "
                        "grid's: poly3 for tracker poses, poly1 poly3 poly3_absu for low-rate poses)")
    p.add_argument("--smoothing", nargs="+", type=float, default=None, metavar="S",
                   help="spline smoothing values s to search (default 0 0.0005 0.005 0.01 for 50 Hz tracker "
                        "poses; noisier or slower poses need larger s, e.g. 1 10 30 for 10 Hz lidar poses)")
    p.add_argument("--tau", nargs="+", type=float, default=None, metavar="SECONDS",
                   help="integration window lengths (default 0.2 0.5 1 2; keep several samples per window)")
    p.add_argument("--alpha", nargs="+", type=float, default=None, metavar="A",
                   help="ridge weights, dimensionless on unit-norm columns (default 0 1e-4 1e-3 1e-2)")
    p.add_argument("--threshold", nargs="+", type=float, default=None, metavar="T",
                   help="STLSQ thresholds: smallest share of an equation's signal a term must carry "
                        "(default 0 0.01 0.03 0.05 0.1 0.2)")
    p.add_argument("--jobs", type=int, default=1, help="worker processes for the grid")
    p.add_argument("--plots", type=Path, default=None, metavar="DIR",
                   help="write figs. 7.4-7.7, 7.10, 7.11, 7.12 as PNG into DIR")
    return p


def run(args) -> int:
    """Search, write the model and print its equations and the ranking; return the exit code."""
    import dataclasses

    from groundfloor.files import atomic_write_json
    from identification.preprocessing.campaigns import open_campaign
    from identification.sindy.library import make_library
    from identification.sindy.search import grid_for_runs, search

    check_output_file(args.out, "--out")
    if args.json:
        check_output_file(args.json, "--json")
    for name in args.library or ():
        make_library(name)  # an unknown library name fails now, not after the search
    changes = {"library": tuple(args.library)} if args.library else {}
    for opt, field in (("smoothing", "s"), ("tau", "tau"), ("alpha", "alpha"), ("threshold", "T")):
        values = getattr(args, opt)
        if values is not None:
            bad = [v for v in values if not (v >= 0 if opt != "tau" else v > 0)]
            if bad:
                raise InputError(f"--{opt}: {bad[0]:g} is not a valid value "
                                 f"({'positive' if opt == 'tau' else 'non-negative'} numbers expected)")
            changes[field] = tuple(sorted(set(values)))
    campaign = open_campaign(args.campaign)
    train = campaign.split("train")
    if not train:
        raise InputError(f"{args.campaign}: campaign.yaml marks no run as train")
    grid, why = grid_for_runs(train, quick=args.quick, kind=args.grid)
    grid = dataclasses.replace(grid, **changes)
    print(f"{why}; {grid.size} grid points")
    result = search(runs=train, grid=grid, n_jobs=args.jobs)
    model = result.model
    best = result.row(result.selected)
    model.training.update({"cv_pos_err_5s_m": best["pos_err_5s_m"], "cv_yaw_err_5s_deg": best["yaw_err_5s_deg"],
                           "grid_size": grid.size, "grid": why, "folds": result.folds,
                           "campaign": str(args.campaign)})
    model.to_json(args.out)
    print(f"identified on {len(train)} train runs of {campaign.name}; grid of {grid.size} points, "
          f"{len(result.folds)}-fold CV by run")
    print(model.equations())
    print(f"\nselected: rank {result.selected + 1}, the {model.training['selection']}")
    print(f"{'rank':>4} {'s':>7} {'tau':>4} {'alpha':>6} {'T':>5} {'terms':>5} {'pos 5s cm':>9} {'+-SE':>5} "
          f"{'yaw 5s deg':>10}  note")
    rows = list(range(min(10, len(result.table["s"]))))
    rows += [result.selected] if result.selected >= 10 else []
    for i in rows:
        r = result.row(i)
        note = "" if r["stable_at_rest"] else "unstable at rest"
        if r["diverged_frac"] > 0:
            note += ("; " if note else "") + f"diverged on {100 * r['diverged_frac']:.0f} % of windows"
        note += ("; " if note else "") + "selected" if i == result.selected else ""
        print(f"{i + 1:4d} {r['s']:7g} {r['tau']:4g} {r['alpha']:6g} {r['T']:5g} {r['complexity']:5.0f} "
              f"{100 * r['pos_err_5s_m']:9.2f} {100 * r['pos_err_5s_se_m']:5.2f} {r['yaw_err_5s_deg']:10.2f}  {note}")
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


def check_output_file(path: Path, option: str) -> Path:
    """Return ``path`` if a file can be written there, else raise InputError naming the culprit.

    Checked before any work: the path must not be a folder, its nearest existing ancestor must
    be a writable folder (not a regular file).
    """
    import os

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder, expected a file name")
    probe = path.parent if str(path.parent) else Path(".")
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{option} {path}: cannot be written, {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK):
        raise InputError(f"{option} {path}: folder {probe} is not writable")
    return path


def _plots(result, out_dir: Path, train, model) -> None:
    """Write the search figures (7.4-7.7, 7.10, 7.11) and the adjustment's correlations (7.12)."""
    import numpy as np

    from identification.sindy.adjust import adjust_coefficients
    from identification.sindy.figures import (
        plot_correlation,
        plot_error_vs_complexity,
        plot_grid,
        plot_term_prevalence,
    )
    from identification.sindy.regression import integral_problem
    from identification.sindy.data import states_of_runs

    out_dir.mkdir(parents=True, exist_ok=True)
    for s in np.unique(result.table["s"]):
        plot_grid(result, float(s), path=out_dir / f"grid_s{s:g}.png")
    plot_error_vs_complexity(result, path=out_dir / "error_vs_complexity.png")
    plot_term_prevalence(result.top_models, path=out_dir / "term_prevalence.png")
    segs, names, _ = states_of_runs(train, model.hyperparameters["s"])
    problem = integral_problem(segs, model.library, model.hyperparameters["tau"], names)
    plot_correlation(adjust_coefficients(model, problem), path=out_dir / "correlation.png")
