"""The compiled EKF step on data it was not designed on: a simulator variant and a real campaign.

For each campaign the SINDy EKF (``run_ekf_batch``, dgnss, the campaign's test runs in lockstep)
runs twice on identical inputs: with the identified model's compiled step and with the generic
numpy step of the dynamics interface (``Dynamics.rk4_step_and_jacobians``). Reports both
real-time factors (CPU, best of 2) and the largest difference of the estimates.

Usage: ``python -m bench.bench_ekf_speed_data [--default-campaign DIR --default-model MODEL.json]``.
The variant campaign is ``bench/_work/variants/variant_03`` (``python -m bench.bench_variants``
builds it) with a model from ``sindy-ekf identify --quick``; the real one is ``../shared/data/
warthog-drive-cmd`` with the model ``bench.bench_monte_carlo`` identified (low-rate grid).
Writes ``bench/results/ekf_speed_data.md``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.publish import publish
from groundfloor.dynamics import Dynamics
from identification.preprocessing.campaigns import open_campaign
from identification.sindy.model import SindyModel
from sindy_ekf.benchmark.run import P0_STD, _prepare_run, fit_models
from sindy_ekf.estimation.ekf import EkfRun, run_ekf_batch

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "bench" / "_work"


def measure(campaign_dir: Path, model_path: Path, smoothing: float) -> tuple[str, float, float, float]:
    """Return the model's description, the compiled and numpy real-time factors and the largest difference."""
    model = SindyModel.load(model_path)
    campaign = open_campaign(campaign_dir)
    ekf = fit_models(campaign.split("train"), model, None, smoothing)["sindy_ekf"]
    runs = [_prepare_run(r, "dgnss", i, None, smoothing, 30.0, 30.0) for i, r in enumerate(campaign.split("test"))]
    ekf_runs = [EkfRun(r.name, r.grid, r.u, r.x0, np.diag(P0_STD ** 2), r.gnss) for r in runs]
    data_s = sum(r.t_pose[-1] - r.t_pose[0] for r in runs)
    compiled, out = SindyModel.rk4_step_and_jacobians, {}
    try:
        for name, step in (("compiled", compiled), ("numpy", Dynamics.rk4_step_and_jacobians)):
            SindyModel.rk4_step_and_jacobians = step
            best = np.inf
            for _ in range(2):
                start = time.process_time()
                res = run_ekf_batch(ekf, ekf_runs)
                best = min(best, time.process_time() - start)
            out[name] = (data_s / best, res)
    finally:
        SindyModel.rk4_step_and_jacobians = compiled
    diff = max(float(np.max(np.abs(a.x - b.x))) for a, b in zip(out["compiled"][1], out["numpy"][1]))
    what = f"{model.library.name}, {model.complexity} terms; {len(runs)} test runs, {data_s:.0f} s"
    return what, out["compiled"][0], out["numpy"][0], diff


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--default-campaign", type=Path, default=WORK / "ekf_speed" / "traj")
    ap.add_argument("--default-model", type=Path, default=WORK / "ekf_speed" / "model.json")
    args = ap.parse_args()
    variant = WORK / "variants" / "variant_03" / "trajectory"
    variant_model = WORK / "variants" / "variant_03" / "model_quick.json"
    if not variant_model.is_file():
        subprocess.run([str(Path(sys.executable).parent / "sindy-ekf"), "identify", str(variant), "--out",
                        str(variant_model), "--quick", "--quiet"], check=True)
    cases = [("simulator variant 3 (its own structure, motor lag, lateral law)", variant, variant_model, 0.0005),
             ("real Warthog, warthog-drive-cmd (held-out test run)", ROOT.parent / "shared" / "data" /
              "warthog-drive-cmd", WORK / "monte_carlo" / "warthog-drive-cmd.json", 20.0),
             ("default simulated campaign, full-grid model", args.default_campaign, args.default_model, 0.0005)]
    lines = ["## EKF speed on other data (the compiled step against the numpy step)", "",
             f"Command: `python -m bench.bench_ekf_speed_data {' '.join(sys.argv[1:])}`; load average "
             f"{' '.join(Path('/proc/loadavg').read_text().split()[:3])} (2 cores). SINDy EKF over each campaign's "
             "test runs in lockstep, dgnss; real-time factor = data seconds / CPU seconds, best of 2.", "",
             "| campaign | model; data | compiled | numpy step | largest difference of the estimates |",
             "|---|---|---|---|---|"]
    for label, camp, model, s in cases:
        what, fast, slow, diff = measure(camp, model, s)
        lines.append(f"| {label} | {what} | {fast:.0f}x | {slow:.0f}x | {diff:.1e} |")
    publish(ROOT / "bench" / "results" / "ekf_speed_data.md", lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
