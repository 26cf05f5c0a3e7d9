"""Identification stage: integral SINDy with the cross-validated grid search on the train runs.

Thesis 5.3.6: every grid point (spline smoothing ``s``, window ``tau``, ridge ``alpha``,
threshold ``T``, library) scored by 5 s prediction error in cross-validation by run, the
selected model refitted on all train runs. :func:`plan_identification` opens the campaign and
chooses the grid (``sindy-ekf identify`` prints it before the search starts);
:func:`identify` searches and returns the model with what the search found about it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from groundfloor.errors import InputError
from groundfloor.parallel import Workers
from groundfloor.types import TrajectoryRun
from identification.preprocessing.campaigns import open_campaign
from identification.sindy.adjust import Adjustment, adjust_coefficients
from identification.sindy.data import states_of_runs
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel
from identification.sindy.regression import integral_problem
from identification.sindy.search import SearchGrid, SearchResult, grid_for_runs, search


@dataclass(frozen=True)
class IdentificationPlan:
    """What to identify on: the train runs of a campaign and the grid to search."""

    campaign: str  # the campaign as given (a path)
    name: str  # the campaign's name
    train: tuple[TrajectoryRun, ...]
    grid: SearchGrid
    why: str  # why this grid (printed, and kept in the model's training facts)


@dataclass(frozen=True)
class Identification:
    """The grid search and the selected model, with its training facts (cross-validated errors, grid)."""

    plan: IdentificationPlan
    search: SearchResult
    model: SindyModel
    model_path: Path | None = None

    @property
    def best(self) -> dict:
        """The selected row of the search table."""
        return self.search.row(self.search.selected)

    def to_json(self) -> dict:
        """Return the ``identify --json`` summary."""
        m = self.model
        return {"model": str(self.model_path), "hyperparameters": m.hyperparameters, "library": m.library.name,
                "complexity": m.complexity, "equations": m.equations().splitlines(),
                "cv_pos_err_5s_m": self.best["pos_err_5s_m"], "cv_yaw_err_5s_deg": self.best["yaw_err_5s_deg"],
                "condition_number": m.training.get("condition_number"), "grid_size": self.plan.grid.size,
                "selected_rank": self.search.selected + 1, "ranking": self.search.ranking(14)}


def grid_overrides(library: Sequence[str] | None = None, smoothing: Sequence[float] | None = None,
                   tau: Sequence[float] | None = None, alpha: Sequence[float] | None = None,
                   threshold: Sequence[float] | None = None) -> dict:
    """Return the changes to a :class:`SearchGrid` asked for (values sorted, repeats dropped).

    Raises
    ------
    InputError
        An unknown library, a negative value, or a window ``tau`` that is not positive; the
        message names the option (``--tau``).
    """
    for name in library or ():
        make_library(name)  # an unknown library name fails now, not after the search
    changes = {"library": tuple(library)} if library else {}
    for opt, field, values in (("smoothing", "s", smoothing), ("tau", "tau", tau), ("alpha", "alpha", alpha),
                               ("threshold", "T", threshold)):
        if values is not None:
            bad = [v for v in values if not (v >= 0 if opt != "tau" else v > 0)]
            if bad:
                raise InputError(f"--{opt}: {bad[0]:g} is not a valid value "
                                 f"({'positive' if opt == 'tau' else 'non-negative'} numbers expected)")
            changes[field] = tuple(sorted(set(values)))
    return changes


def plan_identification(campaign: str | Path, quick: bool = False, kind: str = "auto",
                        overrides: dict | None = None) -> IdentificationPlan:
    """Return the train runs of ``campaign`` and the grid for them (:func:`grid_for_runs` with ``overrides``).

    Raises
    ------
    InputError
        Not a campaign, or no run marked ``train``.
    """
    traj = open_campaign(campaign)
    train = traj.split("train")
    if not train:
        raise InputError(f"{campaign}: campaign.yaml marks no run as train")
    grid, why = grid_for_runs(train, quick=quick, kind=kind)
    return IdentificationPlan(str(campaign), traj.name, tuple(train), dataclasses.replace(grid, **(overrides or {})),
                              why)


def identify(plan: IdentificationPlan, n_jobs: Workers | int = 1, out: str | Path | None = None) -> Identification:
    """Return the search of ``plan`` and its selected model, written to ``out`` when given.

    The model's training facts gain the cross-validated 5 s errors of the selected row, the
    grid's size and why it was chosen, the folds and the campaign.
    """
    result = search(runs=list(plan.train), grid=plan.grid, n_jobs=n_jobs)
    best = result.row(result.selected)
    model = dataclasses.replace(result.model, training={
        **result.model.training, "cv_pos_err_5s_m": best["pos_err_5s_m"], "cv_yaw_err_5s_deg": best["yaw_err_5s_deg"],
        "grid_size": plan.grid.size, "grid": plan.why, "folds": result.folds, "campaign": plan.campaign})
    path = model.to_json(out) if out is not None else None
    return Identification(plan, result, model, path)


def coefficient_adjustment(identification: Identification) -> Adjustment:
    """Return the least-squares adjustment of the selected model's active terms on the train runs
    (eq. 5.79, their correlations are fig. 7.12)."""
    model = identification.model
    segs, names, _ = states_of_runs(list(identification.plan.train), model.hyperparameters["s"])
    problem = integral_problem(segs, model.library, model.hyperparameters["tau"], names)
    return adjust_coefficients(model, problem)
