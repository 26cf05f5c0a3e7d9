"""Estimation speed and accuracy on the default simulated campaign (issue 5).

Measures (wall time on this machine, numbers written to ``bench/results/estimation.md``):

1. the SINDy EKF over the whole default campaign (all nine runs, 45 min of driving) at 50 Hz
   with ``dgnss`` fixes (target: at most 60 s on 2 cores);
2. batch factor-graph smoothing of one 7-minute run (target: at most 60 s) and fixed-lag iSAM2
   on the same run (target: faster than real time);
3. the benchmark of every estimator on the test runs with ``dgnss``: ATE, error at the end of
   5, 10, 30 and 60 s outages, and the acceptance ratios of the issue.

Usage::

    python -m bench.bench_estimation [--campaign DIR] [--model MODEL.json] [--gnss dgnss]

Without ``--campaign`` the default campaign is simulated (``sindy-ekf simulate DIR --seed 0``)
and identified (``sindy-ekf identify DIR --out MODEL.json --quick``) into a cache folder.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.publish import publish

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=None)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--gnss", default="dgnss")
    ap.add_argument("--cache", type=Path, default=ROOT / "bench" / ".cache" / "estimation")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "estimation.md")
    ap.add_argument("--skip-isam2", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    exe = str(Path(sys.executable).parent / "sindy-ekf")
    campaign_dir = args.campaign or args.cache / "campaign"
    if not (campaign_dir / "campaign.yaml").is_file():
        subprocess.run([exe, "simulate", str(campaign_dir), "--seed", "0", "--quiet"], check=True)
    model_path = args.model or args.cache / "model.json"
    if not model_path.is_file():
        subprocess.run([exe, "identify", str(campaign_dir), "--out", str(model_path), "--quick",
                        "--quiet"], check=True)

    from identification.preprocessing.campaigns import open_campaign
    from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
    from identification.sindy.model import SindyModel
    from simulation.truth import true_dynamics_of
    from sindy_ekf.benchmark.run import (
        P0_STD,
        _prepare_run,
        benchmark_campaign,
        fit_models,
    )
    from sindy_ekf.estimation.ekf import EkfRun, run_ekf_batch
    from sindy_ekf.estimation.graph import smooth_batch, smooth_isam2

    model = SindyModel.load(model_path)
    campaign = open_campaign(campaign_dir)
    oracle = true_dynamics_of(campaign_dir)
    lines = [f"# Estimation benchmark ({args.gnss})", "",
             f"Campaign `{campaign_dir}` ({len(campaign.runs)} runs), model `{model_path}`.",
             f"Command: `python -m bench.bench_estimation {' '.join(sys.argv[1:])}`", ""]

    # 1. the EKF over the whole campaign
    models = fit_models(campaign.split("train"), model, oracle, DEFAULT_SMOOTHING)
    runs = [_prepare_run(r, args.gnss, i, oracle, DEFAULT_SMOOTHING, 30.0, 30.0)
            for i, r in enumerate(campaign.runs)]
    P0 = np.diag(P0_STD ** 2)
    n_steps = sum(len(r.grid) for r in runs)
    duration = sum(r.t_pose[-1] - r.t_pose[0] for r in runs)
    start = time.perf_counter()
    run_ekf_batch(models["sindy_ekf"], [EkfRun(r.name, r.grid, r.u, r.x0, P0, r.gnss) for r in runs])
    t_ekf = time.perf_counter() - start
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else []
    lines += ["## Speed", "", f"Load average when measured: {' '.join(load)} (2 cores, shared).", "",
              "| what | data | steps | wall time s | real-time factor | target |", "|---|---|---|---|---|---|",
              f"| sindy_ekf, whole campaign, {len(runs)} runs in lockstep | {duration:.0f} s | {n_steps} | "
              f"{t_ekf:.1f} | {duration / t_ekf:.0f} | <= 60 s |"]

    # 2. graph smoothing and iSAM2 on the 7-minute run closest to 420 s
    long_run = min(runs, key=lambda r: abs((r.t_pose[-1] - r.t_pose[0]) - 420.0))
    d_long = long_run.t_pose[-1] - long_run.t_pose[0]
    start = time.perf_counter()
    ekf_long = run_ekf_batch(models["sindy_ekf"], [EkfRun(long_run.name, long_run.grid, long_run.u,
                                                          long_run.x0, P0, long_run.gnss)])[0]
    t_init = time.perf_counter() - start
    g = smooth_batch(models["sindy_ekf"], long_run.grid, long_run.u, long_run.x0, P0, long_run.gnss,
                     x_init=ekf_long.x, marginal_stride=None)
    lines.append(f"| sindy_graph batch LM from the EKF estimate, {long_run.name} | {d_long:.0f} s | "
                 f"{len(long_run.grid)} | {g.runtime_s:.1f} ({g.iterations} iterations; + {t_init:.1f} "
                 f"for the EKF that starts it) | {d_long / g.runtime_s:.0f} | <= 60 s |")
    if not args.skip_isam2:
        i2 = smooth_isam2(models["sindy_ekf"], long_run.grid, long_run.u, long_run.x0, P0, long_run.gnss)
        lines.append(f"| sindy_isam2 fixed-lag (3 s), {long_run.name} | {d_long:.0f} s | {len(long_run.grid)} | "
                     f"{i2.runtime_s:.1f} | {d_long / i2.runtime_s:.1f} | > 1 |")

    # 3. the benchmark on the test runs
    names = ("dead_reckoning", "cv_ekf", "unicycle_ekf", "sindy_ekf", "sindy_ekf_lateral", "oracle_ekf",
             "sindy_graph", "sindy_graph_lateral") + \
        (() if args.skip_isam2 else ("sindy_isam2",))
    if oracle is None:
        names = tuple(n for n in names if n != "oracle_ekf")
    res = benchmark_campaign(campaign, model, args.gnss, seed=0, oracle_dynamics=oracle, estimators=names)
    durs = sorted({k for s in res.scores.values() for k in s.outage_pos_err_m}, key=float)
    n_out = {d: sum(int(np.sum(np.isclose(np.diff(o, axis=1).ravel(), float(d)))) for o in res.outages.values())
             for d in durs}
    lines += ["", f"## Accuracy on the test runs ({', '.join(res.truth)}), GNSS {args.gnss}, alignment "
              f"{res.alignment}", "",
              "RMS position error [m] at the end of outages (number of outages: "
              + ", ".join(f"{d} s: {n_out[d]}" for d in durs) + "), ATE, NEES (pose, 3 dof, 95 % "
              f"per-sample bounds {res.nees_bounds_95[0]:.2f}-{res.nees_bounds_95[1]:.2f}), NIS (2 dof).", "",
              "| estimator | ATE m | ATE deg | " + " | ".join(f"{d} s outage m" for d in durs)
              + " | mean NEES | NEES in 95 % | mean NIS | runtime s |",
              "|---" * (7 + len(durs)) + "|"]
    for name, s in res.scores.items():
        lines.append(f"| {name} | {s.ate_pos_m:.3f} | {s.ate_yaw_deg:.2f} | "
                     + " | ".join(f"{s.outage_pos_err_m.get(d, float('nan')):.3f}" for d in durs)
                     + f" | {s.nees_mean:.2f} | {s.nees_inside_95:.2f} | {s.nis_mean:.2f} | {s.runtime_s:.1f} |")
    sc = res.scores
    lines += ["", "## Acceptance (issue 5)", ""]
    if "10" in sc["sindy_ekf"].outage_pos_err_m:
        e10 = {n: s.outage_pos_err_m["10"] for n, s in sc.items()}
        lines.append(f"- sindy_ekf / unicycle_ekf at the end of 10 s outages: "
                     f"{e10['sindy_ekf'] / e10['unicycle_ekf']:.2f} (target <= 0.5)")
        if "oracle_ekf" in e10:
            lines.append(f"- sindy_ekf / oracle_ekf at the end of 10 s outages: "
                         f"{e10['sindy_ekf'] / e10['oracle_ekf']:.2f} (target <= 1.3)")
    lines.append(f"- sindy_graph ATE / sindy_ekf ATE: {sc['sindy_graph'].ate_pos_m / sc['sindy_ekf'].ate_pos_m:.2f} "
                 "(target <= 1)")
    if oracle is not None and "10" in sc["sindy_ekf"].outage_pos_err_m:
        # reference: the simulator's own polynomial terms as the "identified" model, to separate
        # what the estimator does from what the identification got right
        from identification.sindy.model import model_from_terms
        from simulation.robot import RobotParams

        ref = benchmark_campaign(campaign, model_from_terms(RobotParams().terms()), args.gnss, seed=0,
                                 estimators=("sindy_ekf",))
        r10 = ref.scores["sindy_ekf"].outage_pos_err_m["10"]
        lines.append(f"- reference, sindy_ekf with the simulator's true polynomial terms: 10 s outage "
                     f"error {r10:.3f} m, {r10 / sc['oracle_ekf'].outage_pos_err_m['10']:.2f} x oracle_ekf, "
                     f"ATE {ref.scores['sindy_ekf'].ate_pos_m:.3f} m")
    publish(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
