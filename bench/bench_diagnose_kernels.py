"""The diagnosis's two inner kernels, before and after, side by side in one run (issue 15, speed).

Usage: ``.venv/bin/python -m bench.bench_diagnose_kernels`` from the checkout; writes
``bench/results/diagnose_kernels.md`` (about six minutes on 2 cores).

``diagnose`` spends most of its time building the per-run normal equations of every candidate of
every family (``sindy_ekf.diagnose.design.normal_equations``) on window integrals
(``Split.integrate``); the floor patch alone has thousands of candidates. The kernels of the
package are timed here against the ones they replaced (:func:`normal_equations_masked`,
:func:`integrate_concatenated`, kept below as they were), each through a whole ``diagnose`` of the
same campaign with the same model, the two runs one after the other in this process. The
diagnoses must agree in every JSON value but the timings: the change is one of memory traffic,
not of arithmetic.

Campaigns: the shared real ``warthog-drive-wheels`` (lidar poses at 10 Hz) clean and with a
deadband of 0.1 hidden in its inputs (``inject``), the model identified on its clean train runs with
the hyperparameters of ``bench/results/real_cli.md``; and the default simulated campaign's smaller
sibling (4 minutes of driving) with its own identified model, a 50 Hz tracker campaign.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.publish import publish
from sindy_ekf.diagnose import columns, crossval, design, fitting
from sindy_ekf.diagnose.data import Split
from sindy_ekf.diagnose.design import Design

HERE = Path(__file__).resolve().parent
WHEELS = HERE.parent.parent / "shared" / "data" / "warthog-drive-wheels"
WHEELS_GRID = ["--smoothing", "20", "--tau", "1", "--alpha", "1", "--threshold", "0.25"]


def normal_equations_masked(y, X, weights, window_run, n_runs) -> Design:
    """The kernel as it was: each run's windows picked by a boolean mask (a copy of ``X`` per run),
    shared targets materialised once per candidate."""
    C, m = y.shape[0], X.shape[-1]
    wy = y * weights
    G, b, yy = np.zeros((C, n_runs, m, m)), np.zeros((C, n_runs, m)), np.zeros((C, n_runs))
    wX = X * weights[:, None] if m else X
    for r in range(n_runs):
        sel = window_run == r
        y_r, wy_r = y[:, sel].reshape(C, -1), wy[:, sel].reshape(C, -1)
        yy[:, r] = np.einsum("ck,ck->c", wy_r, y_r)
        if m:
            wX_r, X_r = wX[:, sel].reshape(C, -1, m), X[:, sel].reshape(C, -1, m)
            G[:, r] = np.swapaxes(wX_r, 1, 2) @ X_r
            b[:, r] = np.einsum("ckm,ck->cm", wX_r, y_r)
    return Design(G, b, yy)


def integrate_concatenated(self, values):
    """``Split.integrate`` as it was: the increments, their cumulative sum and a row of zeros concatenated."""
    inc = 0.5 * (values[..., :-1, :] + values[..., 1:, :]) * self.dt_next[:-1, None]
    cum = np.concatenate([np.zeros(values.shape[:-2] + (1, values.shape[-1])), np.cumsum(inc, axis=-2)], axis=-2)
    return cum[..., self.end, :] - cum[..., self.start, :]


@contextlib.contextmanager
def old_kernels():
    """Run the package with the replaced kernels (every module that imported the name by value)."""
    mods = (design, columns, crossval, fitting)
    saved = [m.normal_equations for m in mods], Split.integrate
    try:
        for m in mods:
            m.normal_equations = normal_equations_masked
        Split.integrate = integrate_concatenated
        yield
    finally:
        for m, f in zip(mods, saved[0]):
            m.normal_equations = f
        Split.integrate = saved[1]


def _without_timings(obj):
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if k not in ("seconds", "wall_s")}
    if isinstance(obj, list):
        return [_without_timings(v) for v in obj]
    return obj


def _diagnose(campaign: Path, model: Path) -> tuple[float, object]:
    from sindy_ekf.diagnose.pipeline import diagnose_campaign

    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        d = diagnose_campaign(campaign, model, ekf=False)
    return time.perf_counter() - t0, d


def cases(work: Path) -> list[tuple[str, Path, Path]]:
    """Return ``(label, campaign, model)`` of the module docstring, made in ``work``."""
    from identification.preprocessing.preprocess import preprocess_campaign
    from simulation.campaign import simulate_campaign
    from sindy_ekf import cli
    from sindy_ekf.diagnose.inject import inject_campaign

    quiet = contextlib.redirect_stdout(io.StringIO())
    with quiet:
        wheels_model = work / "wheels.json"
        assert cli.main(["identify", str(WHEELS), "--out", str(wheels_model), *WHEELS_GRID, "--quiet"]) == 0
        deadband = inject_campaign(WHEELS, work / "wheels-deadband", "deadband", 0.1)
        simulate_campaign(work / "sim-raw", seed=1, minutes=4.0)
        sim = work / "sim"
        preprocess_campaign(work / "sim-raw", sim)
        sim_model = work / "sim.json"
        assert cli.main(["identify", str(sim), "--out", str(sim_model), "--quick", "--quiet"]) == 0
    return [("real wheels, clean", WHEELS, wheels_model),
            ("real wheels, deadband 0.1 injected", deadband, wheels_model),
            ("simulated tracker campaign, 4 min (seed 1)", sim, sim_model)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "diagnose_kernels.md")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, campaign, model in cases(Path(tmp)):
            with old_kernels():
                t_old, d_old = _diagnose(campaign, model)
            t_new, d_new = _diagnose(campaign, model)
            same = json.dumps(_without_timings(d_old.to_json()), sort_keys=True, default=str) == \
                json.dumps(_without_timings(d_new.to_json()), sort_keys=True, default=str)
            rows.append(f"| {label} | {d_new.verdict} | {t_old:.1f} | {t_new:.1f} | {t_old / t_new:.2f}x | "
                        f"{'yes' if same else '**no**'} |")
            print(rows[-1], flush=True)
    lines = ["# The diagnosis's inner kernels, before and after (issue 15, speed)", "",
             "Command: `.venv/bin/python -m bench.bench_diagnose_kernels` (side by side in one run, 2 cores, "
             "`diagnose` without the EKF, one process). *Before*: each run's windows picked by boolean masks "
             "(a copy of every candidate's columns per run), targets shared by all candidates materialised per "
             "candidate, the window integrals through a concatenated cumulative sum (`bench/bench_diagnose_kernels.py` "
             "keeps them). *After*: a slice per run, shared targets summed once, the cumulative sum in place "
             "(`sindy_ekf/diagnose/design.py`, `sindy_ekf/diagnose/data.py`).", "",
             "| campaign | verdict | before [s] | after [s] | speed-up | same JSON (all but timings) |",
             "|---|---|---|---|---|---|", *rows]
    publish(args.out, lines)
    return 0 if all("**no**" not in r for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
