"""Estimation stage: the estimators under degraded GNSS on the test runs (:mod:`sindy_ekf.benchmark`).

Which estimators run: those the filter settings enable (:mod:`sindy_ekf.config`; by default all
of :data:`sindy_ekf.benchmark.run.ESTIMATORS`), without ``oracle_ekf`` on a measured campaign (it runs the simulator's true dynamics, which only a
simulated campaign has). Q and the lag model come from the train runs' states at the model's
own smoothing ``s``. ``sindy-ekf benchmark`` prints and writes the result; the report's chain
keeps it for its section.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from groundfloor.parallel import Workers
from groundfloor.types import TrajectoryCampaign
from identification.preprocessing.campaigns import open_campaign, train_campaign_of
from identification.sindy.checks import require_checks_passed
from identification.sindy.model import SindyModel
from simulation.truth import true_dynamics_of
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.benchmark.run import ESTIMATORS, benchmark_campaign
from sindy_ekf.config import FilterConfig, OutageSchedule, load_config

__all__ = ["ORACLE_EKF", "OutageSchedule", "estimators_for", "estimation_stage", "benchmark_files"]

ORACLE_EKF = "oracle_ekf"


def estimators_for(estimators: Sequence[str] | None, oracle: Dynamics | None, campaign: str | Path,
                   enabled: Sequence[str] = ESTIMATORS) -> tuple[str, ...]:
    """Return the estimators to run: ``estimators``, or by default those of ``enabled`` (the
    configuration's) that the campaign allows.

    Raises
    ------
    InputError
        ``oracle_ekf`` asked for on a campaign without the simulator's truth (names ``campaign``).
    """
    if estimators is None:
        return tuple(n for n in enabled if n != ORACLE_EKF or oracle is not None)
    names = tuple(estimators)
    if ORACLE_EKF in names and oracle is None:
        raise InputError(f"{campaign}: oracle_ekf needs a simulated campaign (truth/truth.yaml)")
    return names


def estimation_stage(campaign: TrajectoryCampaign, model: SindyModel, oracle: Dynamics | None = None,
                     profile: str | None = None, seed: int | None = None, estimators: Sequence[str] | None = None,
                     campaign_path: str | Path | None = None, outages: OutageSchedule | None = None,
                     config: FilterConfig | None = None, workers: Workers | int = 1,
                     train_campaign: TrajectoryCampaign | None = None) -> BenchmarkResult:
    """Return the benchmark of the estimators on the test runs of ``campaign`` with the model.

    ``oracle`` (the simulator's true dynamics) runs as ``oracle_ekf``; ``estimators`` as in
    :func:`estimators_for`; ``campaign_path`` names the campaign in errors (default its root);
    ``outages`` when GNSS drops out. ``config``: the filter settings (default the shipped ones,
    :mod:`sindy_ekf.config`); ``profile``, ``seed``, ``estimators`` and ``outages`` win over it
    when given. ``workers``: where the smoothers' runs go (:mod:`groundfloor.parallel`).
    ``train_campaign``: whose train runs fit Q, the unicycle gains and the lag (default ``campaign``).
    """
    config = load_config() if config is None else config
    names = estimators_for(estimators, oracle, campaign.root if campaign_path is None else campaign_path,
                           config.enabled())
    s = model.hyperparameters.get("s")  # Q and the lag model from states at the model's own smoothing
    if outages is not None:
        config = config.with_overrides(outages=outages)
    return benchmark_campaign(campaign, model, profile=profile, seed=seed, oracle_dynamics=oracle, estimators=names,
                              smoothing=None if s is None else float(s), config=config, workers=workers,
                              train_campaign=train_campaign)


def benchmark_files(campaign: str | Path, model_path: str | Path, profile: str | None = None,
                    seed: int | None = None, estimators: Sequence[str] | None = None,
                    config: FilterConfig | None = None, workers: Workers | int = 1,
                    train: str | Path | None = None) -> BenchmarkResult:
    """Return the benchmark of the model file on a campaign (``sindy-ekf benchmark``).

    A tracker campaign is preprocessed first (cached); a simulated campaign's true dynamics
    (:func:`simulation.truth.true_dynamics_of`) run as ``oracle_ekf``. ``config``: the filter
    settings (:func:`sindy_ekf.config.load_config`); ``profile``, ``seed`` and ``estimators``
    (the command line's) win over it when given. ``workers``: where the smoothers' runs go.
    """
    model = SindyModel.load(model_path)
    require_checks_passed(model, str(model_path))
    traj = open_campaign(campaign)
    train_campaign = train_campaign_of(train)
    return estimation_stage(traj, model, true_dynamics_of(campaign), profile, seed, estimators, campaign,
                            config=config, workers=workers, train_campaign=train_campaign)
