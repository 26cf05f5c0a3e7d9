"""The forms suite of ``bench_diagnose --forms`` on simulator variants 11 to 20, which no threshold was
calibrated on and no mechanism was designed on (issue 15, item 4).

Usage: ``.venv/bin/python -m bench.forms_heldout`` from the checkout (about 7 min on 2 cores); writes
``bench/results/diagnose_forms_heldout.{md,json}``. ``--summarise-only`` rewrites the table from the JSON.
Not a ``bench_*`` script: ``bench.run_all`` does not run it.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import bench.bench_diagnose as bd
from groundfloor.parallel import Workers

HELD_OUT = tuple(range(11, 21))
OUT = Path(__file__).resolve().parent / "results" / "diagnose_forms_heldout"


def lines(forms: dict) -> list[str]:
    """Return the forms suite's markdown with this script's command and variants."""
    text = "\n".join(bd.forms_lines(forms["rows"]))
    return [text.replace("on simulator variants (issue 15, item 4)",
                         "on held-out simulator variants 11 to 20 (issue 15, item 4)", 1)
            .replace("`.venv/bin/python -m bench.bench_diagnose --jobs 2 --forms` (",
                     f"`.venv/bin/python -m bench.forms_heldout` ({forms['minutes']:.0f} min; ", 1)
            .replace("simulator variants 1 to 10", "simulator variants 11 to 20", 1)]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--summarise-only" not in argv:
        from tests.support.diagnose_synth import fit_reference_with_lateral_law

        bd.VARIANTS = HELD_OUT  # forms_jobs deals its campaigns round-robin over these
        import sindy_ekf.diagnose  # noqa: F401  # imported before the workers fork
        model = fit_reference_with_lateral_law(n_runs=4, run_s=bd.RUN_S, rate_hz=bd.RATE_HZ)
        t0 = time.perf_counter()
        rows = bd.run_jobs(bd.forms_jobs(), model, Workers(2, None))
        OUT.with_suffix(".json").write_text(json.dumps({"minutes": (time.perf_counter() - t0) / 60, "rows": rows},
                                                       indent=1))
    forms = json.loads(OUT.with_suffix(".json").read_text())
    OUT.with_suffix(".md").write_text("\n".join(lines(forms)) + "\n")
    print(OUT.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
