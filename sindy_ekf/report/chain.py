"""The whole chain on one campaign, stage by stage, for the report and the demo.

``open -> calibration -> synchronisation -> identification -> evaluation -> estimation ->
diagnosis``. Opening the campaign is the one step whose failure stops everything (bad input ends
as :class:`~groundfloor.errors.InputError`); a later stage that fails is logged and recorded in
:attr:`ChainResult.errors`, and the report says so in its section instead of losing the rest.
A tracker campaign is preprocessed once, into the cache of
:func:`identification.preprocessing.campaigns.preprocessed_dir`, so a later command reuses it.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from groundfloor.errors import InputError
from groundfloor.progress import progress
from groundfloor.types import BodyStates, TrajectoryCampaign

log = logging.getLogger(__name__)

STAGES = ("calibration", "synchronisation", "identification", "evaluation", "estimation", "diagnosis")
# The demo's and ``report --quick``'s grid: every hyperparameter of table 5.1 still varies, with
# 2 values of tau, 3 of alpha and 3 of T, cross-validated over 3 folds of runs.
QUICK = "quick"
# Estimators in quick mode: all but the fixed-lag iSAM2 smoother, the slowest by far and the one
# INTERFACES.md does not require.
QUICK_ESTIMATORS = ("dead_reckoning", "cv_ekf", "unicycle_ekf", "sindy_ekf", "oracle_ekf", "sindy_graph")


@dataclass
class ChainResult:
    """Everything the chain found on one campaign (fields stay None where a stage did not run)."""

    campaign_path: Path
    kind: str  # "tracker" or "trajectory"
    trajectory: TrajectoryCampaign
    preprocess: dict | None = None  # preprocess.json of a tracker campaign
    survey: object | None = None  # groundfloor.types.Survey
    calibration: object | None = None  # identification.preprocessing.calibration.Calibration
    showcase: tuple | None = None  # (RawRun, preprocess.RunResult) of the run shown in detail
    search: object | None = None  # identification.sindy.search.SearchResult
    model: object | None = None  # identification.sindy.model.SindyModel
    model_path: Path | None = None
    states: dict[str, list[BodyStates]] = field(default_factory=dict)  # split -> segments at model s
    evaluation: dict | None = None  # model name -> EvaluationResult (RK4)
    benchmark: object | None = None
    diagnosis: object | None = None
    errors: dict[str, str] = field(default_factory=dict)  # stage -> one-line reason it failed
    skipped: dict[str, str] = field(default_factory=dict)  # stage -> why it does not apply
    seconds: dict[str, float] = field(default_factory=dict)

    def headline(self) -> dict:
        """Return the key numbers: 5 s prediction errors, estimation errors, diagnosis verdict."""
        out: dict = {"campaign": str(self.campaign_path), "kind": self.kind,
                     "runs": {s: len(self.trajectory.split(s)) for s in ("train", "test")}}
        if self.model is not None:
            out["model"] = {"complexity": int(self.model.complexity),
                            "hyperparameters": dict(self.model.hyperparameters)}
        if self.evaluation:
            out["pos_err_5s_m"] = {n: r.pos_err_5s_m for n, r in self.evaluation.items()}
            out["yaw_err_5s_deg"] = {n: r.yaw_err_5s_deg for n, r in self.evaluation.items()}
        if self.benchmark is not None:
            out["benchmark"] = self.benchmark.to_json()
        if self.diagnosis is not None:
            d = self.diagnosis
            out["diagnosis"] = {"verdict": d.verdict, "pos_err_5s_m": {"before": d.before["pos_err_5s_m"],
                                                                       "after": d.after["pos_err_5s_m"]}}
        out["errors"] = dict(self.errors)
        out["seconds"] = {k: round(v, 2) for k, v in self.seconds.items()}
        return out


def open_chain(campaign: str | Path, need_train: bool = True) -> ChainResult:
    """Return the chain's start: the campaign opened as a trajectory campaign (preprocessed once).

    Raises
    ------
    InputError
        Not a campaign, unreadable, no run marked ``test``, or (``need_train``) none marked
        ``train``; the message names the campaign.
    """
    import json

    from identification.preprocessing.campaigns import campaign_kind, preprocessed_dir
    from identification.preprocessing.preprocess import REPORT_FILE
    from identification.preprocessing.trajectory import read_trajectory_campaign

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
    chain = ChainResult(campaign_path=root, kind=kind, trajectory=traj, preprocess=pre)
    chain.seconds["open"] = time.perf_counter() - tic
    return chain


def stage_calibration(chain: ChainResult) -> None:
    """Calibrate from the raw survey (thesis 5.1, 5.2.1): transform, body frame, lever arms."""
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey

    chain.survey = read_survey(chain.campaign_path / "calibration.yaml")
    chain.calibration = calibrate(chain.survey)


def stage_synchronisation(chain: ChainResult) -> None:
    """Preprocess one test run again in memory, for its synchronisation figures (thesis 5.2.2).

    The cached trajectory campaign keeps only poses, inputs and the numbers of preprocess.json;
    the figures need the raw stamps and the synchronised run, so the first test run that
    preprocessing kept is read and synchronised once more (a second or two).
    """
    from identification.preprocessing.io_tracker import read_tracker_run
    from identification.preprocessing.preprocess import (
        DEFAULT_SMOOTHING,
        preprocess_run,
    )

    if chain.calibration is None:
        stage_calibration(chain)
    run = chain.trajectory.split("test")[0]
    smoothing = (chain.preprocess or {}).get("smoothing", DEFAULT_SMOOTHING)
    raw = read_tracker_run(chain.campaign_path / "runs" / run.name, run.name, run.split)
    chain.showcase = (raw, preprocess_run(raw, chain.calibration, smoothing))


def stage_identification(chain: ChainResult, model: str | Path | None = None, grid=None,
                         out_dir: Path | None = None, n_jobs: int = 1) -> None:
    """Load ``model``, or identify one on the train runs with the grid search (thesis 5.3.6).

    ``grid`` is a :class:`identification.sindy.search.SearchGrid`, ``"quick"`` for the search's
    ``QUICK_GRID``, or None for the full grid. An identified model is written to
    ``out_dir/model.json``.
    """
    from identification.sindy.model import SindyModel
    from identification.sindy.search import DEFAULT_GRID, QUICK_GRID, search

    if model is not None:
        chain.model, chain.model_path = SindyModel.load(model), Path(model)
        return
    grid = QUICK_GRID if grid == QUICK else (DEFAULT_GRID if grid is None else grid)
    result = search(runs=chain.trajectory.split("train"), grid=grid, n_jobs=n_jobs)
    best = result.ranking(1)[0]
    result.model.training.update({"cv_pos_err_5s_m": best["pos_err_5s_m"], "grid_size": grid.size,
                                  "folds": result.folds, "campaign": str(chain.campaign_path)})
    chain.search, chain.model = result, result.model
    if out_dir is not None:
        chain.model_path = result.model.to_json(Path(out_dir) / "model.json")


def true_dynamics_of(campaign_dir: Path):
    """Return the simulator's true dynamics (``simulation.robot.TrueDynamics``) of a simulated
    campaign, with its effect, else None (real campaigns have no ``truth/``)."""
    if not (Path(campaign_dir) / "truth" / "truth.yaml").is_file():
        return None
    from simulation.effects import Effect
    from simulation.robot import TrueDynamics
    from simulation.truth import read_truth

    truth = read_truth(campaign_dir, states=False)
    return TrueDynamics(effect=Effect(*truth.effects[0]) if truth.effects else None)


def oracle_for(campaign_dir: Path):
    """Return the simulator's true dynamics as a model for the evaluation, else None.

    Only the dynamics are used (the best any model can do); input-side effects (delay,
    deadband, ...) are not applied to the recorded inputs.
    """
    return true_dynamics_of(campaign_dir)


def stage_evaluation(chain: ChainResult) -> None:
    """Score the model, the baselines and (simulated campaigns) the oracle on the test runs (5.3.8)."""
    from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel
    from identification.sindy.evaluate import evaluate_on_runs
    from identification.sindy.data import states_of_runs

    s = float(chain.model.hyperparameters.get("s") or 0.0)
    for split in ("train", "test"):
        chain.states[split] = states_of_runs(chain.trajectory.split(split), s)[0]
    models = {"sindy": chain.model, "constant_velocity": ConstantVelocityModel()}
    if chain.states["train"]:
        models["unicycle"] = UnicycleModel().fit(chain.states["train"])
    oracle = oracle_for(chain.campaign_path)
    if oracle is not None:
        models["oracle"] = oracle
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # envelope warnings: the evaluate command's business
        res = evaluate_on_runs(models, chain.trajectory.split("test"), s)
    chain.evaluation = {name: r["rk4"] for name, r in res.items()}


def stage_estimation(chain: ChainResult, profile: str = "dgnss", estimators=None) -> None:
    """Benchmark the estimators under degraded GNSS with outages (:mod:`sindy_ekf.benchmark.run`).

    On a simulated campaign the simulator's true dynamics run as ``oracle_ekf`` beside them.
    ``estimators`` defaults to all of ``sindy_ekf.benchmark.run.ESTIMATORS``.
    """
    try:
        from sindy_ekf.benchmark import run as benchmark
    except ImportError:
        chain.skipped["estimation"] = "sindy_ekf.benchmark.run is not part of this installation yet"
        return
    s = chain.model.hyperparameters.get("s")
    chain.benchmark = benchmark.benchmark_campaign(
        chain.trajectory, chain.model, profile=profile, oracle_dynamics=true_dynamics_of(chain.campaign_path),
        smoothing=None if s is None else float(s), **({} if estimators is None else {"estimators": estimators}))


def stage_diagnosis(chain: ChainResult) -> None:
    """Diagnose what the model gets wrong (:mod:`sindy_ekf.diagnose`, issue 7)."""
    from sindy_ekf.diagnose import diagnose_campaign

    if chain.model_path is None:
        chain.skipped["diagnosis"] = "the model was not written to a file"
        return
    chain.diagnosis = diagnose_campaign(chain.campaign_path, chain.model_path)


def run_chain(campaign: str | Path, out_dir: str | Path | None = None, model: str | Path | None = None,
              grid=QUICK, stages=STAGES, n_jobs: int = 1, estimators=None) -> ChainResult:
    """Return the chain run on ``campaign``: each stage of ``stages`` in order, failures recorded.

    Parameters
    ----------
    campaign : tracker or trajectory campaign folder.
    out_dir : where an identified model is written (``model.json``).
    model : a model file of ``identify``; without it one is identified on the train runs.
    grid : search grid for the identification (see :func:`stage_identification`).
    stages : the stages to run, a subset of :data:`STAGES`.
    estimators : the benchmark's estimators (default: :data:`QUICK_ESTIMATORS` with the quick
        grid, else all).

    Raises
    ------
    InputError
        When the campaign cannot be opened or lacks test (or, without ``model``, train) runs.
    """
    unknown = set(stages) - set(STAGES)
    if unknown:
        raise InputError(f"stages: unknown {sorted(unknown)}; choose from {list(STAGES)}")
    chain = open_chain(campaign, need_train=model is None)
    steps = {
        "calibration": lambda: stage_calibration(chain),
        "synchronisation": lambda: stage_synchronisation(chain),
        "identification": lambda: stage_identification(chain, model, grid, out_dir, n_jobs),
        "evaluation": lambda: stage_evaluation(chain),
        "estimation": lambda: stage_estimation(
            chain, estimators=estimators or (QUICK_ESTIMATORS if grid == QUICK else None)),
        "diagnosis": lambda: stage_diagnosis(chain),
    }
    needs_model = {"evaluation", "estimation", "diagnosis"}
    for name in STAGES:
        if name not in stages:
            chain.skipped[name] = "stage not requested"
    for name in progress([s for s in STAGES if s in stages], desc="chain"):
        if name in ("calibration", "synchronisation") and chain.kind != "tracker":
            chain.skipped[name] = "a trajectory campaign holds no raw tracker data"
            continue
        if name in needs_model and chain.model is None:
            chain.skipped[name] = "no model (identification did not run or failed)"
            continue
        tic = time.perf_counter()
        try:
            steps[name]()
        except Exception as exc:  # noqa: BLE001 - one stage failing must not lose the others
            log.warning("report: stage %s failed: %s: %s", name, type(exc).__name__, exc)
            log.debug("stage %s", name, exc_info=True)
            chain.errors[name] = f"{type(exc).__name__}: {exc}".splitlines()[0]
        chain.seconds[name] = time.perf_counter() - tic
    return chain
