"""``sindy-ekf preprocess CAMPAIGN --out DIR``: raw bags to synchronised poses and body states."""

from __future__ import annotations

import argparse
import os

import numpy as np

from groundfloor.files import atomic_write_json, check_outputs
from identification.preprocessing.preprocess import (
    DEFAULT_SMOOTHING,
    TIMING_ERROR_R,
    PreprocessResult,
    preprocess_campaign,
    reading_json,
)
from identification.preprocessing.sync import SyncedRun
from sindy_ekf.cli_workers import add_worker_arguments, workers_of
from sindy_ekf.report.bag_facts import bag_notes


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``preprocess`` arguments to its parser."""
    p.description = ("Preprocess a tracker campaign (data contract part 1) into a trajectory campaign: clock "
                     "sync, AT960 offset, hub model, poses, body-frame states (thesis 5.2).")
    p.add_argument("campaign", help="tracker campaign folder (campaign.yaml, calibration.yaml, runs/)")
    p.add_argument("--out", required=True, help="output folder (a trajectory campaign)")
    p.add_argument("--json", metavar="PATH", help="also write the key results as JSON")
    p.add_argument("--smoothing", type=float, default=None,
                   help="spline smoothing factor s of eq. 5.68 (default 0.0005)")
    p.add_argument("--plots", metavar="DIR", help="save the figures of each step there")
    p.add_argument("--force", action="store_true", help="replace a non-empty output folder")
    p.add_argument("--no-hub-correction", action="store_true",
                   help="do not refer the prisms to the hub axes (eq. 5.25 model) before the "
                        "poses, as the thesis did not")
    add_worker_arguments(p, min(2, os.cpu_count() or 1), "runs")


def format_summary(result: PreprocessResult) -> str:
    """Return the per-run summary table printed by the command."""
    head = (f"{'run':<10} {'split':<5} {'LTD800 ppm':>11} {'AT960 ppm':>10} {'offset ms':>10} "
            f"{'r before':>8} {'r after':>8} {'base rms mm':>12} {'poses':>6} "
            f"{'lost':>5} {'spur':>5} {'1-prism':>7} {'reord':>5} {'nan':>4}")
    lines = [head, "-" * len(head)]
    for name, r in result.runs.items():
        s = r.synced
        at, ltd = s.counts["at960"], s.counts["ltd800"]
        reordered = sum(r.facts.reordered.values()) if r.facts is not None else 0
        lines.append(
            f"{name:<10} {s.split:<5} {s.clock['ltd800'].drift_ppm:>11.4f} "
            f"{s.clock['at960'].drift_ppm:>10.4f} {s.offset.dt * 1e3:>10.4f} "
            f"{s.r_speed_before:>8.2f} {s.r_speed_after:>8.2f} "
            f"{s.baseline_rms_m('before') * 1e3:>5.3f}->{s.baseline_rms_m('after') * 1e3:<6.3f} "
            f"{r.poses.t.size:>6d} {at.lost + ltd.lost:>5d} {at.spurious + ltd.spurious:>5d} "
            f"{r.n_one_prism:>7d} {reordered:>5d} {at.dropped_nan + ltd.dropped_nan:>4d}")
    for name, why in result.skipped.items():
        lines.append(f"{name:<10} skipped: {why}")
    lines += bag_notes({name: reading_json(r) for name, r in result.runs.items()})
    lines += _timing_error_lines([r.synced for r in result.runs.values()])
    return "\n".join(lines)


def _timing_error_lines(synced: list[SyncedRun]) -> list[str]:
    """Return the summary's line on a timing error, or none when no run's baseline length follows its speed."""
    r0 = np.array([s.r_speed_before for s in synced])
    if not np.any(np.abs(r0) > TIMING_ERROR_R):
        return []
    late = max({s.offset_tracker for s in synced}, key=[s.offset_tracker for s in synced].count)
    dt = np.median([s.offset.dt for s in synced]) * 1e3
    return [f"timing error found: the baseline length follows the forward speed (median r "
            f"{np.median(r0):+.2f}); the {late.upper()} measures {dt:.3f} ms after the "
            f"trigger pulse (median over runs), corrected (median r after "
            f"{np.median([s.r_speed_after for s in synced]):+.2f})"]


def run(args) -> int:
    """Preprocess, print the summary table, write ``--json``; return the exit code."""
    check_outputs(args)
    smoothing = DEFAULT_SMOOTHING if args.smoothing is None else args.smoothing
    result = preprocess_campaign(args.campaign, args.out, smoothing=smoothing, force=args.force,
                                 plots_dir=args.plots, jobs=workers_of(args),
                                 hub_correction=not args.no_hub_correction)
    if not args.quiet:
        print(format_summary(result))
        t = result.seconds
        wall = t.get("calibrate", 0) + t.get("runs_wall", 0) + t.get("write", 0)
        stages = ", ".join(f"{k} {t[k]:.1f}" for k in ("read", "sync", "hub", "poses", "states",
                                                       "plots") if t.get(k))
        print(f"wrote {len(result.runs)} runs to {result.out_dir} in {wall:.1f} s "
              f"(summed over runs: {stages})")
    if args.json:
        atomic_write_json(args.json, result.to_json_dict())
    return 0
