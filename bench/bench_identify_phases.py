"""Where ``identify``'s wall time goes on the default campaign, phase by phase (issue 13, item 7).

Usage: ``.venv/bin/python -m bench.bench_identify_phases [--jobs J]`` from the checkout; writes
``bench/results/identify_phases.md`` (about five minutes).

The default simulated campaign (seed 0, 45.4 min) is simulated and preprocessed (not timed), then
``sindy-ekf identify`` runs in this process with the full tracker grid, each phase of
:func:`identification.sindy.identify.identify` timed by wrapping the function that does it: the
screening (``search``), the candidate pass and the stepwise pass (``_fold_pass``, by its label) and
the final refit (``_final``). ``bench_identify_speed`` times the whole command before and after a
change; this says which phase a next change has to shorten.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from pathlib import Path

import identification.sindy.identify as ident
from bench.publish import publish
from sindy_ekf.cli import main as cli

HERE = Path(__file__).resolve().parent
PHASES = {"search": "screening (integral-regression grid, every point cross-validated)",
          "_fold_pass": None,  # labelled by its ``what`` argument
          "_final": "final refit on all train runs"}


def timed(record: dict):
    """Wrap the phase functions of :mod:`identification.sindy.identify` so that each call adds its wall time to ``record``."""
    for name in PHASES:
        fn = getattr(ident, name)

        @functools.wraps(fn)
        def wrapper(*args, _fn=fn, _name=name, **kwargs):
            t0 = time.perf_counter()
            try:
                return _fn(*args, **kwargs)
            finally:
                label = f"{args[4]} pass" if _name == "_fold_pass" else PHASES[_name]
                record[label] = record.get(label, 0.0) + time.perf_counter() - t0

        setattr(ident, name, wrapper)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=2)
    a = p.parse_args(argv)
    record: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="identify_phases_") as tmp:
        tmp = Path(tmp)
        for args in (["simulate", str(tmp / "sim"), "--seed", "0"],
                     ["preprocess", str(tmp / "sim"), "--out", str(tmp / "traj"), "--jobs", str(a.jobs)]):
            if cli([*args, "--quiet"]) != 0:
                raise SystemExit(f"{args[0]} failed")
        timed(record)
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        if cli(["identify", str(tmp / "traj"), "--jobs", str(a.jobs), "--out", str(tmp / "model.json"), "--quiet"]):
            raise SystemExit("identify failed")
        total = time.perf_counter() - t0
    lines = ["## identify's wall time by phase on the default campaign (issue 13, item 7)", "",
             f"Command: `.venv/bin/python -m bench.bench_identify_phases --jobs {a.jobs}` (default campaign, seed 0, "
             f"45.4 min, full tracker grid; {os.cpu_count()} cores shared with other jobs, load average {load:.1f} at "
             "the start). Each phase timed by wrapping the function of `identification.sindy.identify` that does it.",
             "", "| phase | wall s | share |", "|---|---:|---:|"]
    for label, s in record.items():
        lines.append(f"| {label} | {s:.1f} | {100 * s / total:.0f} % |")
    rest = total - sum(record.values())
    lines += [f"| the rest (reading, reference states, lag baseline, writing) | {rest:.1f} | {100 * rest / total:.0f} % |",
              f"| **identify in all** | **{total:.1f}** | |", "",
              "Target for the whole command: 120 s. The stepwise pass is one sequential search per fold and one on "
              "all train runs, three rounds on two workers (`docs/identification.md`, where identify's time goes)."]
    publish(HERE / "results" / "identify_phases.md", lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
