"""EKF speed through the one dynamics interface: real-time factor on the whole default campaign.

Measures the wall time of the SINDy EKF (``sindy_ekf.estimation.ekf.run_ekf_batch``, all runs in
lockstep, 50 Hz grid, ``dgnss`` fixes) over every run of the default simulated campaign (45.4 min)
with a model identified on the full default grid, and reports the real-time factor
``data seconds / EKF wall seconds`` (target of issue 12: at least 500). The same measurement runs
side by side on a baseline revision of the tree (default: the commit before the dynamics
interface), exported with ``git archive`` into a temporary folder and imported in a child
process, so that old and new code see the same data and model; the largest difference of their
estimates is reported too (the refactoring must not change them).

Usage::

    python -m bench.bench_ekf_speed [--campaign DIR] [--model MODEL.json] [--baseline REV] [--repeat N]

Without ``--campaign`` the default campaign is simulated (``sindy-ekf simulate DIR --seed 0``),
preprocessed (``sindy-ekf preprocess DIR --out TRAJ``) and identified on the full grid
(``sindy-ekf identify TRAJ --out MODEL.json --jobs 2``) into ``bench/_work/ekf_speed``.
Writes ``bench/results/ekf_speed.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

BASELINE = "6c1b82f"  # the last commit before the one dynamics interface (issue 12)


def measure(tree: Path, campaign_dir: Path, model_path: Path, repeat: int, npz: Path | None) -> dict:
    """Return the EKF timings of the code in ``tree`` (first on the child's ``PYTHONPATH``).

    The imports are local on purpose: they must resolve in whichever tree the child was
    started on, the current one or the baseline revision.
    """
    from identification.preprocessing.campaigns import open_campaign
    from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
    from identification.sindy.model import SindyModel
    from sindy_ekf.benchmark.run import P0_STD, _prepare_run, fit_models
    from sindy_ekf.estimation.ekf import EkfRun, run_ekf_batch

    model = SindyModel.load(model_path)
    campaign = open_campaign(campaign_dir)
    models = fit_models(campaign.split("train"), model, None, DEFAULT_SMOOTHING)
    runs = [_prepare_run(r, "dgnss", i, None, DEFAULT_SMOOTHING, 30.0, 30.0) for i, r in enumerate(campaign.runs)]
    P0 = np.diag(P0_STD ** 2)
    ekf_runs = [EkfRun(r.name, r.grid, r.u, r.x0, P0, r.gnss) for r in runs]
    out = {"tree": str(tree), "n_runs": len(runs), "steps": int(sum(len(r.grid) for r in runs)),
           "data_s": float(sum(r.t_pose[-1] - r.t_pose[0] for r in runs)),
           "complexity": model.complexity, "wall_s": {}, "cpu_s": {}}
    for name in ("sindy_ekf", "cv_ekf", "unicycle_ekf"):
        walls, cpus = [], []
        for _ in range(repeat if name == "sindy_ekf" else 1):
            start, start_cpu = time.perf_counter(), time.process_time()
            res = run_ekf_batch(models[name], ekf_runs)
            walls.append(time.perf_counter() - start)
            cpus.append(time.process_time() - start_cpu)
        out["wall_s"][name], out["cpu_s"][name] = walls, cpus
        if npz is not None and name == "sindy_ekf":
            np.savez(npz, **{r.name: r.x for r in res})
    return out


def export_tree(rev: str, dest: Path) -> Path:
    """Return ``dest`` holding the tree of git revision ``rev`` (``git archive``)."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=None, help="trajectory (or tracker) campaign")
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--baseline", default=BASELINE, help="git revision to compare with ('' for none)")
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions of the SINDy EKF (best is kept)")
    ap.add_argument("--cache", type=Path, default=ROOT / "bench" / "_work" / "ekf_speed")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "ekf_speed.md")
    ap.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)  # child process
    ap.add_argument("--tree", type=Path, default=ROOT, help=argparse.SUPPRESS)
    ap.add_argument("--npz", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        print(json.dumps(measure(args.tree, args.campaign, args.model, args.repeat, args.npz)))
        return 0

    exe = str(Path(sys.executable).parent / "sindy-ekf")
    args.cache.mkdir(parents=True, exist_ok=True)
    campaign_dir = args.campaign
    if campaign_dir is None:
        campaign_dir = args.cache / "traj"
        if not (campaign_dir / "campaign.yaml").is_file():
            raw = args.cache / "campaign"
            if not (raw / "campaign.yaml").is_file():
                subprocess.run([exe, "simulate", str(raw), "--seed", "0", "--quiet"], check=True)
            subprocess.run([exe, "preprocess", str(raw), "--out", str(campaign_dir), "--quiet"], check=True)
    model_path = args.model or args.cache / "model.json"
    if not model_path.is_file():
        subprocess.run([exe, "identify", str(campaign_dir), "--out", str(model_path), "--jobs", "2", "--quiet"],
                       check=True)

    def child(tree: Path, npz: Path) -> dict:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--measure", "--tree", str(tree), "--campaign",
               str(campaign_dir.resolve()), "--model", str(model_path.resolve()), "--repeat", str(args.repeat),
               "--npz", str(npz)]
        # the tree's own packages first: ahead of the editable install, which points at the checkout
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tree), os.environ.get("PYTHONPATH")]))}
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=tree, env=env)
        if done.returncode:
            sys.exit(f"measuring {tree} failed:\n{done.stderr}")
        return json.loads(done.stdout.strip().splitlines()[-1])  # the JSON is the last line

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = {"new": child(ROOT, tmp / "new.npz")}
        if args.baseline:
            (tmp / "old").mkdir()
            results["old"] = child(export_tree(args.baseline, tmp / "old"), tmp / "old.npz")
            new, old = np.load(tmp / "new.npz"), np.load(tmp / "old.npz")
            max_diff = max(float(np.max(np.abs(new[k] - old[k]))) for k in new.files)
    new = results["new"]
    load = Path("/proc/loadavg").read_text().split()[:3] if Path("/proc/loadavg").exists() else []
    lines = ["# EKF speed through the dynamics interface", "",
             f"Campaign `{campaign_dir}` ({new['n_runs']} runs, {new['data_s']:.0f} s of data, {new['steps']} "
             f"grid steps in all), model `{model_path}` ({new['complexity']} active terms).",
             f"Command: `python -m bench.bench_ekf_speed {' '.join(sys.argv[1:])}`", "",
             f"Load average when measured: {' '.join(load)} (2 cores, shared). All runs in lockstep "
             f"(`run_ekf_batch`), dgnss fixes; best of {args.repeat} for sindy_ekf.", "",
             "The real-time factor is data seconds over the EKF's time: wall time (what a user waits, inflated "
             "when other jobs share the cores) and the process's own CPU time (what the code costs on one "
             "core, nearly independent of the load; the EKF is single-threaded).", "",
             "| code | EKF | wall time s | real-time factor (wall) | CPU time s | real-time factor (CPU) | target |",
             "|---|---|---|---|---|---|---|"]
    for label, r in results.items():
        tree = "this tree" if label == "new" else f"baseline `{args.baseline}`"
        for name, walls in r["wall_s"].items():
            best, best_cpu = min(walls), min(r["cpu_s"][name])
            target = ">= 500" if name == "sindy_ekf" else ""
            lines.append(f"| {tree} | {name} | {best:.2f} | {r['data_s'] / best:.0f} | {best_cpu:.2f} | "
                         f"{r['data_s'] / best_cpu:.0f} | {target} |")
    if "old" in results:
        speed_up = min(results["old"]["wall_s"]["sindy_ekf"]) / min(new["wall_s"]["sindy_ekf"])
        speed_up_cpu = min(results["old"]["cpu_s"]["sindy_ekf"]) / min(new["cpu_s"]["sindy_ekf"])
        lines += ["", f"- sindy_ekf speed-up over the baseline: {speed_up:.1f} x (wall), {speed_up_cpu:.1f} x (CPU).",
                  f"- largest difference of the sindy_ekf estimates, this tree against the baseline: {max_diff:.2e} "
                  "(state units)."]
    # imported here, not at the top: the --measure child runs this file on the baseline tree's packages
    from bench.publish import publish

    publish(args.out, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
