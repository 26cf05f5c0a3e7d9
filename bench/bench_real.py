"""The chain on the real Warthog campaigns: baselines, full search, cross-campaign, diagnosis.

Usage: ``.venv/bin/python bench/bench_real.py [--quick] [--jobs N] [--no-diagnose]
[--out bench/results/real.md]``. Writes ``bench/results/real.md`` (assembled into
bench/RESULTS.md by ``bench/run_all.py``) with, per campaign of ``../shared/data``:

- the README's baselines reproduced with the package's evaluation (centred differences);
- the model identified on the train runs by the full search (``REAL_GRID`` of
  ``examples/real_warthog.py``), its 5 s position and heading errors on the test runs beside
  the unicycle and constant-velocity baselines on the same windows, and the search's time;
- each campaign's model scored on the other campaign's test runs (envelope warnings listed);
- the diagnosis (``sindy_ekf.diagnose``) of the identified model, with its gain, and an
  independent check of the delay family: the unicycle with an input delay chosen on the
  train runs;
- the estimator benchmark (``sindy_ekf.benchmark``) when that module exists.
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from identification.baselines import ConstantVelocityModel, UnicycleModel  # noqa: E402
from identification.evaluate import evaluate_model  # noqa: E402
from identification.search import states_of_runs  # noqa: E402
from identification.trajectory import read_trajectory_campaign  # noqa: E402


def _example():
    spec = importlib.util.spec_from_file_location("real_warthog", ROOT / "examples" / "real_warthog.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["real_warthog"] = module
    spec.loader.exec_module(module)
    return module


def delayed(states, delay_s: float):
    """Return ``states`` with inputs delayed by ``delay_s`` (the input the robot acted on)."""
    return [replace(st, u1=np.interp(st.t - delay_s, st.t, st.u1), u2=np.interp(st.t - delay_s, st.t, st.u2))
            for st in states]


def delay_from_train(train, delays=np.arange(0.0, 1.01, 0.05)) -> float:
    """Return the input delay (s) whose unicycle fit leaves the smallest velocity residual on ``train``."""
    sse = []
    for d in delays:
        st = delayed(train, d)
        uni = UnicycleModel().fit(st)
        v = uni.velocities(np.zeros((1, 3)), np.vstack([s.inputs for s in st]))
        x = np.vstack([s.state for s in st])
        sse.append(np.sum((x[:, 0] - v[:, 0]) ** 2) / np.var(x[:, 0]) + np.sum((x[:, 2] - v[:, 2]) ** 2) / np.var(x[:, 2]))
    return float(delays[int(np.argmin(sse))])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small fixed grid (as the tests)")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--no-diagnose", action="store_true")
    parser.add_argument("--out", type=Path, default=HERE / "results" / "real.md")
    args = parser.parse_args()
    ex = _example()
    grid = ex.QUICK_REAL_GRID if args.quick else ex.REAL_GRID
    cmd = "bench/bench_real.py" + (" --quick" if args.quick else "") + (f" --jobs {args.jobs}" if args.jobs > 1 else "")
    md = ["## Real data: Clearpath Warthog on grass (issue 6)", "",
          f"Command: `.venv/bin/python {cmd}` ({platform.python_version()}, load average "
          f"{', '.join(f'{x:.1f}' for x in __import__('os').getloadavg())} at start). Data: `../shared/data` "
          "(norlab-ulaval DRIVE, BSD-3-Clause; lidar-ICP poses at about 10 Hz, stamps up to 50 ms late).", ""]

    # 1. the README's baselines with the package's evaluation --------------------------------
    md += ["### Baselines of the data README, reproduced", "",
           "Unicycle gains fitted on the train runs, constant velocity from the data's initial velocity; "
           "body velocities by centred differences over +-2 poses (`states_by_differences`); "
           "`identification.evaluate`, 5 s windows, 50 % overlap, RMS at 5 s.", "",
           "| campaign | model | pos 5 s [m] | yaw 5 s [deg] | windows | README |", "|---|---|---|---|---|---|"]
    campaigns = {n: read_trajectory_campaign(ex.DATA / n) for n in ex.CAMPAIGNS}
    for name, camp in campaigns.items():
        tr = [ex.states_by_differences(r) for r in camp.split("train")]
        te = [ex.states_by_differences(r) for r in camp.split("test")]
        for label, model in (("unicycle", UnicycleModel().fit(tr)), ("constant_velocity", ConstantVelocityModel())):
            r = evaluate_model(model, te)
            ref = ex.README_BASELINES[name][label]
            md.append(f"| {name} | {label} | {r.pos_err_5s_m:.3f} | {r.yaw_err_5s_deg:.1f} | {r.n_windows} | "
                      f"{ref[0]:.2f} m" + ("" if ref[1] is None else f", {ref[1]:.1f} deg") + " |")
    md.append("")

    # 2. identification with the search, scored on the test runs ----------------------------
    md += ["### Identified model against the baselines (test runs)", "",
           f"Search: {grid.size} grid points (s {list(grid.s)}, tau {list(grid.tau)} s, alpha {list(grid.alpha)}, "
           f"T {list(grid.T)}, libraries {list(grid.library)}), {grid.n_folds}-fold cross-validation by run on the "
           "train runs, ranked by the 5 s position error; baselines on the same spline states and windows.", "",
           "| campaign | model | pos 5 s [m] | yaw 5 s [deg] | windows | x README unicycle | target |",
           "|---|---|---|---|---|---|---|"]
    scores, seconds = {}, {}
    for name in ex.CAMPAIGNS:
        t0 = time.perf_counter()
        scores[name] = ex.run_campaign(ex.DATA / name, grid, args.jobs)
        seconds[name] = time.perf_counter() - t0
        readme_uni = ex.README_BASELINES[name]["unicycle"][0]
        for label, pos, yaw, n in scores[name].rows():
            ratio = pos / readme_uni
            target = f"<= {ex.TARGET_RATIO[name]:.1f}: {'met' if ratio <= ex.TARGET_RATIO[name] else 'NOT met'}" \
                if label == "sindy" else ""
            md.append(f"| {name} | {label} | {pos:.3f} | {yaw:.1f} | {n} | {ratio:.2f} | {target} |")
        print(name, scores[name].rows(), f"{seconds[name]:.1f} s", flush=True)
    md.append("")
    for name, sc in scores.items():
        hp = sc.model.hyperparameters
        md += [f"`{name}`: {sc.model.library.name}, s = {hp['s']:g}, tau = {hp['tau']:g} s, alpha = {hp['alpha']:g}, "
               f"T = {hp['T']:g}, {sc.model.complexity} terms, cross-validated 5 s error "
               f"{sc.search.ranking(1)[0]['pos_err_5s_m']:.3f} m; search and scoring {seconds[name]:.0f} s wall.", "",
               "```", sc.model.equations(), "```", ""]

    # 3. cross-campaign ----------------------------------------------------------------------
    md += ["### Trained on one campaign, scored on the other", "",
           "| trained on | scored on | sindy pos/yaw | unicycle pos/yaw | constant velocity pos/yaw | envelope |",
           "|---|---|---|---|---|---|"]
    for a, b in (ex.CAMPAIGNS, ex.CAMPAIGNS[::-1]):
        sc = ex.score(scores[a].model, campaigns[a], campaigns[b])
        cells = [f"{r.pos_err_5s_m:.3f} m / {r.yaw_err_5s_deg:.1f} deg" for r in sc.results.values()]
        env = "; ".join(sc.envelope_warnings) or "inside"
        md.append(f"| {a} | {b} | {' | '.join(cells)} | {env} |")
    md.append("")

    # 4. diagnosis -----------------------------------------------------------------------------
    if not args.no_diagnose:
        from sindy_ekf.diagnose import diagnose_states

        md += ["### Diagnosis of the identified model", "",
               "`sindy_ekf.diagnose.diagnose_states` (families fitted on the train runs, scored on the test runs); "
               "beside it, the unicycle with an input delay chosen on the train runs (velocity residual), scored "
               "on the test runs, as an independent look at the command-to-motion delay.", "",
               "| campaign | verdict | estimate | pos 5 s before -> after [m] | next causes (gain m) | "
               "unicycle delay (train) | unicycle pos 5 s, no delay -> delayed |", "|---|---|---|---|---|---|---|"]
        for name, sc in scores.items():
            s = float(sc.model.hyperparameters["s"])
            tr, trn, _ = states_of_runs(campaigns[name].split("train"), s)
            te, ten, _ = states_of_runs(campaigns[name].split("test"), s)
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                d = diagnose_states(sc.model, tr, te, trn, ten, ekf=False)
            dt_diag = time.perf_counter() - t0
            est = d.ranked[0].score.estimate if d.verdict != "none" else {}
            est_txt = ", ".join(f"{k} = {v:.3g}" for k, v in est.items()) or "-"
            others = ", ".join(f"{c.name} ({c.gain:.3f})" for c in d.ranked[:4] if c.name != d.verdict)
            tr_d = [ex.states_by_differences(r) for r in campaigns[name].split("train")]
            te_d = [ex.states_by_differences(r) for r in campaigns[name].split("test")]
            delay = delay_from_train(tr_d)
            e0 = evaluate_model(UnicycleModel().fit(tr_d), te_d).pos_err_5s_m
            e1 = evaluate_model(UnicycleModel().fit(delayed(tr_d, delay)), delayed(te_d, delay)).pos_err_5s_m
            md.append(f"| {name} | {d.verdict} | {est_txt} | {d.before['pos_err_5s_m']:.3f} -> "
                      f"{d.after['pos_err_5s_m']:.3f} | {others} | {delay:.2f} s | {e0:.3f} -> {e1:.3f} |")
            print(name, "diagnosis", d.verdict, d.before, d.after, f"{dt_diag:.0f} s", flush=True)
        md.append("")

    # 5. estimator benchmark ------------------------------------------------------------------
    if importlib.util.find_spec("sindy_ekf.benchmark") is None:
        md += ["### Estimator benchmark", "", "`sindy_ekf.benchmark` did not exist when this ran: not measured.", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(md) + "\n")
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
