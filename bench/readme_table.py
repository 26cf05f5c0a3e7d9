"""The README's results table and code facts, generated: never typed.

Usage: ``.venv/bin/python -m bench.readme_table [--check]`` from the checkout (``make bench``
runs it after the bench scripts). Each row of the table names the bench result it comes from
(``bench/results/<area>.md``, written by ``bench/bench_<area>.py`` with the command that
produced it) and reads its numbers out of that file; a file or pattern that no longer matches is
an error naming both, so a bench whose output changed cannot leave a stale number behind. The
thesis column quotes the thesis (fixed values, cited by table). The facts block (grid sizes, the
demo's campaign and outages) is read from the code. Both are written between their markers in
``README.md``; ``--check`` only compares and exits 1 when the README differs (the test suite
runs the same check).
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from identification.sindy.search import DEFAULT_GRID, QUICK_GRID
from simulation.gnss import PROFILES
from sindy_ekf.report.demo import DEMO_MINUTES, DEMO_OUTAGES

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
README = ROOT / "README.md"
BLOCKS = {  # name -> (begin marker, end marker) in README.md
    "results": ("<!-- results table: written by `python -m bench.readme_table` from bench/results/*.md -->",
                "<!-- end of results table -->"),
    "facts": ("<!-- facts: written by `python -m bench.readme_table` from the code -->", "<!-- end of facts -->"),
}


class ReadmeTableError(Exception):
    """A bench result that does not hold what a README row reads from it."""


@dataclass(frozen=True)
class Source:
    """One bench result file, read once."""

    name: str  # area, the file is bench/results/<name>.md
    text: str

    def find(self, pattern: str) -> re.Match:
        """Return the first match of ``pattern`` in the file, or raise naming file and pattern."""
        m = re.search(pattern, self.text, re.MULTILINE)
        if m is None:
            raise ReadmeTableError(f"bench/results/{self.name}.md: no match for {pattern!r} (rerun its bench "
                                   "script or update bench/readme_table.py)")
        return m

    def number(self, pattern: str, group: int = 1) -> float:
        """Return the number captured by ``pattern``."""
        return float(self.find(pattern).group(group))

    def table(self, header_start: str) -> list[list[str]]:
        """Return the body rows (cells stripped) of the markdown table whose header starts with ``header_start``."""
        m = self.find(r"^\| ?" + re.escape(header_start) + r".*\n\|[-|: ]+\|\n((?:\|.*\n?)+)")
        return [[c.strip() for c in line.strip().strip("|").split("|")] for line in m.group(1).strip().splitlines()]

    def row(self, header_start: str, *first_cells: str) -> list[str]:
        """Return the row of that table whose first cells are ``first_cells``."""
        for cells in self.table(header_start):
            if cells[:len(first_cells)] == list(first_cells):
                return cells
        raise ReadmeTableError(f"bench/results/{self.name}.md: table '{header_start}' has no row {first_cells}")


def vector(cell: str) -> list[float]:
    """Return the numbers of a cell like ``[-3.03, -0.08, -1.03]``."""
    return [float(x) for x in re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", cell)]


def lead(cell: str) -> float:
    """Return the first number of a cell."""
    return vector(cell)[0]


@dataclass(frozen=True)
class Row:
    """One line of the README's table: what, from which result, how, and the thesis's value."""

    source: str
    quantity: Callable[[Source], str] | str
    package: Callable[[Source], str]
    thesis: Callable[[Source], str] | str  # quoted from the thesis (or "-"), or read where a result quotes it
    optional: bool = False  # left out when its pattern is absent (a result only some runs write)


def _filled(pattern: str, template: str) -> Callable[[Source], str]:
    """Return a row's reader: ``template`` filled with the named groups of ``pattern``'s first match."""
    def fill(r: Source) -> str:
        return template.format(**r.find(pattern).groupdict())

    return fill


def _transform(r: Source) -> str:
    cells = r.row("method", "Gauss-Helmert WLS, both trackers' sigmas (3 iterations)")
    s0 = r.find(r"variance factor s0\^2 = ([\d.]+) \(dof (\d+).*?the survey sigmas are about ([\d.]+) times (\w+)")
    return (f"within {max(map(abs, vector(cells[1]))):.1f} um and {max(map(abs, vector(cells[2]))):.2f} arcsec "
            f"of table 7.2; s0^2 = {s0.group(1)} (dof {s0.group(2)}): the survey sigmas about {s0.group(3)} times "
            f"{s0.group(4)}")


def _levers(r: Source) -> str:
    rows = [r.row("prism", p) for p in ("front", "rear")]
    d = max(abs(x) for c in rows for x in vector(c[1]))
    ds = max(abs(a - b) for c in rows for a, b in zip(vector(c[2]), vector(c[3])))
    return f"within {d:.2f} um of table 7.1, standard deviations within {ds:.1f} um"


def _per_run(r: Source) -> list[list[str]]:
    return r.table("run | LTD800 drift err")


def _drift(r: Source) -> str:
    rows = _per_run(r)
    worst = max(max(abs(lead(c[1])), abs(lead(c[2]))) for c in rows)
    return f"error at most {worst:.3f} ppm per run ({len(rows)} runs)"


def _offset(r: Source) -> str:
    rows = _per_run(r)
    worst = max(abs(lead(c[3])) for c in rows)
    m = r.find(r"`--stress [\d,]+ --stress-minutes [\d.]+`: (\d+) runs;.*worst offset error ([\d.]+) us")
    return (f"error at most {worst:.1f} us per run on the default campaign; {m.group(2)} us worst over "
            f"{m.group(1)} runs of short campaigns (other seeds)")


def _baseline(r: Source) -> str:
    pairs = [vector(c[7]) for c in _per_run(r)]
    b, a = [p[0] for p in pairs], [p[1] for p in pairs]
    return f"{min(b):.2f}-{max(b):.2f} / {min(a):.2f}-{max(a):.2f} mm (simulated)"


_hub = _filled(r"hub radii \(eq\. 5\.25\), median over runs: r1 (?P<r1>[\d.]+) mm, r2 (?P<r2>[\d.]+) mm; "
               r"truth (?P<truth1>[\d.]+) / (?P<truth2>[\d.]+) mm",
               "{r1} / {r2} mm (median over runs; simulated truth {truth1} / {truth2} mm)")
_poses = _filled(r"pose position RMS \*\*(?P<pos>[\d.]+) mm\*\*.*yaw RMS \*\*(?P<yaw>[\d.]+) deg\*\*",
                 "{pos} mm position, {yaw} deg yaw (the noise floor)")
_preprocess_q = _filled(r"(?P<runs>\d+) runs, (?P<minutes>[\d.]+) min of triggers",
                        "preprocessing of the full default campaign ({minutes} min, {runs} runs)")


def _preprocess(r: Source) -> str:
    wall = r.number(r"\*\*Wall time: ([\d.]+) s\*\*")
    return f"{wall:g} s wall on 2 shared cores"


def _identify_q(r: Source) -> str:
    points, minutes = r.number(r"= \*\*(\d+) points\*\*"), r.number(r"Data: ([\d.]+) min")
    return (f"5 s position / heading error of the selected model on the test runs (full grid of {points:.0f} points "
            f"on a {minutes:g} min simulated campaign, one-SE selection)")


def _identify(r: Source) -> str:
    sindy = r.row("model", "SINDy (RK4)")
    uni = r.row("model", "unicycle")
    ratio = r.find(r"position \*\*([\d.]+)x\*\*, heading \*\*([\d.]+)x\*\*")
    wall = r.number(r"wall time: \*\*(\d+) s\*\*")
    return (f"{sindy[1]} cm / {sindy[2]} deg = {ratio.group(1)}x / {ratio.group(2)}x the simulator's true dynamics; "
            f"unicycle {lead(uni[1]):.1f} cm / {lead(uni[2]):.1f} deg; full grid {wall:.0f} s")


def _scaleout_q(r: Source) -> str:
    tasks = r.number(r"\*\*(\d+) tasks\*\*")
    return f"identify's grid search ({tasks:.0f} tasks) on 2 local processes / a 2-worker Dask LocalCluster"


def _scaleout(r: Source) -> str:
    header = "where the"
    loky = r.row(header, "jobs=2 (loky)")
    dask = r.row(header, "Dask LocalCluster, 2 workers")
    serial = r.row(header, "jobs=1")
    same = r.find(r"equal exactly\): \*\*(\w+)\*\*").group(1)
    load = r.find(r"load average \(1 min\) ([\d.]+)").group(1)
    return (f"{loky[2]} / {dask[2]} the one-process wall time ({serial[1]} s; workers started beforehand, load average {load} "
            f"on 2 shared cores); same model: {same}")


def _identify_thesis(r: Source) -> str:
    row = r.row("model", "thesis model B, real data (table 7.6, model 1)")
    return f"table 7.6, model 1: {row[1]} cm / {row[2]} deg"


_demo_q = _filled(r"campaign of (?P<minutes>[\d.]+) min, quick grid of (?P<points>\d+) points",
                  "same, demo campaign ({minutes} min, quick grid of {points} points)")


def _demo(r: Source) -> str:
    rows = {c[0]: c for c in r.table("model (test runs)")}
    return (f"{lead(rows['sindy'][1]):.1f} cm / {lead(rows['sindy'][2]):.1f} deg; unicycle "
            f"{lead(rows['unicycle'][1]):.1f} cm; true dynamics {lead(rows['oracle'][1]):.1f} cm")


def _batched(r: Source) -> str:
    m = r.find(r"batched RK4 \(dt [\d.]+ s\) \*\*([\d.]+) s\*\*, solve_ivp RK45 \(rtol [\de.-]+\) per window "
               r"\*\*([\d.]+) s\*\*: \*\*(\d+)x\*\*")
    diff = r.number(r"largest difference of the 5 s position error: ([\d.]+) mm")
    return f"{m.group(1)} s vs {float(m.group(2)):.0f} s ({m.group(3)}x), equal to {diff} mm"


def _estimation_q(r: Source) -> str:
    p = PROFILES[r.find(r"^# Estimation benchmark \((\w+)\)").group(1)]
    return (f"EKF under {p.name.upper()} ({p.std_m:g} m, {p.rate_hz:g} Hz), position error at the end of 10 s "
            "outages, default campaign, full-grid model")


def _estimation(r: Source) -> str:
    def cell(name: str, col: int) -> float:
        return lead(r.row("estimator", name)[col])

    ratio = r.number(r"sindy_ekf / oracle_ekf at the end of 10 s outages: ([\d.]+)")
    return (f"SINDy EKF {cell('sindy_ekf', 4):.3f} m = {ratio:.2f}x the true-dynamics EKF, "
            f"{cell('sindy_ekf', 4) / cell('unicycle_ekf', 4):.2f}x the unicycle EKF ({cell('unicycle_ekf', 4):.2f} m); "
            f"SINDy graph ATE {cell('sindy_graph', 1):.3f} m vs SINDy EKF {cell('sindy_ekf', 1):.3f} m; with "
            f"`v_y = 0`: {cell('sindy_ekf_lateral', 4):.3f} / {cell('sindy_graph_lateral', 4):.3f} m (EKF / graph)")


def _ekf_speed(r: Source) -> str:
    rows = [c for c in r.table("code") if c[1] == "sindy_ekf"]  # this tree first, then the baseline
    wall, cpu = lead(rows[0][3]), lead(rows[0][5])
    before = [c for c in rows[1:] if c[0].startswith("baseline")]
    return (f"{wall:.0f}x real time (wall), {cpu:.0f}x (CPU)"
            + (f"; {lead(before[0][5]):.0f}x (CPU) before the restructuring, side by side" if before else ""))


_diagnose_q = _filled(r"suite of \d+ campaigns \((?P<effect>\d+) with an effect.*?(?P<free>\d+) effect-free\)",
                      "diagnosis, randomised suite of {effect} simulated campaigns + {free} effect-free")


def _diagnose(r: Source) -> str:
    named = r.find(r"named correctly: (\d+)/(\d+)")
    false = r.find(r"false alarms on effect-free: (\d+)/(\d+)")
    lowered = r.find(r"lowered by the extension in (\d+)/(\d+)")
    took = r.number(r"took \*\*([\d.]+) s\*\*")
    return (f"{named.group(1)}/{named.group(2)} named correctly, {false.group(1)}/{false.group(2)} false alarms; "
            f"extension lowers the 5 s error in {lowered.group(1)}/{lowered.group(2)}; default-size campaign "
            f"diagnosed in {took:.0f} s")


def _diagnose_kernels(r: Source) -> str:
    rows = r.table("campaign")
    same = "yes" if all(c[5] == "yes" for c in rows) else "NO"
    return "; ".join(f"{c[0]} {c[2]} -> {c[3]} s" for c in rows) + f"; the same JSON: {same}"


def _diagnose_forms(r: Source) -> str:
    named = r.find(r"named correctly: (\d+)/(\d+)")
    false = r.find(r"false alarms on effect-free variant campaigns: (\d+)/(\d+)")
    return (f"{named.group(1)}/{named.group(2)} named correctly (target 90 %), {false.group(1)}/{false.group(2)} "
            "false alarms (target 10 %)")


def _variants(r: Source) -> str:
    m = r.find(r"median \*\*([\d.]+)x\*\* \(target <= ([\d.]+).*?worst \*\*([\d.]+)x\*\* \(target <= ([\d.]+)")
    floor = r.find(r"The true terms refitted on the same train runs: median \*\*([\d.]+)x\*\*, worst \*\*([\d.]+)x\*\*")
    return (f"median {m.group(1)}x (target {m.group(2)}x), worst {m.group(3)}x (target {m.group(4)}x) the true "
            f"dynamics; the true terms refitted on the same train runs: median {floor.group(1)}x, worst "
            f"{floor.group(2)}x")


def _identify_speed(r: Source) -> str:
    full = [c for c in r.table("case | before wall s") if c[0].startswith("default campaign")]
    if not full:
        raise ReadmeTableError(f"bench/results/{r.name}.md: no row of the full grid on the default campaign "
                               "(rerun bench/bench_identify_speed.py with --full)")
    c = full[0]
    base = r.find(r"Before: `(\w+)`").group(1)
    return f"{c[3]} s wall ({c[4]} s CPU); {c[1]} s ({c[2]} s CPU) at `{base}`; target 120 s"


def _leave_one_day_out(r: Source) -> str:
    parts = []
    for cells in r.table("campaign | train -> test"):
        parts.append(f"{cells[0].replace('warthog-drive-', '')} {cells[1].replace(' -> ', '->')}: {cells[6].split()[0]}")
    return "identified / lag: " + "; ".join(parts) + " (target 0.8x)"


def _inject_real(r: Source) -> str:
    parts = []
    for c in ("wheels", "cmd"):
        m = r.find(rf"### warthog-drive-{c}: \*\*(\d+) of (\d+) named correctly, (\d+) with the estimate within "
                   r"25 %\*\*; clean campaign: \*\*(\w+)\*\*")
        parts.append(f"{c}: {m.group(1)} of {m.group(2)} named, {m.group(3)} within 25 %, clean `{m.group(4)}`")
    return "; ".join(parts)


def _real_clean(r: Source) -> str:
    false = r.find(r"false alarms: (\d+)/(\d+) = \d+ %")
    guarded = r.find(r"top family above its own threshold but not named: (\d+)/(\d+)")
    return (f"{false.group(1)}/{false.group(2)} false alarms (target 10 %); in {guarded.group(1)} of "
            f"{guarded.group(2)} the top family was above its threshold and stopped by a guard (a lateral law "
            "the model lacks; a delay not told from zero)")


def _new_ground(r: Source) -> str:
    named = r.find(r"other grounds named \(verdict not none\): (\d+)/(\d+)")
    lowers = r.find(r"the extension lowers the 5 s error in (\d+)/(\d+)")
    false = r.find(r"false alarms on the base ground: (\d+)/(\d+)")
    return (f"{named.group(1)}/{named.group(2)} other grounds named, the extension better in {lowers.group(1)}/"
            f"{lowers.group(2)}; {false.group(1)}/{false.group(2)} false alarms on the model's own ground")


def _against_unicycle(r: Source, header: str) -> str:
    """Return the SINDy rows of a 5 s error table as ``cmd ... m = ...x (target ...x); wheels ...``: the
    position error in column 2, the ratio in the column headed ``x README unicycle``, the target after it."""
    k = [c.strip() for c in header.split("|")].index("x README unicycle")
    cmd = r.row(header, "warthog-drive-cmd", "sindy")
    whl = r.row(header, "warthog-drive-wheels", "sindy")
    target = [re.search(r"<= ([\d.]+)", c[k + 1]).group(1) for c in (cmd, whl)]
    return (f"cmd {cmd[2]} m = {cmd[k]}x (target {target[0]}x); wheels {whl[2]} m = {whl[k]}x "
            f"(target {target[1]}x)")


def _real(r: Source) -> str:
    return _against_unicycle(r, "campaign | model | pos 5 s [m] | yaw 5 s [deg] | windows | x README unicycle")


def _real_cli(r: Source) -> str:
    def row(campaign: str, name: str) -> list[str]:
        return r.row("campaign | estimator | ATE pos", f"warthog-drive-{campaign}", name)

    g = [row(c, "sindy_graph_lateral") for c in ("cmd", "wheels")]
    u = [row(c, "unicycle_ekf") for c in ("cmd", "wheels")]
    e = [row(c, "sindy_ekf") for c in ("cmd", "wheels")]
    return (f"SINDy graph with `v_y = 0` factors: ATE {g[0][2]} / {g[1][2]} m, {g[0][4]} / {g[1][4]} m at the end of "
            f"10 s outages; unicycle EKF {u[0][2]} / {u[1][2]} m and {u[0][4]} / {u[1][4]} m; plain SINDy EKF ATE "
            f"{e[0][2]} / {e[1][2]} m")


def _real_cli_evaluate(r: Source) -> str:
    return _against_unicycle(r, "campaign | model | pos 5 s [m] | yaw 5 s [deg] | x README unicycle")


def _real_cli_diagnosis(r: Source) -> str:
    parts = []
    for c in ("cmd", "wheels"):
        m = r.find(rf"`warthog-drive-{c}`: verdict \*\*(\w+)\*\*; 5 s position error ([\d.]+) -> ([\d.]+) m")
        parts.append(f"{c}: `{m.group(1)}`, 5 s error {m.group(2)} -> {m.group(3)} m")
    return "; ".join(parts)


def _real_diagnosis(r: Source) -> str:
    parts = []
    for c in ("cmd", "wheels"):
        row = r.row("campaign | verdict", f"warthog-drive-{c}")
        parts.append(f"{c}: `{row[1]}`, 5 s error {row[3]} m")
    return "; ".join(parts)


def _monte_carlo_q(r: Source) -> str:
    runs = r.number(r"(\d+) of \d+ Monte-Carlo runs done")
    return (f"Monte Carlo under GNSS faults ({runs:.0f} windows of outliers, multipath bursts, jumps, covariance "
            "10x small, outages up to 60 s): runs diverged; position error at the end of 30 / 60 s outages")


def _monte_carlo(r: Source) -> str:
    header = "estimator | fault mix | runs | diverged"
    ekf, graph = (r.row(header, name, "**all mixes**") for name in ("sindy_ekf", "sindy_graph"))
    out = [r.row("estimator | fault mix | outage s", "sindy_ekf", "outage", str(s)) for s in (30, 60)]
    return (f"SINDy EKF {ekf[3]} of {ekf[2]}, graph {graph[3]} of {graph[2]} (target 0); EKF median "
            f"{out[0][4]} / {out[1][4]} m")


_mutation = _filled(r"### seed (?P<seed>\d+) \(a fresh draw[^)]*\): \*\*(?P<killed>\d+) of (?P<n>\d+) mutants killed: "
                    r"(?P<share>\d+) %\*\*",
                    "{killed} of {n} killed, {share} % (fresh draw, seed {seed}; target 90 %)")


_lodo_ceiling = _filled(r"reaches (?P<target>[\d.]+)x the other day's lag in (?P<k>\d+) of (?P<n>\d+) directions "
                        r"\((?P<ratios>[^)]*)\)",
                        "{ratios} the other day's lag: {target}x reached in {k} of {n} directions even in sample")


_demo_wall = _filled(r"\*\*`sindy-ekf demo`: (?P<wall>\d+) s wall, (?P<cpu>\d+) s CPU\*\*.*?"
                     r"load average (?P<before>[\d.]+) before, (?P<after>[\d.]+) after",
                     "{wall} s wall, {cpu} s CPU (load average {before} before, {after} after, 2 cores)")
_fresh_clone = _filled(r"\*\*`make demo` on a fresh clone: (?P<wall>\d+) s wall, (?P<cpu>\d+) s CPU\*\*",
                       "{wall} s wall, {cpu} s CPU")


ROWS = (
    Row("calibration", "LTD800 -> AT960 transform from the raw survey (tables 6.1, 6.2)", _transform,
        "table 7.2 (Spatial Analyzer USMN)"),
    Row("calibration", "prism lever arms in the body frame (table 6.3)", _levers, "table 7.1"),
    Row("preprocess", "tracker clock drift, simulated default campaign", _drift,
        "table 7.3: drifts stable to about 0.1 ppm over the runs"),
    Row("preprocess", "additional AT960 offset, simulated", _offset, "table 7.4: 1.32 to 1.47 ms"),
    Row("preprocess", "baseline length RMS before / after the offset", _baseline,
        "table 7.4: 0.45-0.74 / 0.09-0.19 mm"),
    Row("preprocess", "turning-hub radii (eq. 5.25)", _hub, "table 7.5: 0.21 / 0.12 mm (mean over runs)"),
    Row("preprocess", "pose accuracy against truth (hub-axis correction on)", _poses, "not measurable on real data"),
    Row("preprocess", _preprocess_q, _preprocess, "-"),
    Row("identify", _identify_q, _identify, _identify_thesis),
    Row("demo", _demo_q, _demo, "-"),
    Row("scaleout", _scaleout_q, _scaleout, "-"),
    Row("identify", "batched 5 s evaluation vs one solve_ivp per window (thesis 5.3.7)", _batched, "-"),
    Row("estimation", _estimation_q, _estimation, "outlook only"),
    Row("ekf_speed", "SINDy EKF speed, default campaign (45 min, 9 runs in lockstep), full-grid model", _ekf_speed,
        "-"),
    Row("diagnose", _diagnose_q, _diagnose, "outlook only"),
    Row("diagnose_kernels", "`diagnose --no-ekf` wall time before -> after its memory-lean kernels (2 cores)",
        _diagnose_kernels, "-"),
    Row("diagnose_forms", "diagnosis, mechanism forms the families were not written from, on simulator variants "
        "1 to 10", _diagnose_forms, "-"),
    Row("diagnose_forms_120s", "the same on runs of 120 s instead of 45 s (a slow effect needs time to show)",
        _diagnose_forms, "-"),
    Row("diagnose_forms_heldout", "the same on held-out simulator variants 11 to 20 (no threshold calibrated, no "
        "mechanism designed on them)", _diagnose_forms, "-"),
    Row("diagnose_forms_heldout_120s", "held-out variants 11 to 20, runs of 120 s", _diagnose_forms, "-"),
    Row("diagnose_forms_heldout_v21-30", "variants 21 to 30, drawn after the changes designed on 11 to 20 (the "
        "lateral law's time scale was found on their lab models)", _diagnose_forms, "-"),
    Row("diagnose_forms_heldout_v21-30_120s", "held-out variants 21 to 30, runs of 120 s", _diagnose_forms, "-"),
    Row("diagnose_forms_heldout_v31-40", "variants 31 to 40, drawn after the lateral law's scoring by its lateral "
        "velocity was designed (on 11 to 20's hardening slips and 21 to 30's effect-free campaigns)",
        _diagnose_forms, "-"),
    Row("diagnose_forms_heldout_v31-40_120s", "held-out variants 31 to 40, runs of 120 s", _diagnose_forms, "-"),
    Row("identify_variants", "identification on simulator variants 1 to 10 (12-min campaigns through bags; "
        "`identify` then `evaluate`): 5 s position error of the selected model on the test runs", _variants, "-"),
    Row("identify_variants_heldout", "the same on simulator variants 11 to 20, which no identification choice "
        "was made on (held out)", _variants, "-"),
    Row("identify_variants_default_length", "the same at the default campaign length (45.4-min campaigns)",
        _variants, "-"),
    Row("identify_speed", "`identify`, full tracker grid (384 points, 5 folds, `--jobs 2`) on the default campaign "
        "(45.4 min): this checkout against an earlier commit, run after run", _identify_speed, "-"),
    Row("identification", "real Warthog data, leave one day out (train on one day, score on the other)",
        _leave_one_day_out, "-"),
    Row("lodo_ceiling", "real Warthog data, leave one day out: the better of the lag and `identify`'s model fitted "
        "on the test day itself (in sample, an optimistic bound), against the other day's lag", _lodo_ceiling, "-"),
    Row("inject_real", "diagnosis of effects hidden in real Warthog data (`inject`: delay, deadband, coupling, "
        "decay at 0.5, 1, 2 x moderate)", _inject_real, "-"),
    Row("real_clean", "diagnosis of clean real Warthog data split by day and by halves of every run (10 splits "
        "nothing was calibrated on; `identify` with its own search)", _real_clean, "-"),
    Row("new_ground", "diagnosis of a model taken to other grounds (turning resistance, track friction) of a "
        "two-track skid-steer generator of another construction (`bench/bench_new_ground.py`)", _new_ground, "-"),
    Row("real_cli", "real Warthog data, `sindy-ekf identify` on the train runs then `evaluate`: 5 s position error "
        "on the test runs, against the data README's unicycle", _real_cli_evaluate, "-"),
    Row("real", "real Warthog data, the integral-regression grid search alone (`examples/real_warthog.py`, no "
        "output-error refinement, no lag candidate): 5 s position error on the test runs, against the data "
        "README's unicycle", _real, "-"),
    Row("real_cli", "real Warthog data, estimators under DGNSS simulated from the ICP poses (cmd / wheels)",
        _real_cli, "-"),
    Row("real_cli", "real Warthog data, `sindy-ekf diagnose` of `identify`'s model (verdict, 5 s error before -> "
        "after the extension)", _real_cli_diagnosis, "-"),
    Row("real", "real Warthog data, diagnosis of the grid-search model (verdict, 5 s error before -> after)",
        _real_diagnosis, "-"),
    Row("monte_carlo", _monte_carlo_q, _monte_carlo, "outlook only"),
    Row("mutation", "tests against wrong changes: mutants of the numeric core killed (`bench/mutation.py`)",
        _mutation, "-"),
    Row("demo", "`sindy-ekf demo`, whole chain and report", _demo_wall, "-"),
    Row("demo", "`make demo` on a fresh clone (venv, pinned `pip install`, demo)", _fresh_clone, "-",
        optional=True),
)


def results_table(results_dir: Path = RESULTS) -> str:
    """Return the README's results table as markdown, every number read from ``results_dir``."""
    sources: dict[str, Source] = {}
    lines = ["| quantity | this package | thesis |", "|---|---|---|"]
    for row in ROWS:
        if row.source not in sources:
            path = results_dir / f"{row.source}.md"
            if not path.is_file():
                raise ReadmeTableError(f"{path}: missing (run python -m bench.bench_{row.source})")
            sources[row.source] = Source(row.source, path.read_text())
        src = sources[row.source]
        try:
            quantity = row.quantity(src) if callable(row.quantity) else row.quantity
            package = row.package(src)
        except ReadmeTableError:
            if row.optional:
                continue
            raise
        thesis = row.thesis(src) if callable(row.thesis) else row.thesis
        lines.append(f"| {quantity} | {package} | {thesis} |")
    return "\n".join(lines)


def facts() -> str:
    """Return the README's sentences on the code's own numbers: grid sizes, the demo's campaign and outages."""
    def shape(g) -> str:
        return " x ".join(f"{len(v)} {k}" for k, v in (("s", g.s), ("tau", g.tau), ("alpha", g.alpha), ("T", g.T))
                          if len(v) > 1)

    lengths = " and ".join(f"{d:g}" for d in DEMO_OUTAGES.durations_s)
    return (f"The demo simulates {DEMO_MINUTES:g} minutes of driving and searches the quick grid of "
            f"{QUICK_GRID.size} points ({shape(QUICK_GRID)}, {QUICK_GRID.n_folds}-fold cross-validation by run); "
            f"its benchmark drops GNSS for {lengths} s in turn, first {DEMO_OUTAGES.warmup_s:g} s after a test run "
            f"starts, with {DEMO_OUTAGES.recovery_s:g} s of GNSS between outages, so that its test runs hold several "
            f"outages of each length. `sindy-ekf identify` searches the full grid of {DEFAULT_GRID.size} points ({shape(DEFAULT_GRID)}, "
            f"{DEFAULT_GRID.n_folds}-fold), which takes minutes.")


def readme_with(text: str, blocks: dict[str, str]) -> str:
    """Return the README ``text`` with each block's content replaced between its markers."""
    for name, content in blocks.items():
        begin, end = BLOCKS[name]
        pattern = re.compile(re.escape(begin) + r"\n.*?\n" + re.escape(end), re.DOTALL)
        if not pattern.search(text):
            raise ReadmeTableError(f"README.md: markers of the {name} block missing ({begin} ... {end})")
        text = pattern.sub(lambda _: f"{begin}\n{content}\n{end}", text)
    return text


def expected_readme(readme: Path = README, results_dir: Path = RESULTS) -> str:
    """Return the README as the script would write it."""
    return readme_with(readme.read_text(), {"results": results_table(results_dir), "facts": facts()})


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        new = expected_readme()
    except ReadmeTableError as exc:
        print(f"readme_table: {exc}", file=sys.stderr)
        return 2
    if "--check" in argv:
        if new != README.read_text():
            print("readme_table: README.md differs from bench/results/*.md and the code "
                  "(run python -m bench.readme_table)", file=sys.stderr)
            return 1
        return 0
    README.write_text(new)
    print(f"README.md: results table and facts written from {RESULTS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
