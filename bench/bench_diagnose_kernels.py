"""``diagnose`` before and after its kernels were made memory-lean, side by side in one run (issue 15, speed).

Usage: ``.venv/bin/python -m bench.bench_diagnose_kernels [--base REV]`` from the checkout; writes
``bench/results/diagnose_kernels.md`` (about eight minutes on 2 cores).

``diagnose`` spends most of its time building the per-run normal equations of every candidate of
every family on window integrals; the floor patch alone has a candidate every 0.4 m over the driven
area (about 33,000 on the real wheels campaign). The kernels were changed in memory traffic only:
each run's windows a slice instead of a boolean copy, targets shared by every candidate summed once,
the cumulative sum in place, only the (equation, column) pairs a mechanism fills integrated, the
patch's derivatives computed only where a Jacobian is asked for. "Before" is the checkout at
``--base`` (default :data:`BASE`, the commit before the change) exported into a temporary folder,
"after" this checkout; each runs ``python -m sindy_ekf.cli diagnose CAMPAIGN --model M --no-ekf
--json`` as a subprocess with its own sources, one after the other on the same files. The two JSON
files must agree in every value but the timings.

Campaigns: the shared real ``warthog-drive-wheels`` (lidar poses at 10 Hz) clean and with a deadband
of 0.1 hidden in its inputs (``inject``), the model identified on its clean train runs with the
hyperparameters of ``bench/results/real_cli.md``; and a 4-minute simulated tracker campaign (seed 1,
50 Hz) with its own model (``identify --quick``).
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

from bench.publish import publish
from bench.revisions import export_revision

ROOT = Path(__file__).resolve().parents[1]
WHEELS = ROOT.parent / "shared" / "data" / "warthog-drive-wheels"
WHEELS_GRID = ["--smoothing", "20", "--tau", "1", "--alpha", "1", "--threshold", "0.25"]
#: the commit before the kernels changed
BASE = "f5d3c68"
PY = sys.executable


def cli(args: list[str], tree: Path) -> float:
    """Return the wall time of ``python -m sindy_ekf.cli ARGS --quiet`` with ``tree``'s sources."""
    tic = time.perf_counter()
    proc = subprocess.run([PY, "-m", "sindy_ekf.cli", *args, "--quiet"], cwd=tree,
                          env=dict(os.environ, PYTHONPATH=str(tree)), capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(args)} in {tree} failed:\n{proc.stderr[-2000:]}")
    return time.perf_counter() - tic


def _without_timings(obj):
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if k != "seconds"}
    if isinstance(obj, list):
        return [_without_timings(v) for v in obj]
    return obj


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default=BASE, help=f"the 'before' revision (default {BASE})")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "diagnose_kernels.md")
    args = ap.parse_args(argv)
    rows, same_all = [], True
    with tempfile.TemporaryDirectory(prefix="diagnose_kernels_") as tmp:
        tmp = Path(tmp)
        old = export_revision(ROOT, args.base, tmp / "before")
        cli(["identify", str(WHEELS), "--out", str(tmp / "wheels.json"), *WHEELS_GRID], ROOT)
        cli(["inject", str(WHEELS), str(tmp / "wheels-deadband"), "--effect", "deadband=0.1"], ROOT)
        cli(["simulate", str(tmp / "sim-raw"), "--minutes", "4", "--seed", "1"], ROOT)
        cli(["preprocess", str(tmp / "sim-raw"), "--out", str(tmp / "sim")], ROOT)
        cli(["identify", str(tmp / "sim"), "--out", str(tmp / "sim.json"), "--quick"], ROOT)
        cases = [("real wheels, clean", WHEELS, tmp / "wheels.json"),
                 ("real wheels, deadband 0.1 injected", tmp / "wheels-deadband", tmp / "wheels.json"),
                 ("simulated tracker campaign, 4 min (seed 1)", tmp / "sim", tmp / "sim.json")]
        for i, (label, campaign, model) in enumerate(cases):
            walls, docs = [], []
            for tree, tag in ((old, "before"), (ROOT, "after")):
                js = tmp / f"{i}-{tag}.json"
                walls.append(cli(["diagnose", str(campaign), "--model", str(model), "--no-ekf", "--json", str(js)],
                                 tree))
                docs.append(json.loads(js.read_text()))
            same = _without_timings(docs[0]) == _without_timings(docs[1])
            same_all &= same
            rows.append(f"| {label} | {docs[1]['verdict']} | {walls[0]:.1f} | {walls[1]:.1f} | "
                        f"{walls[0] / walls[1]:.2f}x | {'yes' if same else '**no**'} |")
            print(rows[-1], flush=True)
    lines = ["# `diagnose` before and after its kernels were made memory-lean (issue 15, speed)", "",
             f"Command: `.venv/bin/python -m bench.bench_diagnose_kernels` (before: `{args.base}`, after: this "
             f"checkout; `sindy-ekf diagnose --no-ekf` in a subprocess each, one after the other, 2 cores, load "
             f"average {os.getloadavg()[0]:.1f} at the end). What changed: each run's windows a slice instead of a "
             "boolean copy, targets shared by every candidate summed once, the cumulative sum in place, only the "
             "(equation, column) pairs a mechanism fills integrated, the floor patches' columns only inside the box "
             "where a patch can be non-zero (`sindy_ekf/diagnose/design.py`, `data.py`, `columns.py`, `families.py`).", "",
             "| campaign | verdict | before [s] | after [s] | speed-up | same JSON (all but timings) |",
             "|---|---|---|---|---|---|", *rows]
    publish(args.out, lines)
    return 0 if same_all else 1


if __name__ == "__main__":
    raise SystemExit(main())
