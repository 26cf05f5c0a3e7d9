"""The real robot's own throttle-to-turn coupling, run by run (issue 15, items 3 and 4).

Usage: ``.venv/bin/python -m bench.own_coupling`` from the checkout (about 1 min); writes
``bench/results/own_coupling.md``. Not a ``bench_*`` script: ``bench.run_all`` does not run it.

An injected coupling (``sindy-ekf inject --effect asymmetry=A``: recorded steering minus A x throttle)
is fitted on the train runs and scored on the test runs. It can only stand out where the robot's own
coupling, relative to the model, is about the same on every run. Per shared Warthog campaign this
script identifies the model of ``bench.bench_inject_real`` on the clean train runs. It then scores the
coupling mechanism on each clean run alone, as the diagnosis scores it (the model kept fixed, its input
gains fitted on that run).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.bench_inject_real import SHARED, identify
from sindy_ekf.diagnose.families import mechanism_spec

OUT = Path(__file__).resolve().parent / "results" / "own_coupling.md"


def main() -> int:
    from tests.support.diagnose_synth import own_coupling_per_run

    bound = max(abs(b) for b in mechanism_spec("asymmetry", "throttle_to_turn_coupling").bounds[0])
    t0 = time.perf_counter()
    lines = ["## The real robot's own throttle-to-turn coupling, run by run (issue 15, items 3 and 4)", "",
             "Command: `.venv/bin/python -m bench.own_coupling` ({seconds} s). Model of "
             "`bench.bench_inject_real` identified on the clean train runs; the coupling mechanism "
             "(`u2 + c u1`) scored on each clean run alone, as the diagnosis scores it (model fixed, input "
             f"gains fitted on the run). The mechanism's bounds are +-{bound:g}: a value at the bound means "
             "at least that much.", ""]
    with tempfile.TemporaryDirectory(prefix="own_coupling_") as work:
        for name in ("wheels", "cmd"):
            rows = own_coupling_per_run(SHARED / f"warthog-drive-{name}", identify(name, Path(work)))
            train = np.array([c for _, split, c in rows if split == "train"])
            lines += [f"### warthog-drive-{name}: train runs {train.min():+.3f} to {train.max():+.3f} "
                      f"(SD {train.std(ddof=1):.3f})", "", "| run | split | own coupling c |", "|---|---|---|"]
            lines += [f"| {run} | {split} | {c:+.4f}{' (at the bound)' if abs(c) >= bound - 1e-9 else ''} |"
                      for run, split, c in rows]
            lines.append("")
    text = "\n".join(lines).replace("{seconds}", f"{time.perf_counter() - t0:.0f}") + "\n"
    OUT.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
