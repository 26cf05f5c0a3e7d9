"""The demo: the whole chain on a built-in simulated campaign, ending in an HTML report.

Simulates a short campaign (:data:`DEMO_MINUTES` of driving in the 9 runs of thesis table 6.4
by default), preprocesses it, identifies a SINDy model with the quick grid, evaluates it against
the baselines and the simulator's true dynamics, benchmarks the estimators under the GNSS
outages of :data:`DEMO_OUTAGES`, diagnoses the model and writes ``OUT/report/report.html``. ``OUT`` itself is the simulated tracker campaign (with
``truth/``; readers ignore the ``report/`` folder beside ``runs/``), so every other command can be
pointed at it. A folder the demo wrote holds :data:`MARKER`, so a rerun may replace it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from groundfloor.errors import InputError
from groundfloor.parallel import Workers
from simulation.campaign import simulate_campaign
from simulation.truth import CampaignTruth
from sindy_ekf.report.html import Report, check_report_dir, render_report
from sindy_ekf.stages.chain import QUICK, run_chain
from sindy_ekf.stages.estimation import OutageSchedule

# 8 minutes give the three test runs 18, 18 and 81 s; the benchmark's own schedule (5, 10, 30,
# 60 s outages, 30 s apart) would fit a single 5 s outage into them, so the demo drops GNSS for
# 5 and 10 s in turn after 8 s and then every 5 s: 5 outages of 5 s and 3 of 10 s, enough for
# an RMS over outages and for the NEES figure to show the filters through several of them.
# Measured by bench/bench_demo.py within the 3-minute budget.
DEMO_MINUTES = 8.0
DEMO_OUTAGES = OutageSchedule(durations_s=(5.0, 10.0), warmup_s=8.0, recovery_s=5.0)
DEFAULT_OUT = Path("demo-out")
MARKER = ".sindy-ekf-demo"  # marks a folder the demo wrote, so a rerun may replace it
REPORT_DIR = "report"


def check_demo_dir(out: str | Path, force: bool) -> Path:
    """Return ``out`` if the demo may (re)write it, else raise InputError naming it.

    A missing or empty folder, one the demo wrote before (it holds the marker file) or any
    folder with ``force`` is fine; the parent must be writable.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: output exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (force or (out / MARKER).is_file()):
        raise InputError(f"{out}: output folder is not empty and not a demo folder (use --force to replace it)")
    check_report_dir(out.parent if out.parent != Path("") else Path("."))
    return out


@dataclass(frozen=True)
class DemoCampaign:
    """The demo's simulated campaign: where it is, its truth, and when the demo began."""

    path: Path
    truth: CampaignTruth
    started_s: float  # time.perf_counter() when the demo began
    simulate_s: float  # seconds to check the folder and simulate


@dataclass(frozen=True)
class Demo:
    """The demo's campaign and its report (whose chain's seconds include simulating and rendering)."""

    campaign: DemoCampaign
    report: Report
    wall_s: float

    def to_json(self) -> dict:
        """Return the ``demo --json`` content: the report's path, the simulation and the headline figures."""
        truth = self.campaign.truth
        return {"report": str(self.report.path), "seed": truth.seed, "minutes": truth.minutes,
                "effects": [{"name": n, "value": v} for n, v in truth.effects],
                "wall_s": self.wall_s, **self.report.chain.headline()}


def simulate_demo_campaign(out: str | Path = DEFAULT_OUT, seed: int = 0, minutes: float = DEMO_MINUTES,
                           effects: Sequence[str] = (), force: bool = False) -> DemoCampaign:
    """Return the demo's campaign simulated into ``out`` (replacing a folder the demo wrote before).

    ``effects`` are ``NAME=VALUE`` dynamics effects of :mod:`simulation.effects` for the simulator
    to hide.
    """
    tic = time.perf_counter()
    campaign = check_demo_dir(out, force)
    # the simulator writes the campaign atomically (a temporary sibling renamed into place)
    truth = simulate_campaign(campaign, seed=seed, minutes=minutes, effects=effects, force=True)
    (campaign / MARKER).write_text("written by sindy-ekf demo; rerunning the demo replaces this folder\n")
    return DemoCampaign(campaign, truth, tic, time.perf_counter() - tic)


def demo_report(campaign: DemoCampaign, workers: Workers | int = 1) -> Demo:
    """Return the demo's chain run on its campaign (quick grid, :data:`DEMO_OUTAGES`) with the report
    written beside the runs; ``workers``: where the chain's parallel tasks go (:mod:`groundfloor.parallel`)."""
    out = campaign.path / REPORT_DIR
    chain = run_chain(campaign.path, out, grid=QUICK, outages=DEMO_OUTAGES, n_jobs=workers)
    tic = time.perf_counter()
    path = render_report(chain, out)
    chain = dataclasses.replace(chain, seconds={"simulate": campaign.simulate_s, **chain.seconds,
                                                "render": time.perf_counter() - tic})
    return Demo(campaign, Report(path, chain), time.perf_counter() - campaign.started_s)
