"""Identification out of sample (issue 13): real Warthog leave-one-day-out and the default
simulated campaign against its true dynamics.

Usage: ``.venv/bin/python -m bench.bench_identification [--jobs J] [--quick] [--no-sim] [--sim DIR]``;
writes ``bench/results/identification.md`` (and ``identification.json`` beside it).

1. **Real Warthog, leave one day out**: on ``../shared/data/warthog-drive-cmd`` and
   ``warthog-drive-wheels`` every run of one day (the date in the run name) is a train run and
   every run of the other day a test run, both ways, whatever the campaign's own split. ``identify``'s
   stage (:func:`sindy_ekf.stages.identification.identify`, the grid ``grid_for_runs`` picks for
   the train runs) runs on the train day alone (one group: cross-validation falls back to
   leaving out runs), timed; ``evaluate``'s stage scores the model, the ``lag`` baseline and the
   kinematic unicycle (both fitted on the train day) on the test day's reference windows. Nothing
   is chosen on the test day.
2. **Identify wall time** per real campaign with its own train split (the command's work, no
   evaluation).
3. **Default simulated campaign** (``simulate_campaign(DIR)``, seed 0, the default length; the
   tracker grid): ``identify`` then ``evaluate`` against the simulator's true dynamics.

Targets (issue 13): identified <= 0.8x the lag and <= 0.5x (cmd) / 0.7x (wheels) the unicycle
at 5 s; <= 1.1x the true dynamics on the simulated campaign; identify <= 60 s per real campaign.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from itertools import permutations
from pathlib import Path

from groundfloor.files import atomic_write_json, atomic_write_text
from groundfloor.types import TrajectoryCampaign
from identification.preprocessing.campaigns import open_campaign
from identification.sindy.reference import run_group
from identification.sindy.search import grid_for_runs
from simulation.truth import true_dynamics_of
from sindy_ekf.stages.evaluation import LAG, MODEL, ORACLE, evaluation_stage
from sindy_ekf.stages.identification import IdentificationPlan, identify, plan_identification

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent.parent / "shared" / "data" if (ROOT.parent.parent / "shared").is_dir() else Path("/work/shared/data")
CAMPAIGNS = ("warthog-drive-cmd", "warthog-drive-wheels")
UNICYCLE_TARGET = {"warthog-drive-cmd": 0.5, "warthog-drive-wheels": 0.7}


def _identify_and_score(campaign: TrajectoryCampaign, plan: IdentificationPlan, jobs: int, oracle=None) -> dict:
    """Return the identification's wall time, selection and the test scores of model and baselines."""
    start = time.perf_counter()
    ident = identify(plan, n_jobs=jobs)
    wall = time.perf_counter() - start
    ev = evaluation_stage(campaign, ident.model, oracle)
    err = ev.errors()
    pipe = ident.pipeline
    chosen = pipe.candidates[pipe.selected]
    out = {"identify_s": wall, "grid": plan.why, "grid_size": plan.grid.size, "selected": chosen.label,
           "complexity": ident.model.complexity, "dead_time_s": list(ident.model.dead_time_s),
           "equations": ident.model.equations().splitlines(), "cv": pipe.folds.note,
           "cv_pos_err_5s_m": chosen.cv_pos_err_5s_m, "cv_lag_pos_err_5s_m": pipe.lag_cv.cv_pos_err_5s_m,
           "checks_passed": bool(ident.model.checks.get("passed")),
           "test": {n: e.to_json() for n, e in err.items()},
           "sensitivity": {str(s): v for s, v in ev.sensitivity.items()}}
    log = logging.getLogger("bench")
    log.info("%s: %.0f s, %s", plan.name, wall, {n: round(e.pos_err_5s_m, 3) for n, e in err.items()})
    return out


def leave_one_day_out(name: str, jobs: int, quick: bool) -> list[dict]:
    """Return one record per (train day, test day) of campaign ``name``."""
    camp = open_campaign(DATA / name)
    days = list(dict.fromkeys(run_group(r) for r in camp.runs))
    records = []
    for train_day, test_day in permutations(days, 2):
        train = tuple(dataclasses.replace(r, split="train") for r in camp.runs if run_group(r) == train_day)
        test = tuple(dataclasses.replace(r, split="test") for r in camp.runs if run_group(r) == test_day)
        lodo = TrajectoryCampaign(camp.root, f"{name} train {train_day} test {test_day}", train + test)
        grid, why = grid_for_runs(train, quick=quick)
        plan = IdentificationPlan(str(DATA / name), lodo.name, train, grid, why)
        rec = _identify_and_score(lodo, plan, jobs)
        records.append({"campaign": name, "train_day": train_day, "test_day": test_day,
                        "train_runs": [r.name for r in train], "test_runs": [r.name for r in test], **rec})
    return records


def campaign_wall_time(name: str, jobs: int, quick: bool) -> float:
    """Return the wall time of identify on the campaign's own train runs."""
    plan = plan_identification(DATA / name, quick=quick)
    start = time.perf_counter()
    identify(plan, n_jobs=jobs)
    return time.perf_counter() - start


def simulated(sim_dir: Path, jobs: int, quick: bool) -> dict:
    """Return identify + evaluate on the default simulated campaign (simulated into ``sim_dir`` if missing)."""
    from simulation.campaign import simulate_campaign  # only this part needs the simulator

    if not (sim_dir / "campaign.yaml").exists():
        simulate_campaign(sim_dir)
    camp = open_campaign(sim_dir)
    plan = plan_identification(sim_dir, quick=quick)
    return _identify_and_score(camp, plan, jobs, true_dynamics_of(sim_dir))


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 else "-"


def markdown(lodo: list[dict], walls: dict, sim: dict | None, command: str) -> str:
    """Return the results page."""
    lines = ["# Identification out of sample (issue 13)", "", f"Command: `{command}`", "",
             "Machine: 2 cores shared with other jobs during the run (times are upper bounds).", "",
             "## Real Warthog, leave one day out", "",
             "Train on every run of one day, score on every run of the other (5 s windows, 50 % overlap, start "
             "states from the reference smoothing s = 1, truth the measured poses). Lag and unicycle fitted on "
             "the train day. Nothing chosen on the test day.", "",
             "| campaign | train -> test | identified pos 5 s [m] / yaw [deg] | lag | unicycle | const. vel. | "
             "id / lag (target <= 0.8) | id / unicycle (target) | selected | CV id / lag [m] | identify [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in lodo:
        t = r["test"]
        m, lag, uni, cv = t[MODEL], t[LAG], t["unicycle"], t["constant_velocity"]
        target = UNICYCLE_TARGET[r["campaign"]]
        ok_lag = "met" if m["pos_err_5s_m"] <= 0.8 * lag["pos_err_5s_m"] else "NOT met"
        ok_uni = "met" if m["pos_err_5s_m"] <= target * uni["pos_err_5s_m"] else "NOT met"
        lines.append(f"| {r['campaign']} | {r['train_day']} -> {r['test_day']} | {m['pos_err_5s_m']:.3f} / "
                     f"{m['yaw_err_5s_deg']:.2f} | {lag['pos_err_5s_m']:.3f} / {lag['yaw_err_5s_deg']:.2f} | "
                     f"{uni['pos_err_5s_m']:.3f} / {uni['yaw_err_5s_deg']:.2f} | {cv['pos_err_5s_m']:.3f} | "
                     f"{_ratio(m['pos_err_5s_m'], lag['pos_err_5s_m'])} {ok_lag} | "
                     f"{_ratio(m['pos_err_5s_m'], uni['pos_err_5s_m'])} (<= {target}) {ok_uni} | {r['selected']} "
                     f"({r['complexity']} terms, dead time {r['dead_time_s'][0]:.2f}/{r['dead_time_s'][1]:.2f} s) | "
                     f"{r['cv_pos_err_5s_m']:.3f} / {r['cv_lag_pos_err_5s_m']:.3f} | {r['identify_s']:.0f} |")
    lines += ["", "Selected models:", ""]
    for r in lodo:
        lines.append(f"- {r['campaign']} train {r['train_day']} ({r['grid']}, {r['grid_size']} points; {r['cv']}):")
        lines += [f"    - `{eq}`" for eq in r["equations"]]
        lines.append("    - start-state sensitivity (s: identified / lag, m): " + ", ".join(
            f"{s}: {v.get(MODEL, float('nan')):.3f} / {v.get(LAG, float('nan')):.3f}"
            for s, v in r["sensitivity"].items()))
    if walls:
        lines += ["", "## identify wall time on each real campaign (its own train split, target <= 60 s)", ""]
        lines += [f"- {n}: {w:.0f} s ({'met' if w <= 60 else 'NOT met'})" for n, w in walls.items()]
    if sim is not None:
        t = sim["test"]
        ratio = t[MODEL]["pos_err_5s_m"] / t[ORACLE]["pos_err_5s_m"]
        lines += ["", "## Default simulated campaign (seed 0, default length, through bags and preprocessing)", "",
                  f"- grid: {sim['grid']}, {sim['grid_size']} points; identify {sim['identify_s']:.0f} s; "
                  f"selected {sim['selected']} ({sim['complexity']} terms); {sim['cv']}",
                  "| model | pos 5 s [m] | yaw 5 s [deg] |", "|---|---|---|"]
        lines += [f"| {n} | {e['pos_err_5s_m']:.4f} | {e['yaw_err_5s_deg']:.3f} |" for n, e in t.items()]
        lines.append(f"\nidentified / true dynamics: **{ratio:.2f}x** (target <= 1.1: "
                     f"{'met' if ratio <= 1.1 else 'NOT met'})")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="the quick grids (for a smoke run; not the recorded figures)")
    p.add_argument("--no-sim", action="store_true", help="leave out the simulated campaign")
    p.add_argument("--no-lodo", action="store_true", help="leave out the leave-one-day-out part")
    p.add_argument("--no-walls", action="store_true", help="leave out the wall time on the campaigns' own splits")
    p.add_argument("--sim", type=Path, default=Path("/tmp/sindy_ekf_bench_identification_sim"),
                   help="where the default simulated campaign is (simulated there when missing)")
    p.add_argument("--from-json", action="store_true", help="only re-render the page from the saved figures")
    p.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "identification.md")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("bench").setLevel(logging.INFO)
    command = "python -m bench.bench_identification " + " ".join(argv if argv is not None else sys.argv[1:])
    raw = args.out.with_suffix(".json")
    if args.from_json:  # re-render the page from a finished run's figures
        done = json.loads(raw.read_text())
        atomic_write_text(args.out, markdown(done["leave_one_day_out"], done["identify_wall_s"], done["simulated"],
                                             done["command"]))
        print(args.out.read_text())
        return 0
    found = {"command": command.strip(), "leave_one_day_out": [], "identify_wall_s": {}, "simulated": None}
    if raw.exists() and (args.no_lodo or args.no_walls or args.no_sim):  # a partial run keeps the other parts
        before = json.loads(raw.read_text())
        found = {**before, "command": f"{before.get('command', '')}; then {command.strip()}"}
        found.update({k: v for k, v in (("leave_one_day_out", []), ("identify_wall_s", {}), ("simulated", None))
                      if not getattr(args, "no_" + {"leave_one_day_out": "lodo", "identify_wall_s": "walls",
                                                    "simulated": "sim"}[k])})
    # the figures are saved after every step: a crash keeps what was measured
    for name in () if args.no_lodo else CAMPAIGNS:
        found["leave_one_day_out"] += leave_one_day_out(name, args.jobs, args.quick)
        atomic_write_json(raw, found)
    for name in () if args.no_walls else CAMPAIGNS:
        found["identify_wall_s"][name] = campaign_wall_time(name, args.jobs, args.quick)
        atomic_write_json(raw, found)
    if not args.no_sim:
        found["simulated"] = simulated(args.sim, args.jobs, args.quick)
        atomic_write_json(raw, found)
    atomic_write_text(args.out, markdown(found["leave_one_day_out"], found["identify_wall_s"], found["simulated"],
                                         found["command"]))
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
