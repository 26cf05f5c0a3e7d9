"""Time ``sindy-ekf identify`` before and after a speed-up (issue 13, item 7), side by side.

Usage: ``.venv/bin/python -m bench.bench_identify_speed [--base REV] [--full] [--jobs J] [--no-write]``;
writes ``bench/results/identify_speed.md``.

"Before" is the checkout at ``--base`` (default :data:`BASE`, the commit the speed-up started
from) exported into a temporary folder; "after" is this checkout. Each runs ``python -m
sindy_ekf.cli identify`` as a subprocess with its own sources first on the path, one after the
other on the same data, so each is timed by wall clock and by the children's CPU time
(``resource.getrusage``). Cases:

1. **demo-sized**: the demo's identification stage, ``--quick`` (12 grid points, 3 folds) on the
   8-minute simulated campaign of seed 0 (``simulate``, then ``preprocess``; not timed);
2. **real cmd**: ``../shared/data/warthog-drive-cmd`` on its own train split (the low-rate grid);
3. with ``--full``, **default campaign**: the full tracker grid (384 points, 5 folds) on the
   default simulated campaign of seed 0 with ``--jobs`` (default 2), before and after alike.

Each before/after pair is compared: selected candidate, hyperparameters and active terms must be
identical, and the largest relative difference of the coefficients, dead times and input lags
and of every candidate's cross-validated error is reported. numba's compilation is done before
the timings (the "before" checkout compiles nothing that identify calls).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.publish import publish
from bench.revisions import export_revision
from identification.sindy.model import SindyModel

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent.parent / "shared" / "data" if (ROOT.parent.parent / "shared").is_dir() else Path("/work/shared/data")
#: the commit the speed-up started from (main before issue 13, item 7)
BASE = "92f8906"
PY = sys.executable
#: compiles (or loads from numba's cache) the compiled output-error rollout and input lag on a tiny problem
WARM_UP = """
import numpy as np
from identification.sindy.model import model_from_terms
from identification.sindy.sensitivity_rollout import sensitivity_rollout
m = model_from_terms({"vx": {"vx": -1.0, "u1": 1.0}}, "poly1")
u = np.zeros((1, 3, 2))
sensitivity_rollout(m._active_terms(), np.zeros(1, int), np.zeros((1, 3), int), np.ones(1, bool), np.zeros((1, 6)),
                    u, 0.05, 2, u, u)
from groundfloor.input_chain import first_order_lag
first_order_lag(np.zeros((3, 2)), 0.01, (0.1, 0.1))
"""


def run(args: list[str], cwd: Path) -> tuple[float, float]:
    """Return (wall s, CPU s of the children) of ``python -m sindy_ekf.cli ARGS`` with ``cwd``'s sources."""
    env = dict(os.environ, PYTHONPATH=str(cwd))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    proc = subprocess.run([PY, "-m", "sindy_ekf.cli", *args, "--quiet"], cwd=cwd, env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(args)} in {cwd} failed:\n{proc.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def compare(before: Path, after: Path) -> dict:
    """Return how the model files of the same identification differ."""
    a, b = SindyModel.load(before), SindyModel.load(after)
    strip = ("dead_time_s", "input_lag_s")
    hp_a = {k: v for k, v in a.hyperparameters.items() if k not in strip}
    hp_b = {k: v for k, v in b.hyperparameters.items() if k not in strip}
    nz = a.coef != 0
    same_terms = a.library.name == b.library.name and np.array_equal(nz, b.coef != 0)
    rel = float(np.max(np.abs(a.coef[nz] - b.coef[nz]) / np.abs(a.coef[nz]))) if same_terms and nz.any() else np.nan
    chain = float(np.max(np.abs(np.r_[a.dead_time_s, a.input_lag_s] - np.r_[b.dead_time_s, b.input_lag_s])))
    cv = [(ca["label"], ca["cv_pos_err_5s_m"], cb["cv_pos_err_5s_m"], ca["passed_checks"] == cb["passed_checks"])
          for ca, cb in zip(a.training["candidates"], b.training["candidates"])]
    return {"selected": (a.training["selected"], b.training["selected"]), "same_hp": hp_a == hp_b,
            "same_terms": same_terms, "n_terms": int(nz.sum()), "coef_rel": rel, "chain_s": chain, "cv": cv,
            "hp": hp_b}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", default=BASE, help=f"the 'before' revision (default {BASE})")
    p.add_argument("--full", action="store_true", help="also the full tracker grid on the default campaign")
    p.add_argument("--jobs", type=int, default=2, help="--jobs of the full-grid run (default 2)")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="identify_speed_") as tmp:
        tmp = Path(tmp)
        old = export_revision(ROOT, args.base, tmp / "before")
        run(["simulate", str(tmp / "sim8"), "--minutes", "8", "--seed", "0"], ROOT)
        run(["preprocess", str(tmp / "sim8"), "--out", str(tmp / "traj8"), "--jobs", "1"], ROOT)
        subprocess.run([PY, "-c", WARM_UP], cwd=ROOT, check=True)  # numba compiles here, not in the timings
        # the before tree's own compilation (its numba cache is by its source path); none before it had numba
        subprocess.run([PY, "-c", WARM_UP], cwd=old, env=dict(os.environ, PYTHONPATH=str(old)), capture_output=True)
        cases = [("demo-sized: 8 min simulated, `--quick` (12 points, 3 folds)",
                  [str(tmp / "traj8"), "--quick"]),
                 ("real: warthog-drive-cmd, own train split (low-rate grid)", [str(DATA / "warthog-drive-cmd")])]
        if args.full:
            run(["simulate", str(tmp / "simfull"), "--seed", "0"], ROOT)
            run(["preprocess", str(tmp / "simfull"), "--out", str(tmp / "trajfull"), "--jobs", "1"], ROOT)
            cases.append((f"default campaign (45.4 min), full tracker grid (384 points, 5 folds), --jobs {args.jobs}",
                          [str(tmp / "trajfull"), "--jobs", str(args.jobs)]))
        rows, comparisons = [], []
        for label, case in cases:
            times = {}
            for name, tree in (("before", old), ("after", ROOT)):
                times[name] = run(["identify", *case, "--out", str(tmp / f"{name}.json")], tree)
                load.append(os.getloadavg()[0])
            rows.append((label, times))
            comparisons.append((label, compare(tmp / "before.json", tmp / "after.json")))
            if case[-2:] == ["--jobs", str(args.jobs)]:
                full_model = SindyModel.load(tmp / "after.json")
    lines = ["## identify's speed (issue 13, item 7), before and after", "",
             f"Command: `.venv/bin/python -m bench.bench_identify_speed{' --full' if args.full else ''}"
             f"{'' if args.base == BASE else ' --base ' + args.base}` "
             f"(Python {platform.python_version()}, {os.cpu_count()} cores shared with other jobs; load average "
             f"(1 min) {', '.join(f'{v:.1f}' for v in load)} at the start and after each run). Before: "
             f"`{args.base}`; after: this checkout. Each run is `python -m sindy_ekf.cli identify` in a "
             "subprocess, one at a time, numba's compilation done beforehand.", "",
             "| case | before wall s | before CPU s | after wall s | after CPU s | speed-up (CPU) |",
             "|---|---:|---:|---:|---:|---:|"]
    for label, t in rows:
        lines.append(f"| {label} | {t['before'][0]:.1f} | {t['before'][1]:.1f} | {t['after'][0]:.1f} | "
                     f"{t['after'][1]:.1f} | {t['before'][1] / t['after'][1]:.1f}x |")
    lines += ["", "The models before and after:", ""]
    for label, c in comparisons:
        lines.append(f"- {label}: selected **{c['selected'][0]}** / **{c['selected'][1]}**; hyperparameters "
                     f"identical: **{'yes' if c['same_hp'] else 'NO'}**; active terms identical: "
                     f"**{'yes' if c['same_terms'] else 'NO'}** ({c['n_terms']} terms); largest relative "
                     f"coefficient difference {c['coef_rel']:.1e}; dead times and input lags within "
                     f"{1e3 * c['chain_s']:.2g} ms")
        worst = max(abs(b - a) / a for _, a, b, _ in c["cv"] if np.isfinite(a) and a > 0)
        lines.append(f"  - candidates' CV 5 s errors: largest relative difference {worst:.1e}; checks passed "
                     f"alike: {'yes' if all(s for *_, s in c['cv']) else 'NO'} "
                     f"({', '.join(f'{lab}: {a:.4f}/{b:.4f} m' for lab, a, b, _ in c['cv'])})")
    if args.full:
        lines.append(f"- default campaign: selected {full_model.training['selected']}, "
                     f"{full_model.complexity} terms, hyperparameters {full_model.hyperparameters}")
    if not args.no_write:
        publish(ROOT / "bench" / "results" / "identify_speed.md", lines)
    else:
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
