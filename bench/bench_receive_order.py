"""Bags stored in receive order (issue 14): a default-size campaign with receive jitter, through
the command line, against the same campaign without it and against truth.

Usage: ``.venv/bin/python -m bench.bench_receive_order [--minutes M] [--seed N] [--jitter MS_LO,MS_HI]``;
writes ``bench/results/receive_order.md``. Three campaigns are simulated once into ``bench/_work/``
(gitignored) and reused, all of one seed, so that they hold the same messages:

- ``plain``: every topic received in stamp order (the simulator's default);
- ``jitter``: ``simulate --receive-jitter``: every message its own receive latency, so spurious
  AT960 pulses next to real ones are stored out of stamp order, as in independently generated
  campaigns;
- ``reset``: the jittered campaign with the AT960 clock restarted half-way through run_06 and the
  LTD800's 2 % into run_09 (a part too short to keep).

Each is preprocessed with ``sindy-ekf preprocess OUT --out P --json P.json`` (wall time of the
whole command, taken ``--repeats`` times in alternation, the best kept: the machine is shared,
and a busy moment slows any stage, the synchronisation of identical data included) and scored
against ``truth/``: runs kept, reorderings counted (against what the simulator injected), pose
position RMS, drift and offset errors.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from groundfloor.files import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]

RESETS = ("run_06:at960:0.5", "run_09:ltd800:0.02")


def cli(*args: str) -> float:
    """Run ``sindy-ekf ARGS`` in a fresh interpreter; return its wall time in seconds."""
    tic = time.perf_counter()
    subprocess.run([sys.executable, "-m", "sindy_ekf.cli", *args, "--quiet"], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - tic


def source(name: str) -> str:
    """Return the run a part ``<run>.<k>`` was cut from (the name itself for a whole run)."""
    head, _, tail = name.rpartition(".")
    return head if head and tail.isdigit() else name


def score(camp: Path, out: Path) -> dict:
    """Return runs, reorderings and errors against truth of one preprocessed campaign."""
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from simulation.truth import read_truth

    truth = read_truth(camp)
    report = json.loads((out / "preprocess.json").read_text())
    rows, err_p = [], []
    for run in read_trajectory_campaign(out).runs:
        t, r = truth.run(source(run.name)), report["runs"][run.name]
        st = t.states
        i = np.clip(np.searchsorted(st.t_utc, run.poses.t), 1, st.t_utc.size - 1)
        i -= np.abs(st.t_utc[i - 1] - run.poses.t) < np.abs(st.t_utc[i] - run.poses.t)
        e = np.linalg.norm(np.column_stack([run.poses.x - st.x[i], run.poses.y - st.y[i],
                                            run.poses.z - st.z[i]]), axis=1)
        err_p.append(e)
        rows.append({"run": run.name, "reordered": sum(r["reordered"].values()),
                     "injected": sum(t.bags.get("reordered", {}).values()),
                     "pos_rms_mm": float(np.sqrt(np.mean(e**2)) * 1e3),
                     "ltd_err_ppm": r["clock"]["ltd800"]["drift_ppm"] - t.clocks["ltd800"]["drift_ppm"],
                     "at_err_ppm": r["clock"]["at960"]["drift_ppm"] - t.clocks["at960"]["drift_ppm"],
                     "offset_err_us": (r["at960_extra_offset_s"] - t.at960["offset_s"]) * 1e6,
                     "resets": [f"{c['topic']} message {c['message']} ({c['jump_s']:+.3f} s)"
                                for c in r["clock_resets"]],
                     "dropped": r["parts_dropped"]})
    return {"rows": rows, "skipped": report["skipped_runs"], "n_truth_runs": len(truth.runs),
            "injected": sum(sum(t.bags.get("reordered", {}).values()) for t in truth.runs),
            "pos_rms_mm": float(np.sqrt(np.mean(np.concatenate(err_p) ** 2)) * 1e3)}


def summary(sc: dict) -> str:
    """Return one line of the overview table for a scored campaign."""
    rows = sc["rows"]
    worst = {k: max(abs(r[k]) for r in rows) for k in ("ltd_err_ppm", "at_err_ppm", "offset_err_us")}
    return (f"{len(rows)} | {len(sc['skipped'])} | {sum(r['reordered'] for r in rows)} / {sc['injected']} | "
            f"{sc['pos_rms_mm']:.3f} | {worst['ltd_err_ppm']:.4f} | {worst['at_err_ppm']:.3f} | "
            f"{worst['offset_err_us']:.1f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=None, help="driving minutes (default 45.4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jitter", default="2,12", help="receive latency range in ms (simulate --receive-jitter)")
    ap.add_argument("--repeats", type=int, default=3, help="timed preprocess runs per campaign, in alternation")
    ap.add_argument("--before", type=Path, default=None, metavar="CHECKOUT",
                    help="a checkout of the code before issue 14 (e.g. `git worktree add ../before 6c1b82f`): "
                         "what its preprocess says of the jittered campaign is recorded")
    args = ap.parse_args()

    tag = ("default" if args.minutes is None else f"{args.minutes:g}min") + f"_seed{args.seed}"
    work = ROOT / "bench" / "_work" / f"receive_order_{tag}"
    base = ["--seed", str(args.seed)] + ([] if args.minutes is None else ["--minutes", f"{args.minutes:g}"])
    variants = {"plain": [], "jitter": ["--receive-jitter", args.jitter],
                "reset": ["--receive-jitter", args.jitter] + [a for r in RESETS for a in ("--clock-reset", r)]}
    sim_s = {}
    for name, extra in variants.items():
        camp = work / name
        if not (camp / "campaign.yaml").is_file():
            sim_s[name] = cli("simulate", str(camp), *base, *extra, "--force")
            print(f"simulated {camp} in {sim_s[name]:.1f} s", flush=True)
    load = os.getloadavg()
    wall = {name: [] for name in variants}
    for _ in range(args.repeats):  # alternate, so that a busy moment of the shared machine hits all
        for name in variants:
            out = work / f"{name}_out"
            shutil.rmtree(out, ignore_errors=True)
            wall[name].append(cli("preprocess", str(work / name), "--out", str(out), "--json",
                                  str(work / f"{name}.json")))
            print(f"preprocessed {name} in {wall[name][-1]:.1f} s", flush=True)
    scores = {name: score(work / name, work / f"{name}_out") for name in variants}
    before = []
    if args.before is not None:
        shutil.rmtree(work / "before_out", ignore_errors=True)
        done = subprocess.run([sys.executable, "-m", "sindy_ekf.cli", "preprocess", str(work / "jitter"), "--out",
                               str(work / "before_out"), "--quiet"], cwd=args.before, capture_output=True, text=True)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=args.before, capture_output=True,
                                text=True).stdout.strip()
        said = done.stderr.strip().splitlines()[-1].replace(f"{ROOT}/", "") if done.stderr.strip() else "no error"
        before = ["", f"The reader before this change (commit {commit}, `--before`) on the jittered campaign: exit "
                  f"code {done.returncode}, `{said}`"]

    minutes = "table 6.4, 45.4 min" if args.minutes is None else f"{args.minutes:g} min"
    cmd = " ".join(["`.venv/bin/python -m bench.bench_receive_order", *sys.argv[1:]]).strip() + "`"
    sim = " ".join(base)
    lines = [
        "## Bags stored in receive order (issue 14, item 1)", "",
        f"Command: {cmd}. Campaigns ({minutes}, seed {args.seed}), each simulated and preprocessed "
        "through the command line:", "",
        f"- plain: `sindy-ekf simulate OUT {sim}`",
        f"- jitter: `sindy-ekf simulate OUT {sim} --receive-jitter {args.jitter}`",
        f"- reset: as jitter, plus `{' '.join('--clock-reset ' + r for r in RESETS)}`",
        "", "each then `sindy-ekf preprocess OUT --out P --json P.json`. Errors are estimate - truth "
        "(`truth/`), worst over runs; reorderings are the preprocess JSON's `reordered`, summed, "
        "against the number the simulator injected (`truth.yaml` runs.*.bags.reordered).", "",
        "| campaign | runs kept | runs skipped | reordered / injected | pose RMS mm | "
        f"LTD800 drift err ppm | AT960 drift err ppm | offset err us | preprocess wall s (best of {args.repeats}) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        *[f"| {name} | {summary(sc)} | {min(wall[name]):.1f} ({', '.join(f'{w:.1f}' for w in wall[name])}) |"
          for name, sc in scores.items()],
        *before,
        "", f"Load average {load[0]:.1f} before the timings and {os.getloadavg()[0]:.1f} after (the "
        "machine is shared by other jobs).", "",
        "Per run of the jittered campaign (reordered = messages stored right after one with a later "
        "stamp, all on /at960/measurement here):", "",
        "| run | reordered | injected | pose RMS mm (plain) | AT960 drift err ppm | offset err us |",
        "|---|---:|---:|---:|---:|---:|",
        *[f"| {r['run']} | {r['reordered']} | {r['injected']} | {r['pos_rms_mm']:.4f} ({p['pos_rms_mm']:.4f}) | "
          f"{r['at_err_ppm']:+.4f} | {r['offset_err_us']:+.2f} |"
          for r, p in zip(scores["jitter"]["rows"], scores["plain"]["rows"])],
        "", "Clock resets (reset campaign):", "",
        *[f"- {r['run']}: reset {'; '.join(r['resets'])}; AT960 drift err {r['at_err_ppm']:+.4f} ppm, "
          f"offset err {r['offset_err_us']:+.2f} us, pose RMS {r['pos_rms_mm']:.4f} mm"
          + (f"; dropped: {'; '.join(r['dropped'])}" if r["dropped"] else "")
          for r in scores["reset"]["rows"] if r["resets"]],
        "",
    ]
    path = ROOT / "bench" / "results" / "receive_order.md"
    atomic_write_text(path, "\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
