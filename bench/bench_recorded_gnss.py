"""Recorded GNSS against the internal GNSS simulation (issue 16, items 1-2): do the filters score alike?

Usage: ``python -m bench.bench_recorded_gnss [--minutes M] [--seeds N] [--out DIR] [--no-write]``
from the checkout; writes ``bench/results/recorded_gnss.md``. One campaign (seed 5, ``M``
minutes, default 20) is simulated with recorded dgnss fixes (``simulate_campaign(gnss="dgnss")``:
a ``sensor_msgs/NavSatFix`` bag per run around a geodetic origin) and preprocessed (which writes
``gnss.csv`` per run); kept in ``DIR`` (default ``bench/_work/recorded_gnss``, gitignored) and
reused. The benchmark then runs on the test runs:

- ``--gnss recorded`` on the campaign as simulated: its own fixes (bag -> ``gnss.csv`` ->
  WGS84 -> ENU with pymap3d -> local through the transform estimated from the ground truth over
  the first 60 s of each run);
- paired, for seeds ``k = 0 .. N-1`` (default 5): ``--gnss dgnss`` (fixes simulated inside the
  benchmark, run ``i`` with seed ``k + i``) against ``--gnss recorded`` on a copy of the campaign
  whose ``gnss.csv`` hold the fixes the simulator records with the same seeds
  (:func:`simulation.gnss_topic.record_fixes` on the true states, NO_FIX and NaN fixes included).
  Same seed, same noise draws: the paired difference is what the recorded path (geodetic round
  trip, estimated transform, dropped fixes) adds, to be set against the spread over seeds (what
  GNSS noise alone does).

The process model is the simulator's own (``model_from_terms(RobotParams().terms())``, a
perfectly identified SINDy model), so that what differs is the GNSS source and nothing else.
"Within noise": the mean paired difference is below the spread over seeds (its std).
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import time
from pathlib import Path

import numpy as np
import yaml

from groundfloor.files import atomic_write_text
from identification.preprocessing.io_sensors import GNSS_CSV, GnssFixes, write_gnss_csv
from identification.preprocessing.preprocess import REPORT_FILE, preprocess_campaign
from identification.preprocessing.trajectory import read_trajectory_campaign
from identification.sindy.model import model_from_terms
from simulation.campaign import simulate_campaign
from simulation.gnss_topic import GnssTopicSpec, record_fixes
from simulation.robot import RobotParams
from simulation.truth import read_truth
from sindy_ekf.benchmark.gnss_source import load_recorded_gnss
from sindy_ekf.benchmark.run import benchmark_campaign

HERE = Path(__file__).resolve().parent
ESTIMATORS = ("cv_ekf", "unicycle_ekf", "sindy_ekf", "sindy_ekf_lateral")
SEED = 5


def _campaign(out: Path, minutes: float) -> Path:
    """Return the trajectory campaign (simulated and preprocessed unless already there)."""
    tracker, traj = out / "campaign", out / "trajectory"
    if not (tracker / "truth" / "gnss.yaml").is_file():
        simulate_campaign(tracker, seed=SEED, minutes=minutes, gnss="dgnss", force=True)
    if not (traj / "runs").is_dir():
        preprocess_campaign(tracker, traj, force=True)
    return traj


def _reseeded(traj: Path, tracker: Path, out: Path, seed: int) -> Path:
    """Return a copy of ``traj`` whose ``gnss.csv`` hold the fixes recorded with seeds ``seed + i``.

    Test run ``i`` gets seed ``seed + i``, as the benchmark's internal simulation gives it.
    """
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(traj, out)
    truth = read_truth(tracker)
    runs = {r.name: r for r in read_trajectory_campaign(traj).runs}
    test = [n for n, r in runs.items() if r.split == "test"]
    spec = GnssTopicSpec("dgnss")
    for j, r in enumerate(truth.runs):
        st = r.states
        t_pose = np.asarray(runs[r.name].poses.t)  # the span the internal simulation samples: same draws
        p = runs[r.name].poses
        t_pose = t_pose[np.isfinite(t_pose) & np.isfinite(p.x) & np.isfinite(p.y) & np.isfinite(p.yaw)]
        sel = (st.t_utc_ns * 1e-9 >= t_pose[0] - 1e-6) & (st.t_utc_ns * 1e-9 <= t_pose[-1] + 1e-6)
        k = seed + test.index(r.name) if r.name in test else 1000 + seed * 10 + j
        f = record_fixes(st.t_utc_ns[sel], st.x[sel], st.y[sel], st.z[sel], st.psi[sel], spec, seed=k)
        write_gnss_csv(out / "runs" / r.name / GNSS_CSV, GnssFixes(
            f.t_valid_ns * 1e-9, f.t_arrival_ns * 1e-9, f.lla, f.cov_enu.reshape(-1, 3, 3), f.status))
    return out


def _scores(result) -> dict[str, dict[str, float]]:
    out = {}
    for name, s in result.scores.items():
        row = {"ATE m": s.ate_pos_m}
        row.update({f"out {d} s m": v for d, v in s.outage_pos_err_m.items()})
        out[name] = row
    return out


def main(argv=None) -> int:
    """Run the comparison, print it and write ``bench/results/recorded_gnss.md``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=20.0)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, default=HERE / "_work" / "recorded_gnss")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    tic = time.perf_counter()
    traj = _campaign(args.out, args.minutes)
    campaign = read_trajectory_campaign(traj)
    truth = yaml.safe_load((args.out / "campaign" / "truth" / "gnss.yaml").read_text())
    recorded = load_recorded_gnss(campaign)
    model = model_from_terms(RobotParams().terms())
    own = _scores(benchmark_campaign(campaign, model, "recorded", estimators=ESTIMATORS))
    sim, rec = [], []
    for k in range(args.seeds):
        sim.append(_scores(benchmark_campaign(campaign, model, "dgnss", seed=k, estimators=ESTIMATORS)))
        copy = read_trajectory_campaign(_reseeded(traj, args.out / "campaign", args.out / "reseeded", k))
        rec.append(_scores(benchmark_campaign(copy, model, "recorded", estimators=ESTIMATORS)))
    seconds = time.perf_counter() - tic

    tr = recorded.transform.to_json_dict()
    lines = ["# Recorded GNSS against the internal simulation (issue 16, items 1-2)", "",
             f"Command: `python -m bench.bench_recorded_gnss --minutes {args.minutes:g} --seeds {args.seeds}` "
             f"({seconds:.0f} s, 2 cores shared with other work).", "",
             f"Campaign: `simulate_campaign(seed={SEED}, minutes={args.minutes:g}, gnss=\"dgnss\")`, "
             f"preprocessed; test runs {', '.join(r.name for r in campaign.split('test'))}. Process model: "
             "the simulator's own terms (a perfect SINDy model), so only the GNSS source differs. "
             "Estimators as `benchmark --gnss dgnss` and `--gnss recorded` run them (default outage "
             "schedule: 5, 10, 30, 60 s after 30 s of GNSS; the score of a length is the error at the "
             "end of its outages).", "",
             "## ENU -> local transform estimated from the ground truth (first 60 s of every run)", "",
             "| | estimate | std | truth | error / std |", "|---|---|---|---|---|",
             f"| yaw deg | {tr['enu_to_local_yaw_deg']:.3f} | {tr['yaw_std_deg']:.3f} | "
             f"{truth['enu_to_local_yaw_deg']:.3f} | "
             f"{(tr['enu_to_local_yaw_deg'] - truth['enu_to_local_yaw_deg']) / tr['yaw_std_deg']:+.2f} |"]
    for i, axis in enumerate("xy"):
        est, sd, true = tr["enu_to_local_t_m"][i], tr["t_std_m"][i], truth["enu_to_local_t_m"][i]
        lines.append(f"| t_{axis} m | {est:.3f} | {sd:.3f} | {true:.3f} | {(est - true) / sd:+.2f} |")
    report = json.loads((traj / REPORT_FILE).read_text())["sensors"]["gnss"]
    dropped = {k: sum(c[k] for c in report.values()) for k in ("fixes", "no_fix_dropped", "nan_dropped")}
    spoilt = {k: sum(r[k] for r in truth["runs"].values()) for k in ("n_fixes", "n_no_fix", "n_nan")}
    lines += ["", f"{tr['n_fixes']} fixes used, {tr['n_rejected']} rejected as outliers, sigma0 "
              f"{tr['sigma0']:.2f}. Preprocessing read {dropped['fixes']} fixes from the bags (simulated "
              f"{spoilt['n_fixes']}): NO_FIX dropped {dropped['no_fix_dropped']} (simulated {spoilt['n_no_fix']}), "
              f"NaN dropped {dropped['nan_dropped']} (simulated {spoilt['n_nan']}).", "",
              f"## Scores (m): internal simulation against recorded fixes, {args.seeds} paired seeds", "",
              "`own`: the campaign's own recorded fixes (read from its bags). `internal`: mean and std "
              "over seeds of `--gnss dgnss`. `paired diff`: mean and std over seeds of recorded minus "
              "internal with the same seeds. Within noise: |mean paired diff| < internal std.", "",
              "| estimator | score | own | internal mean | internal std | recorded mean | paired diff | "
              "within noise |", "|---|---|---|---|---|---|---|---|"]
    n_ok = n_all = 0
    for name in ESTIMATORS:
        for key in own[name]:
            a = np.array([x[name].get(key, np.nan) for x in sim])
            b = np.array([x[name].get(key, np.nan) for x in rec])
            d = b - a
            ok = abs(np.nanmean(d)) < np.nanstd(a, ddof=1)
            n_all += 1
            n_ok += bool(ok)
            lines.append(f"| {name} | {key} | {own[name][key]:.3f} | {np.nanmean(a):.3f} | "
                         f"{np.nanstd(a, ddof=1):.3f} | {np.nanmean(b):.3f} | {np.nanmean(d):+.3f} +- "
                         f"{np.nanstd(d, ddof=1):.3f} | {'yes' if ok else 'no'} |")
    lines += ["", f"{n_ok} of {n_all} scores within noise."]
    text = "\n".join(lines) + "\n"
    print(text)
    if not args.no_write:
        atomic_write_text(HERE / "results" / "recorded_gnss.md", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
