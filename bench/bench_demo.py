"""Time ``sindy-ekf demo`` (what ``make demo`` runs) and, optionally, ``make demo`` on a fresh clone.

Usage: ``.venv/bin/python -m bench.bench_demo [--fresh-clone] [--no-write] [--keep DIR]``.
Target (issue 8): the demo in at most 3 minutes on 2 cores. The demo runs as a subprocess of this
interpreter on the checkout's sources (``python -m sindy_ekf.cli``, the checkout first on
``PYTHONPATH``), so
its CPU time is the children's (``resource.getrusage``); the per-stage wall times come from its
``--json`` output. ``--fresh-clone`` also clones the repository into a temporary folder and
times ``make demo`` there (venv creation and ``pip install`` included, then the demo).
Writes ``bench/results/demo.md`` (unless ``--no-write``) with the figures and this command;
``--keep DIR`` keeps the demo's output (campaign and report) in ``DIR`` for the section
screenshots (``python -m bench.report_screenshots``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from identification.sindy.search import QUICK_GRID
from sindy_ekf.report.demo import DEMO_MINUTES

ROOT = Path(__file__).resolve().parents[1]

TARGET_S = 180.0


def timed(cmd: list[str], cwd: Path, env: dict | None = None) -> tuple[float, float, int, str]:
    """Return (wall s, children's CPU s, exit code, last lines of output) of a command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-25:])
    return wall, cpu, proc.returncode, tail


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fresh-clone", action="store_true", help="also time `make demo` in a fresh clone")
    parser.add_argument("--no-write", action="store_true", help="print only, do not write bench/results/demo.md")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="keep the demo's output (campaign and report) in DIR")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="bench-demo-"))
    out = args.keep.resolve() if args.keep is not None else work / "demo-out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    load0 = os.getloadavg()
    wall, cpu, rc, tail = timed([sys.executable, "-m", "sindy_ekf.cli", "demo", "--quiet", "--out", str(out),
                                 "--json", str(work / "demo.json")], cwd=work, env=env)
    load1 = os.getloadavg()
    info = json.loads((work / "demo.json").read_text()) if (work / "demo.json").is_file() else {}
    report = Path(info.get("report", out / "report" / "report.html"))
    size_mb = report.stat().st_size / 1e6 if report.is_file() else float("nan")
    lines = [
        "## Demo (issue 8): `sindy-ekf demo`, the whole chain to the HTML report",
        "",
        "Command: `.venv/bin/python -m bench.bench_demo" + (" --fresh-clone`" if args.fresh_clone else "`")
        + f" (Python {platform.python_version()}, {os.cpu_count()} cores shared with other jobs).",
        "",
        f"**`sindy-ekf demo`: {wall:.0f} s wall, {cpu:.0f} s CPU** (target {TARGET_S:.0f} s on 2 cores); exit {rc}; "
        f"load average {load0[0]:.1f} before, {load1[0]:.1f} after; report {size_mb:.1f} MB.",
        "",
        f"Simulated campaign of {DEMO_MINUTES:g} min, quick grid of {QUICK_GRID.size} points "
        f"({QUICK_GRID.n_folds}-fold cross-validation by run).",
        "",
    ]
    if info.get("seconds"):
        lines += ["| stage | wall s |", "|---|---:|"]
        lines += [f"| {k} | {v:.1f} |" for k, v in info["seconds"].items()]
        lines.append("")
    if info.get("pos_err_5s_m"):
        lines += ["| model (test runs) | pos. error 5 s cm | heading error 5 s deg |", "|---|---:|---:|"]
        lines += [f"| {k} | {100 * v:.2f} | {info['yaw_err_5s_deg'][k]:.2f} |" for k, v in info["pos_err_5s_m"].items()]
        lines.append("")
    est = (info.get("benchmark") or {}).get("estimators") or {}
    if est:
        lines += [f"Estimators on the test runs, GNSS profile `{info['benchmark'].get('profile')}`:", "",
                  "| estimator | ATE pos m | ATE yaw deg | error at end of outage m | NEES mean |", "|---|---:|---:|---|---:|"]
        for name, e in est.items():
            ends = ", ".join(f"{k} s: {v:.2f}" for k, v in (e.get("outage_pos_err_m") or {}).items() if v is not None)
            nees = e.get("nees_mean")
            lines.append(f"| {name} | {e['ate_pos_m']:.3f} | {e['ate_yaw_deg']:.2f} | {ends} | "
                         f"{'-' if nees is None else f'{nees:.1f}'} |")
        lines.append("")
    if info.get("diagnosis"):
        d = info["diagnosis"]
        lines.append(f"Diagnosis verdict on the effect-free demo campaign: `{d['verdict']}` "
                     f"(5 s position error {100 * d['pos_err_5s_m']['before']:.2f} -> "
                     f"{100 * d['pos_err_5s_m']['after']:.2f} cm).")
        lines.append("")
    for stage, why in (info.get("errors") or {}).items():
        lines.append(f"- stage `{stage}` failed in this run: {why}")
    if info.get("errors"):
        lines.append("")
    if args.fresh_clone:
        clone = work / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        if (ROOT.parent / "shared").is_dir() and not (clone.parent / "shared").exists():
            (clone.parent / "shared").symlink_to(ROOT.parent / "shared")
        c_wall, c_cpu, c_rc, c_tail = timed(["make", "demo"], cwd=clone)
        lines += [f"**`make demo` on a fresh clone: {c_wall:.0f} s wall, {c_cpu:.0f} s CPU** (venv, `pip install` of "
                  f"the pinned packages from the registry, then the demo); exit {c_rc}.", ""]
        if c_rc != 0:
            lines += ["```", c_tail, "```", ""]
    text = "\n".join(lines)
    print(text)
    if rc != 0:
        print(tail, file=sys.stderr)
    if not args.no_write:
        (ROOT / "bench" / "results" / "demo.md").write_text(text)
    shutil.rmtree(work, ignore_errors=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
