"""Effects hidden in the default simulator, diagnosed against a model ``identify`` selected (issue 15).

Usage: ``.venv/bin/python -m bench.bench_effects_identified [--jobs 2]`` from the checkout; writes
``bench/results/effects_identified.md`` (and ``.json``; about ten minutes).

``bench_diagnose`` diagnoses against lab models fitted in the bench (no cross-validation record), so
two parts of the verdict never run there: the question whether the model's own coefficients hold
(:mod:`sindy_ekf.diagnose.own_terms`, which needs the model file's cross-validation estimate) and the
warning of an extension that predicts the test runs worse (:mod:`sindy_ekf.diagnose.on_test`). Here the
path a user takes: ``simulate`` an effect-free campaign and ``identify --quick`` on it (the demo's
search, with its cross-validation record), then ``simulate`` one campaign per effect (another seed, the
family's default form and three other forms, each at its moderate value) and ``diagnose`` each against
that model through the command line. A family replaced by the model's own terms refitted is a miss
here: no campaign is another ground.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

from bench.publish import publish
from groundfloor.files import atomic_write_json

HERE = Path(__file__).resolve().parent
MINUTES, CLEAN_SEED, EFFECT_SEED = 8.0, 7, 8
EFFECTS = ("input_delay", "asymmetry", "deadband", "heading_dependence", "position_dependence", "time_dependence",
           "lateral_slip", "input_delay:motor_lag", "asymmetry:coupling", "deadband:soft")


def cli(*args: str) -> None:
    """Run one ``sindy-ekf`` command in this process, its terminal output swallowed; raise on a non-zero exit."""
    from sindy_ekf import cli as entry

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = entry.main([*args, "--quiet"])
    if code != 0:
        raise RuntimeError(f"sindy-ekf {' '.join(args)}: exit {code}")


def estimate_of(effect: str, doc: dict) -> tuple[float, float | None]:
    """Return the hidden effect's value and the named family's estimate of it (None where the family is not
    named or its estimate is not comparable: ``bench_diagnose.FORM_ESTIMATE``, the floor patch's damping)."""
    from bench.bench_diagnose import FORM_ESTIMATE
    from simulation.effects import parse_effect

    eff = parse_effect(effect)
    keys = FORM_ESTIMATE.get((eff.name, eff.form), "damping_fraction" if eff.form == "disc" else ())
    named = [c["estimate"] for c in doc["causes"] if c["name"] == eff.name and doc["verdict"] == eff.name]
    found = [named[0][k] for k in ((keys,) if isinstance(keys, str) else keys) if named and named[0].get(k) is not None]
    return eff.value, (float(found[0]) if found else None)


def row(effect: str, doc: dict, seconds: float) -> dict:
    """Return what the table shows of one ``diagnose --json`` document."""
    own = doc["cause_evidence"].get("own_terms") or {}
    ext = doc.get("extension_on_test") or {}
    first = doc["causes"][0]
    truth, estimate = estimate_of(effect, doc)
    return {"effect": effect, "family": effect.split(":")[0], "verdict": doc["verdict"],
            "truth": truth, "estimate": estimate,
            "instead_of": (doc["cause_evidence"].get("unexplained") or {}).get("instead_of"),
            "against_family": own.get("against_family"), "own_gain_5s": own.get("gain_5s"),
            "before_m": first["pos_err_5s_m"]["before"], "after_m": first["pos_err_5s_m"]["after"],
            "windows_better": ext.get("windows_better"), "n_windows": ext.get("n_windows"),
            "median_5s_m": ext.get("median_5s_m"), "warnings": doc["warnings"], "seconds": seconds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    jobs = ["--jobs", str(args.jobs)]
    t_start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="effects_identified_") as work:
        work = Path(work)
        cli("simulate", str(work / "clean_raw"), "--seed", str(CLEAN_SEED), "--minutes", str(MINUTES))
        cli("preprocess", str(work / "clean_raw"), "--out", str(work / "clean"), *jobs)
        cli("identify", str(work / "clean"), "--out", str(work / "model.json"), "--quick", *jobs)
        model = json.loads((work / "model.json").read_text())
        for effect in EFFECTS:
            name = effect.replace(":", "_")
            cli("simulate", str(work / f"{name}_raw"), "--seed", str(EFFECT_SEED), "--minutes", str(MINUTES),
                "--effect", effect)
            cli("preprocess", str(work / f"{name}_raw"), "--out", str(work / name), *jobs)
            t0 = time.perf_counter()
            cli("diagnose", str(work / name), "--model", str(work / "model.json"), "--json",
                str(work / f"{name}.json"), *jobs)
            rows.append(row(effect, json.loads((work / f"{name}.json").read_text()), time.perf_counter() - t0))
            print(f"{effect}: {rows[-1]['verdict']}", file=sys.stderr, flush=True)
    named = [r for r in rows if r["verdict"] == r["family"]]
    replaced = [r for r in rows if r["instead_of"]]
    asked = [r for r in rows if r["against_family"]]
    cv = model["training"].get("cv", {}).get("pos_err_5s_m")
    lines = ["## Effects hidden in the default simulator, against a model `identify` selected (issue 15)", "",
             f"Command: `.venv/bin/python -m bench.bench_effects_identified --jobs {args.jobs}` "
             f"({(time.perf_counter() - t_start) / 60:.0f} min; `bench/bench_effects_identified.py`). An effect-free "
             f"campaign of {MINUTES:g} min (seed {CLEAN_SEED}), `identify --quick` on it (selected: "
             f"{model['training'].get('selected')}, cross-validation "
             + (f"{100 * cv:.2f} cm at 5 s" if cv is not None else "none recorded")
             + f"); one campaign per effect at its moderate value (seed {EFFECT_SEED}, the default form unless "
             "named), `diagnose` through the command line. The model carries its cross-validation record, so "
             "the own-terms question is asked wherever a family is named (none of these campaigns is another "
             "ground: a family it replaces is a miss).", "",
             f"- **named correctly: {len(named)}/{len(rows)}**",
             f"- own terms asked against a named family: {len(asked)}; the family replaced: {len(replaced)}"
             + (" (" + ", ".join(r["effect"] for r in replaced) + ")" if replaced else ""), "",
             "| effect | verdict | estimate (hidden) | named family against the own terms refitted: test 5 s RMS cm "
             "(paired t of the log error ratio, refit better above 2) | own terms: 5 s gain | "
             "5 s error before -> after, cm | windows better | median before -> after, cm | warning |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        vs = r["against_family"]
        vs = "-" if not vs else (f"{100 * vs['test_rms_5s_m'][0]:.2f} / {100 * vs['test_rms_5s_m'][1]:.2f} "
                                 f"(t {vs['t_refit_better']:+.1f})")
        gain = "-" if r["own_gain_5s"] is None else f"{100 * r['own_gain_5s']:.0f} %"
        med = "-" if not r["median_5s_m"] else f"{100 * r['median_5s_m'][0]:.2f} -> {100 * r['median_5s_m'][1]:.2f}"
        better = "-" if r["n_windows"] is None else f"{r['windows_better']} / {r['n_windows']}"
        warn = "; ".join(r["warnings"]) or "-"
        est = "-" if r["estimate"] is None else f"{r['estimate']:.4g} ({r['truth']:g})"
        lines.append(f"| {r['effect']} | {r['verdict']} | {est} | {vs} | {gain} | {100 * r['before_m']:.2f} -> "
                     f"{100 * r['after_m']:.2f} | {better} | {med} | {warn} |")
    atomic_write_json(HERE / "results" / "effects_identified.json", {"model_cv_m": cv, "rows": rows})
    publish(HERE / "results" / "effects_identified.md", lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
