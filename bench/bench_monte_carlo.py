"""Faults survived, measured (issue 14, item 3): Monte-Carlo runs under GNSS faults, and the plain
SINDy EKF on the real Warthog cmd runs.

Monte Carlo (:mod:`sindy_ekf.benchmark.monte_carlo`): each run is a 150 s window of a test run of
the default simulated campaign at a random start, with its own dgnss noise and one fault mix of
:data:`simulation.gnss_faults.FAULT_MIXES` (the mixes in turn: none, outliers, multipath, jump,
cov_small, outage, all), seeded by ``(seed, run index)``. ``sindy_ekf`` and ``sindy_ekf_lateral``
run on every window (chunks of windows in lockstep, NIS monitor and re-initialisation on), the
batch ``sindy_graph`` on a random subset (``--graph-runs``). Chunks go to ``--jobs`` processes
(or to the Dask cluster of ``--dask ADDRESS``; groundfloor.parallel).

Warthog: :func:`sindy_ekf.benchmark.run.benchmark_campaign` on ``warthog-drive-cmd`` (dgnss
simulated from the ICP poses, seed 0, the model identified by ``sindy-ekf identify``), plain
``sindy_ekf`` and ``sindy_ekf_lateral``; whether the plain filter diverges, and its lateral
velocity against the train runs' to show the mechanism.

Usage::

    python -m bench.bench_monte_carlo [--campaign TRAJ] [--model MODEL.json] [--runs 1000]
        [--graph-runs 100] [--jobs 2] [--dask ADDRESS] [--real-model CMD.json]

Without ``--campaign``/``--model`` the default campaign is simulated, preprocessed and identified
into ``bench/_work/monte_carlo`` as ``bench_ekf_speed`` does. Writes ``bench/results/monte_carlo.md``
and ``bench/results/monte_carlo.json``.
"""

from __future__ import annotations

import argparse
import json
import logging
import subprocess
import sys
import time
import warnings
from dataclasses import asdict, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from groundfloor.parallel import Workers, parallel_iter

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "warthog-drive-cmd"


@lru_cache(maxsize=1)
def _context(campaign_dir: str, model_path: str):
    """Return the models, lateral constraint and sources of a campaign (once per worker process)."""
    from identification.preprocessing.campaigns import open_campaign
    from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
    from identification.sindy.model import SindyModel
    from sindy_ekf.benchmark.monte_carlo import prepare_sources
    from sindy_ekf.benchmark.run import LATERAL_EVERY, fit_models, train_series
    from sindy_ekf.estimation.ekf import fit_lateral_constraint

    campaign = open_campaign(campaign_dir)
    model = SindyModel.load(model_path)
    series = train_series(campaign.split("train"), DEFAULT_SMOOTHING)
    models = fit_models(campaign.split("train"), model, None, DEFAULT_SMOOTHING, series)
    lateral = fit_lateral_constraint([x.x6[:, 4] for x in series], every=LATERAL_EVERY)
    return models["sindy_ekf"], lateral, prepare_sources(campaign.split("test"), DEFAULT_SMOOTHING)


def run_chunk(campaign_dir: str, model_path: str, indices: list[int], seed: int, profile: str,
              graph_on: set[int], window_s: float | None = None) -> tuple[list, float]:
    """Return the outcomes of Monte-Carlo runs ``indices`` and this process's CPU seconds for them."""
    from sindy_ekf.benchmark.monte_carlo import draw_window, run_windows
    from sindy_ekf.benchmark.run import P0_STD

    logging.disable(logging.WARNING)  # re-initialisations are counted in the outcomes, not logged
    cpu = time.process_time()
    model, lateral, sources = _context(campaign_dir, model_path)
    windows = [draw_window(sources, i, seed, profile, **({} if window_s is None else {"window_s": window_s}))
               for i in indices]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = run_windows(model, lateral, windows, np.diag(P0_STD ** 2), graph_on)
    return [asdict(o) for o in out], time.process_time() - cpu


def run_chunk_task(task: tuple) -> tuple[list, float]:
    """Return :func:`run_chunk` of one task ``(campaign_dir, model_path, indices, seed, profile, graph_on, window_s)``."""
    return run_chunk(*task)


def build_default(cache: Path) -> tuple[Path, Path]:
    """Return the default campaign (trajectory) and its full-grid model, made in ``cache`` if missing."""
    exe = str(Path(sys.executable).parent / "sindy-ekf")
    cache.mkdir(parents=True, exist_ok=True)
    traj, raw, model = cache / "traj", cache / "campaign", cache / "model.json"
    if not (traj / "campaign.yaml").is_file():
        if not (raw / "campaign.yaml").is_file():
            subprocess.run([exe, "simulate", str(raw), "--seed", "0", "--quiet"], check=True)
        subprocess.run([exe, "preprocess", str(raw), "--out", str(traj), "--quiet"], check=True)
    if not model.is_file():
        subprocess.run([exe, "identify", str(traj), "--out", str(model), "--jobs", "2", "--quiet"], check=True)
    return traj, model


def summarise(rows: list[dict]) -> list[str]:
    """Return the markdown tables of the outcomes: per estimator and mix, and outage-end errors."""
    from sindy_ekf.benchmark.monte_carlo import MC_ESTIMATORS

    mixes = list(dict.fromkeys(r["mix"] for r in sorted(rows, key=lambda r: r["index"] % 7)))
    md = ["| estimator | fault mix | runs | diverged | failed | runs re-initialised (total) | NEES in band | "
          "median NEES mean | median per-sample share in 95 % | ATE median m | ATE p95 m | ATE max m | "
          "re-initialisations per hour | alarms explained by a step of the fixes (not reset) | runs with "
          "saturated model steps |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for est in MC_ESTIMATORS:
        for mix in mixes + ["all mixes"]:
            rs = [r for r in rows if r["estimator"] == est and (mix == "all mixes" or r["mix"] == mix)]
            if not rs:
                continue
            st = [r["status"] for r in rs]
            rec = [r["recoveries"] for r in rs]
            ate = np.array([r["ate_pos_m"] for r in rs], float)
            nm = np.array([r["nees_mean"] for r in rs], float)
            sh = np.array([r["nees_share_95"] for r in rs], float)
            label = f"**{mix}**" if mix == "all mixes" else mix
            md.append(f"| {est} | {label} | {len(rs)} | {st.count('diverged')} | {st.count('failed')} | "
                      f"{sum(1 for x in rec if x)} ({sum(rec)}) | {np.mean([r['nees_in_band'] for r in rs]):.2f} | "
                      f"{np.nanmedian(nm):.2f} | {np.nanmedian(sh):.2f} | {np.nanmedian(ate):.3f} | "
                      f"{np.nanpercentile(ate, 95):.3f} | {np.nanmax(ate):.2f} | "
                      f"{3600.0 * sum(rec) / max(np.nansum([r.get('window_s', np.nan) for r in rs]), 1e-9):.2f} | "
                      f"{sum(r.get('fix_steps', 0) for r in rs)} | "
                      f"{sum(1 for r in rs if r.get('saturated_steps', 0))} |")
    md += ["", "Position error at the end of the outage, by outage length (windows of the `outage` and `all` mixes; "
           "n = outages reached):", "",
           "| estimator | fault mix | outage s | n | median m | p95 m | max m |", "|---|---|---|---|---|---|---|"]
    for est in MC_ESTIMATORS:
        for mix in ("outage", "all"):
            for d in sorted({r["outage_s"] for r in rows if np.isfinite(r["outage_s"])}):
                e = np.array([r["outage_end_err_m"] for r in rows if r["estimator"] == est and r["mix"] == mix
                              and r["outage_s"] == d], float)
                e = e[np.isfinite(e)]
                if e.size:
                    md.append(f"| {est} | {mix} | {d:g} | {e.size} | {np.median(e):.3f} | "
                              f"{np.percentile(e, 95):.3f} | {e.max():.3f} |")
    return md


def real_cmd(model_path: Path) -> tuple[list[str], dict]:
    """Return the markdown and figures of plain and lateral sindy_ekf on the Warthog cmd test runs."""
    from identification.preprocessing.campaigns import open_campaign
    from identification.sindy.model import SindyModel
    from sindy_ekf.benchmark.health import guarded_ekf_batch
    from sindy_ekf.benchmark.run import P0_STD, _prepare_run, benchmark_campaign, fit_models, train_series
    from sindy_ekf.estimation.ekf import EkfRun

    campaign = open_campaign(REAL)
    model = SindyModel.load(model_path)
    s = float(model.hyperparameters["s"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = benchmark_campaign(campaign, model, profile="dgnss", seed=0, smoothing=s,
                                 estimators=("sindy_ekf", "sindy_ekf_lateral", "dead_reckoning"))
    vy_train = np.concatenate([x.x6[:, 4] for x in train_series(campaign.split("train"), s)])
    figures = {"vy_train_rms_m_s": float(np.sqrt(np.mean(vy_train ** 2))), "estimators": {}}
    md = [f"`benchmark_campaign({REAL.name}, model, profile='dgnss', seed=0, smoothing={s:g})` with the model "
          f"`{model_path}`:", "", "```", model.equations(),
          "```", "",
          "| estimator | status | re-initialisations | reason | ATE m | ATE deg | max abs v_y estimate m/s | "
          "RMS v_y estimate m/s |", "|---|---|---|---|---|---|---|---|"]
    for est, sc in res.scores.items():
        vy = np.concatenate([e.x[:, 4] for e in res.estimates[est].values() if len(e.x)])
        figures["estimators"][est] = {"status": sc.status, "recoveries": sc.recoveries, "reason": sc.reason,
                                      "ate_pos_m": sc.ate_pos_m, "ate_yaw_deg": sc.ate_yaw_deg,
                                      "vy_max_m_s": float(np.max(np.abs(vy))),
                                      "vy_rms_m_s": float(np.sqrt(np.mean(vy ** 2)))}
        f = figures["estimators"][est]
        md.append(f"| {est} | {sc.status} | {sc.recoveries} | {sc.reason or '-'} | {sc.ate_pos_m:.3f} | "
                  f"{sc.ate_yaw_deg:.2f} | {f['vy_max_m_s']:.3f} | {f['vy_rms_m_s']:.3f} |")
    md += ["", f"RMS of v_y on the train runs' smoothed states: {figures['vy_train_rms_m_s']:.3f} m/s.", "",
           "The same plain `sindy_ekf` without the monitor's re-initialisation (`guarded_ekf_batch(..., "
           "recover=False)`, same GNSS); with `v_y` left a random walk (`fit_process_noise(..., mean_reverting=False)`, "
           "the mechanism of issue 14 item 3 switched off), without the step test, and with the yaw equation's `vy` "
           "coefficient set to 0 (mechanism checks):",
           "", "| model | run | status | reason | max abs v_y m/s | final position error m |", "|---|---|---|---|---|---|"]
    names = list(model.library.feature_names)
    coef = model.coef.copy()
    coef[2, names.index("vy")] = 0.0
    figures["no_recovery"] = {}
    from sindy_ekf.estimation.process_models import fit_process_noise

    series = train_series(campaign.split("train"), s)
    cases = (("as identified", model, True, True), ("as identified, vy a random walk", model, False, True),
             ("as identified, no step test", model, True, False), ("yaw's vy term 0", replace(model, coef=coef), True, True))
    for label, m, mean_reverting, step_test in cases:
        models = fit_models(campaign.split("train"), m, None, s)
        if not mean_reverting:
            fit_process_noise(models["sindy_ekf"], series, mean_reverting=False)
        test = campaign.split("test")
        runs = [_prepare_run(r, "dgnss", i, None, s, 30.0, 30.0) for i, r in enumerate(test)]
        batch = [EkfRun(r.name, r.grid, r.u, r.x0, np.diag(P0_STD ** 2), r.gnss) for r in runs]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            results = guarded_ekf_batch(models["sindy_ekf"], batch, recover=False, step_test=step_test)
        for r, (ekf, st) in zip(runs, results):
            n = 0 if ekf is None else int(np.searchsorted(r.at_pose, len(ekf.t)))
            err = float(np.hypot(*(ekf.x[r.at_pose[n - 1], :2] - r.truth[n - 1, 1:3]))) if n else float("nan")
            vy = float(np.max(np.abs(ekf.x[:, 4]))) if ekf is not None else float("nan")
            figures["no_recovery"][f"{label} {r.name}"] = {"status": st.status, "t_s": st.t_s, "reason": st.reason,
                                                          "vy_max_m_s": vy, "final_err_m": err}
            md.append(f"| {label} | {r.name} | {st.status} | {st.reason or '-'} | {vy:.3f} | {err:.3f} |")
    return md, figures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--campaign", type=Path, default=None, help="trajectory campaign (default: built in --cache)")
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--graph-runs", type=int, default=100, help="random subset of runs that also get sindy_graph")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--dask", default=None, metavar="SCHEDULER_ADDRESS", help="run the chunks on this Dask cluster")
    ap.add_argument("--chunk", type=int, default=20, help="Monte-Carlo runs per lockstep batch")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--profile", default="dgnss")
    ap.add_argument("--window-s", type=float, default=None, help="window length (default: monte_carlo.WINDOW_S, 150 s)")
    ap.add_argument("--real-model", type=Path, default=None, help="model of warthog-drive-cmd (default: identified)")
    ap.add_argument("--no-real", action="store_true")
    ap.add_argument("--cache", type=Path, default=ROOT / "bench" / "_work" / "monte_carlo")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "monte_carlo.md")
    args = ap.parse_args()
    workers = Workers(args.jobs, args.dask)

    load0 = Path("/proc/loadavg").read_text().split()[:3]
    wall0, cpu0 = time.perf_counter(), time.process_time()
    if args.campaign is None or args.model is None:
        traj, model = build_default(args.cache)
    campaign_dir, model_path = (args.campaign or traj).resolve(), (args.model or model).resolve()
    real_md, real_fig = [], {}
    if not args.no_real:  # first: a minute, and its verdict does not wait for the Monte Carlo
        real_model = args.real_model or args.cache / "warthog-drive-cmd.json"
        if not real_model.is_file():
            subprocess.run([str(Path(sys.executable).parent / "sindy-ekf"), "identify", str(REAL), "--out",
                            str(real_model), "--jobs", "2", "--quiet"], check=True)
        real_md, real_fig = real_cmd(real_model)
    rng = np.random.default_rng(args.seed)
    graph_on = set(rng.choice(args.runs, size=min(args.graph_runs, args.runs), replace=False).tolist())
    chunks = [list(range(i, min(i + args.chunk, args.runs))) for i in range(0, args.runs, args.chunk)]
    # the workers import the chunk function from the module (a function of __main__ does not unpickle there)
    from bench.bench_monte_carlo import run_chunk_task as chunk_fn

    rows, cpu_workers = [], 0.0

    def write(n_done: int) -> str:
        """Write the results of the chunks done so far (all of them at the end); return the markdown."""
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0 + cpu_workers
        load1 = Path("/proc/loadavg").read_text().split()[:3]
        n_runs = len({r["index"] for r in rows})
        n_graph = len({r["index"] for r in rows if r["estimator"] == "sindy_graph"})
        state = "" if n_done == len(chunks) else (f" **Partial: {n_done} of {len(chunks)} chunks done when this "
                                                  "was written.**")
        md = ["# Faults survived: Monte Carlo under GNSS faults (issue 14, item 3)", "",
              f"Command: `python -m bench.bench_monte_carlo {' '.join(sys.argv[1:])}`", "",
              f"Campaign `{campaign_dir}`, model `{model_path}`. {n_runs} of {args.runs} Monte-Carlo runs done "
              f"({n_graph} of them also through `sindy_graph`, of {len(graph_on)} asked), {workers.describe()}, "
              f"chunks of {args.chunk} runs in lockstep.{state} Wall {wall:.0f} s, CPU {cpu:.0f} s over all "
              f"processes; load average {' '.join(load0)} at start, {' '.join(load1)} when written (2 cores, "
              "shared).", ""]
        if real_md:
            md += ["## Plain SINDy EKF on the real Warthog cmd runs", "", *real_md, ""]
        md += ["## Monte Carlo", "", *(summarise(rows) if rows else ["(no chunk done yet)"]), ""]
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(md) + "\n")
        args.out.with_suffix(".json").write_text(json.dumps({"runs": rows, "real": real_fig, "wall_s": wall,
                                                             "cpu_s": cpu, "chunks_done": n_done,
                                                             "chunks": len(chunks)}, default=float) + "\n")
        return "\n".join(md)

    text = write(0)
    # in chunk order, each chunk's windows drawn from its own indices and the seed: the same runs
    # whichever worker or cluster computes them
    jobs = parallel_iter(chunk_fn, [(str(campaign_dir), str(model_path), c, args.seed, args.profile,
                                     graph_on & set(c), args.window_s) for c in chunks], workers,
                         desc="Monte-Carlo chunks", names=[f"chunk of runs {c[0]}-{c[-1]}" for c in chunks])
    for n_done, (out, cpu_chunk) in enumerate(jobs, start=1):
        rows += out
        cpu_workers += cpu_chunk
        text = write(n_done)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
