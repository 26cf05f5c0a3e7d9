"""The whole chain on one campaign, stage by stage, for the report and the demo.

``open -> calibration -> synchronisation -> identification -> evaluation -> estimation ->
diagnosis``. Opening the campaign is the one step whose failure stops everything (bad input ends
as :class:`~groundfloor.errors.InputError`); a later stage that fails is logged and recorded in
:attr:`ChainResult.errors`, and the report says so in its section instead of losing the rest.
A tracker campaign is preprocessed once, into the cache of
:func:`identification.preprocessing.campaigns.preprocessed_dir`, so a later command reuses it.
Each stage is the library function its command calls (:mod:`sindy_ekf.stages`).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from groundfloor.errors import InputError
from groundfloor.parallel import Workers
from groundfloor.progress import progress
from groundfloor.results import PredictionError
from groundfloor.types import BodyStates, Survey, TrajectoryCampaign
from identification.preprocessing.calibration import Calibration
from identification.preprocessing.campaigns import campaign_kind, preprocessed_dir, train_campaign_of
from identification.preprocessing.preprocess import DEFAULT_SMOOTHING, REPORT_FILE
from identification.preprocessing.trajectory import read_trajectory_campaign
from identification.sindy.data import states_of_runs
from identification.sindy.evaluate import EvaluationResult
from identification.sindy.model import SindyModel
from identification.sindy.search import SearchGrid, SearchResult, grid_for_runs
from simulation.truth import true_dynamics_of
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.config import FilterConfig, load_config
from sindy_ekf.diagnose import Diagnosis, diagnose_campaign
from sindy_ekf.stages.calibration import (
    Showcase,
    calibration_stage,
    synchronisation_stage,
)
from sindy_ekf.stages.estimation import ORACLE_EKF, OutageSchedule, estimation_stage
from sindy_ekf.stages.evaluation import (
    evaluation_stage,
    model_smoothing,
    prediction_error,
)
from sindy_ekf.stages.identification import IdentificationPlan, identify

log = logging.getLogger(__name__)

STAGES = ("calibration", "synchronisation", "identification", "evaluation", "estimation", "diagnosis")
# The demo's and ``report --quick``'s grid: every hyperparameter of table 5.1 still varies, with
# 2 values of tau, 3 of alpha and 3 of T, cross-validated over 3 folds of runs.
QUICK = "quick"
# Estimators in quick mode: all but the fixed-lag iSAM2 smoother, the slowest by far and the one
# INTERFACES.md does not require.
QUICK_ESTIMATORS = ("dead_reckoning", "cv_ekf", "unicycle_ekf", "lag_ekf", "sindy_ekf", "oracle_ekf", "sindy_graph")
NEEDS_MODEL = ("evaluation", "estimation", "diagnosis")


@dataclass(frozen=True)
class ChainResult:
    """Everything the chain found on one campaign (fields stay None where a stage did not run)."""

    campaign_path: Path
    kind: str  # "tracker" or "trajectory"
    trajectory: TrajectoryCampaign
    preprocess: dict | None = None  # preprocess.json of a tracker campaign
    survey: Survey | None = None
    calibration: Calibration | None = None
    showcase: Showcase | None = None  # the run shown in detail
    search: SearchResult | None = None
    model: SindyModel | None = None
    model_path: Path | None = None
    states: dict[str, list[BodyStates]] = field(default_factory=dict)  # split -> segments at model s
    evaluation: dict[str, EvaluationResult] | None = None  # model name -> RK4 evaluation
    benchmark: BenchmarkResult | None = None
    diagnosis: Diagnosis | None = None
    errors: dict[str, str] = field(default_factory=dict)  # stage -> one-line reason it failed
    skipped: dict[str, str] = field(default_factory=dict)  # stage -> why it does not apply
    seconds: dict[str, float] = field(default_factory=dict)

    def prediction_errors(self) -> dict[str, PredictionError]:
        """Return each evaluated model's 5 s errors on the test runs (empty without the evaluation)."""
        return {n: prediction_error(r) for n, r in (self.evaluation or {}).items()}

    def headline(self) -> dict:
        """Return the key numbers: 5 s prediction errors, estimation errors, diagnosis verdict."""
        out: dict = {"campaign": str(self.campaign_path), "kind": self.kind,
                     "runs": {s: len(self.trajectory.split(s)) for s in ("train", "test")}}
        if self.model is not None:
            out["model"] = {"complexity": int(self.model.complexity),
                            "hyperparameters": dict(self.model.hyperparameters)}
        errors = self.prediction_errors()
        if errors:
            out["pos_err_5s_m"] = {n: e.pos_err_5s_m for n, e in errors.items()}
            out["yaw_err_5s_deg"] = {n: e.yaw_err_5s_deg for n, e in errors.items()}
        if self.benchmark is not None:
            out["benchmark"] = self.benchmark.to_json()
        if self.diagnosis is not None:
            d = self.diagnosis
            out["diagnosis"] = {"verdict": d.verdict, "pos_err_5s_m": {"before": d.before.pos_err_5s_m,
                                                                       "after": d.after.pos_err_5s_m}}
        out["errors"] = dict(self.errors)
        out["seconds"] = {k: round(v, 2) for k, v in self.seconds.items()}
        return out


class StageSkipped(Exception):
    """A stage that does not apply to this chain (the message says why)."""


def open_chain(campaign: str | Path, need_train: bool = True) -> ChainResult:
    """Return the chain's start: the campaign opened as a trajectory campaign (preprocessed once).

    Raises
    ------
    InputError
        Not a campaign, unreadable, no run marked ``test``, or (``need_train``) none marked
        ``train``; the message names the campaign.
    """
    root = Path(campaign)
    tic = time.perf_counter()
    kind = campaign_kind(root)
    pre = None
    if kind == "tracker":
        cache = preprocessed_dir(root)
        traj = read_trajectory_campaign(cache)
        if (cache / REPORT_FILE).is_file():
            pre = json.loads((cache / REPORT_FILE).read_text())
    else:
        traj = read_trajectory_campaign(root)
    if not traj.split("test"):
        raise InputError(f"{root}: campaign.yaml marks no run as test (the report scores on test runs)")
    if need_train and not traj.split("train"):
        raise InputError(f"{root}: campaign.yaml marks no run as train (nothing to identify a model on)")
    return ChainResult(campaign_path=root, kind=kind, trajectory=traj, preprocess=pre,
                       seconds={"open": time.perf_counter() - tic})


def identification_plan(chain: ChainResult, grid: SearchGrid | str | None) -> IdentificationPlan:
    """Return the identification of the chain: its train runs and the grid (``"quick"`` or None:
    the quick or the full grid for the poses' rate, as ``sindy-ekf identify`` chooses it,
    :func:`~identification.sindy.search.grid_for_runs`; else the grid given).

    The tracker grid on 10 Hz poses (a real lidar or RTK campaign) smooths nothing and gave no
    finite prediction error on the shared Warthog campaigns: ``report`` failed where ``identify`` worked.
    """
    train = tuple(chain.trajectory.split("train"))
    if grid == QUICK or grid is None:
        grid, why = grid_for_runs(train, quick=grid == QUICK)
    else:
        why = "grid given to the chain"
    return IdentificationPlan(str(chain.campaign_path), chain.trajectory.name, train, grid, why)


def _stage_steps(chain: ChainResult, found: dict, model: str | Path | None, grid, out_dir: Path | None,
                 n_jobs: Workers | int, estimators: Sequence[str] | None,
                 outages: OutageSchedule | None, config: FilterConfig | None,
                 train_camp: TrajectoryCampaign | None = None) -> dict[str, Callable[[], dict]]:
    """Return each stage as a function of what the stages before it ``found``, returning its fields
    (``train_camp``: the campaign whose train runs the stages fit on, default the chain's own)."""
    traj, path = chain.trajectory, chain.campaign_path
    train_runs = None if train_camp is None else train_camp.split("train")

    def calibration() -> dict:
        sc = calibration_stage(path)
        return {"survey": sc.survey, "calibration": sc.calibration}

    def synchronisation() -> dict:
        fields = {} if found.get("calibration") is not None else calibration()
        smoothing = (chain.preprocess or {}).get("smoothing", DEFAULT_SMOOTHING)
        cal = fields.get("calibration", found.get("calibration"))
        return {**fields, "showcase": synchronisation_stage(path, traj, cal, smoothing)}

    def identification() -> dict:
        if model is not None:
            return {"model": SindyModel.load(model), "model_path": Path(model)}
        on = chain if train_camp is None else dataclasses.replace(chain, trajectory=train_camp)
        ident = identify(identification_plan(on, grid), n_jobs=n_jobs,
                         out=None if out_dir is None else Path(out_dir) / "model.json")
        return {"search": ident.search, "model": ident.model, "model_path": ident.model_path}

    def evaluation() -> dict:
        m = found["model"]
        found["states"] = {"test": states_of_runs(traj.split("test"), model_smoothing(m))[0]}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # envelope warnings: the evaluate command's business
            ev = evaluation_stage(traj, m, true_dynamics_of(path), train_runs=train_runs)
        return {"states": {"train": ev.train_states, **found["states"]},
                "evaluation": {name: r["rk4"] for name, r in ev.results.items()}}

    def estimation() -> dict:
        oracle = true_dynamics_of(path)
        cfg = load_config() if config is None else config
        quick = tuple(n for n in QUICK_ESTIMATORS if n in cfg.enabled())  # of those the settings enable
        wished = estimators or (quick if grid == QUICK else None)
        names = None if wished is None else tuple(n for n in wished if n != ORACLE_EKF or oracle is not None)
        return {"benchmark": estimation_stage(traj, found["model"], oracle, estimators=names, outages=outages,
                                              config=cfg, workers=n_jobs, train_campaign=train_camp)}

    def diagnosis() -> dict:
        if found.get("model_path") is None:
            raise StageSkipped("the model was not written to a file")
        return {"diagnosis": diagnose_campaign(path, found["model_path"], workers=n_jobs, train_runs=train_runs)}

    return {"calibration": calibration, "synchronisation": synchronisation, "identification": identification,
            "evaluation": evaluation, "estimation": estimation, "diagnosis": diagnosis}


def run_chain(campaign: str | Path, out_dir: str | Path | None = None, model: str | Path | None = None,
              grid=QUICK, stages=STAGES, n_jobs: Workers | int = 1, estimators=None,
              outages: OutageSchedule | None = None, config: FilterConfig | None = None,
              train: str | Path | None = None) -> ChainResult:
    """Return the chain run on ``campaign``: each stage of ``stages`` in order, failures recorded.

    Parameters
    ----------
    campaign : tracker or trajectory campaign folder.
    out_dir : where an identified model is written (``model.json``).
    model : a model file of ``identify``; without it one is identified on the train runs.
    grid : search grid for the identification (see :func:`identification_plan`).
    stages : the stages to run, a subset of :data:`STAGES`.
    n_jobs : where the parallel tasks of the stages go (grid points, smoother runs, diagnosis
        families): local processes, or :class:`groundfloor.parallel.Workers` with a Dask scheduler.
    estimators : the benchmark's estimators (default: those ``config`` enables, of them only
        :data:`QUICK_ESTIMATORS` with the quick grid; ``oracle_ekf`` only on a simulated campaign).
    outages : when the benchmark drops GNSS (default: ``config``'s, 5, 10, 30, 60 s in turn, 30 s apart).
    config : the benchmark's filter settings (:mod:`sindy_ekf.config`; default the shipped ones).
    train : a campaign whose train runs the stages fit on (identification, baselines, process
        noise, mechanisms) instead of ``campaign``'s own: for a campaign of test runs only.

    Raises
    ------
    InputError
        When the campaign cannot be opened or lacks test (or, without ``model``, train) runs.
    """
    unknown = set(stages) - set(STAGES)
    if unknown:
        raise InputError(f"stages: unknown {sorted(unknown)}; choose from {list(STAGES)}")
    train_camp = train_campaign_of(train)
    chain = open_chain(campaign, need_train=model is None and train_camp is None)
    found: dict = {}
    errors, skipped, seconds = {}, {}, dict(chain.seconds)
    steps = _stage_steps(chain, found, model, grid, out_dir, n_jobs, estimators, outages, config, train_camp)
    for name in STAGES:
        if name not in stages:
            skipped[name] = "stage not requested"
    for name in progress([s for s in STAGES if s in stages], desc="chain"):
        if name in ("calibration", "synchronisation") and chain.kind != "tracker":
            skipped[name] = "a trajectory campaign holds no raw tracker data"
            continue
        if name in NEEDS_MODEL and found.get("model") is None:
            skipped[name] = "no model (identification did not run or failed)"
            continue
        tic = time.perf_counter()
        try:
            found.update(steps[name]())
        except StageSkipped as why:
            skipped[name] = str(why)
        except Exception as exc:  # noqa: BLE001 - one stage failing must not lose the others
            log.warning("report: stage %s failed: %s: %s", name, type(exc).__name__, exc)
            log.debug("stage %s", name, exc_info=True)
            errors[name] = f"{type(exc).__name__}: {exc}".splitlines()[0]
        seconds[name] = time.perf_counter() - tic
    return dataclasses.replace(chain, **found, errors=errors, skipped=skipped, seconds=seconds)
