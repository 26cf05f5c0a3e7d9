"""Run every bench script and assemble bench/RESULTS.md from bench/results/*.md.

Usage: ``.venv/bin/python -m bench.run_all [--assemble-only]`` from the checkout. Each ``bench/bench_*.py``
writes its own ``bench/results/<area>.md`` with the figures and the command that produced
them; this script runs them one after another (never in parallel: timings are for 2 cores), with
the modes of :data:`MODES` that write files of their own (the diagnosis's forms suite), and
concatenates the sections in pipeline order; then it writes the README's results table
from them (:mod:`bench.readme_table`).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from bench import readme_table

HERE = Path(__file__).resolve().parent
ORDER = ["simulate", "calibration", "preprocess", "poses", "identify", "identification", "identify_variants",
         "identify_variants_heldout", "identify_variants_default_length", "lodo_ceiling", "identify_speed",
         "identify_phases", "scaleout", "estimation", "sensors", "input_checks", "monte_carlo",
         "monte_carlo_variant", "ekf_speed", "ekf_speed_data", "real", "real_cli", "diagnose", "diagnose_kernels",
         "diagnose_forms", "diagnose_forms_120s", "diagnose_forms_heldout", "diagnose_forms_heldout_120s",
         "diagnose_forms_heldout_v21-30", "diagnose_forms_heldout_v21-30_120s", "diagnose_forms_heldout_v31-40",
         "diagnose_forms_heldout_v31-40_120s", "diagnose_ladder_120s",
         "inject_real", "real_clean", "new_ground", "effects_identified", "diagnose_notes", "demo"]


def assemble() -> Path:
    """Concatenate bench/results/*.md in pipeline order into bench/RESULTS.md; return its path."""
    parts = [(HERE / "RESULTS_HEADER.md").read_text()]
    found = sorted((HERE / "results").glob("*.md"), key=lambda p: (
        ORDER.index(p.stem) if p.stem in ORDER else len(ORDER), p.stem))
    for path in found:
        parts.append(path.read_text().strip() + "\n")
    out = HERE / "RESULTS.md"
    out.write_text("\n".join(parts))
    return out


# modes of a script that write results files of their own (run after the script's default run)
MODES = {"bench_diagnose": (["--forms"], ["--forms", "--run-s", "120"],
                            ["--ladder-only", "time_dependence", "--run-s", "120"])}


def main() -> int:
    if "--assemble-only" not in sys.argv:
        for script in sorted(HERE.glob("bench_*.py")):
            for args in ([],) + MODES.get(script.stem, ()):
                t0 = time.perf_counter()
                what = " ".join([script.name] + args)
                print(f"== {what}", flush=True)
                # as a module from the checkout: its sources, and tests.support for the builders
                rc = subprocess.call([sys.executable, "-m", f"bench.{script.stem}", *args], cwd=HERE.parent)
                print(f"== {what}: exit {rc} after {time.perf_counter() - t0:.1f} s", flush=True)
    print(assemble())
    return readme_table.main([])


if __name__ == "__main__":
    sys.exit(main())
