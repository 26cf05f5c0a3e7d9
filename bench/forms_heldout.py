"""The forms suite of ``bench_diagnose --forms`` on simulator variants 11 to 20, which no threshold was
calibrated on and no mechanism was designed on (issue 15, item 4).

Usage: ``.venv/bin/python -m bench.forms_heldout [--run-s S] [--variants A-B]`` from the checkout (about 2 min
on 2 cores for the default 45 s runs, 5 min for 120 s); writes ``bench/results/diagnose_forms_heldout.{md,json}``
(runs of other lengths: ``diagnose_forms_heldout_<S>s``; variants other than 11 to 20, a fresh draw held out
from a change designed after the suite of 11 to 20 was seen: ``diagnose_forms_heldout_v<A>-<B>[_<S>s]``).
``--summarise-only`` rewrites the table from the JSON.
Not a ``bench_*`` script: ``bench.run_all`` does not run it.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import bench.bench_diagnose as bd
from groundfloor.parallel import Workers

HELD_OUT = tuple(range(11, 21))
RESULTS = Path(__file__).resolve().parent / "results"


def out_path(run_s: float, variants: tuple[int, ...] = HELD_OUT) -> Path:
    """Return the results' path without suffix for runs of ``run_s`` on ``variants``."""
    other = "" if variants == HELD_OUT else f"_v{variants[0]}-{variants[-1]}"
    return RESULTS / bd.forms_stem(run_s).replace("diagnose_forms", "diagnose_forms_heldout" + other)


def variant_range(text: str) -> tuple[int, ...]:
    """Return the variants of ``A-B`` (both included, above 10: 1 to 10 are the development suite's)."""
    try:
        a, b = (int(v) for v in text.split("-"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--variants {text!r} is not A-B") from None
    if not 10 < a <= b:
        raise argparse.ArgumentTypeError(f"--variants {text!r}: need 10 < A <= B (1 to 10 are the development suite's)")
    return tuple(range(a, b + 1))


def lines(forms: dict) -> list[str]:
    """Return the forms suite's markdown with this script's command and variants."""
    run_s = float(forms.get("run_s", bd.RUN_S))
    variants = tuple(forms.get("variants", HELD_OUT))
    a, b = variants[0], variants[-1]
    flags = ((f" --run-s {run_s:g}" if run_s != bd.RUN_S else "")
             + (f" --variants {a}-{b}" if variants != HELD_OUT else ""))
    text = "\n".join(bd.forms_lines(forms["rows"], run_s))
    text = re.sub(r"`\.venv/bin/python -m bench\.bench_diagnose --jobs 2 --forms[^`]*` \(",
                  f"`.venv/bin/python -m bench.forms_heldout{flags}` ({forms['minutes']:.0f} min; ", text, count=1)
    return [text.replace("on simulator variants (issue 15, item 4)",
                         f"on held-out simulator variants {a} to {b} (issue 15, item 4)", 1)
            .replace("simulator variants 1 to 10", f"simulator variants {a} to {b}", 1)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-s", type=float, default=bd.RUN_S, metavar="S", help="length of every run (s)")
    ap.add_argument("--variants", type=variant_range, default=HELD_OUT, metavar="A-B",
                    help="simulator variants A to B (default 11-20)")
    ap.add_argument("--summarise-only", action="store_true", help="rewrite the table from the JSON")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    out = out_path(args.run_s, args.variants)
    if not args.summarise_only:
        from tests.support.diagnose_synth import fit_reference_with_lateral_law

        bd.VARIANTS = args.variants  # forms_jobs deals its campaigns round-robin over these
        import sindy_ekf.diagnose  # noqa: F401  # imported before the workers fork
        model = fit_reference_with_lateral_law(n_runs=4, run_s=bd.RUN_S, rate_hz=bd.RATE_HZ)
        t0 = time.perf_counter()
        rows = bd.run_jobs(bd.forms_jobs(run_s=args.run_s), model, Workers(2, None))
        out.with_suffix(".json").write_text(json.dumps(
            {"minutes": (time.perf_counter() - t0) / 60, "run_s": args.run_s, "variants": list(args.variants),
             "rows": rows}, indent=1))
    forms = json.loads(out.with_suffix(".json").read_text())
    out.with_suffix(".md").write_text("\n".join(lines(forms)) + "\n")
    print(out.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
