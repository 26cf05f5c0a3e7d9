"""Identification stage: the pipeline of :mod:`identification.sindy.identify` on the train runs.

Thesis 5.3.6 and issue 13: the integral-regression grid (spline smoothing ``s``, window ``tau``,
ridge ``alpha``, threshold ``T``, library) screened on reference windows by grouped
cross-validation, its best distinct structures and the first-order lag refined by output error
and cross-validated again, the sparsest candidate passing the well-posedness checks within one
standard error selected and refitted on all train runs (never a model failing the checks).
:func:`plan_identification` opens the campaign and chooses the grid (``sindy-ekf identify``
prints it before the search starts); :func:`identify` runs the pipeline and returns the model
with what it found about it, including whether it beats the ``lag`` baseline.
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
from identification.sindy.identify import Identification as Pipeline
from identification.sindy.identify import identify as identify_runs
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel
from identification.sindy.regression import integral_problem
from identification.sindy.search import SearchGrid, SearchResult, grid_for_runs


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
    """The identification pipeline's selected model, with its screening, candidates and training facts."""

    plan: IdentificationPlan
    search: SearchResult  # the screening of the integral-regression grid
    model: SindyModel
    model_path: Path | None = None
    pipeline: Pipeline | None = None  # candidates, folds, the lag baseline and its CV score

    @property
    def best(self) -> dict:
        """The selected candidate's CV errors (``pos_err_5s_m``, ``yaw_err_5s_deg``, ``pos_err_5s_se_m``)."""
        if self.pipeline is None:
            row = self.search.row(self.search.selected)
            return {k: row[k] for k in ("pos_err_5s_m", "yaw_err_5s_deg", "pos_err_5s_se_m") if k in row}
        c = self.pipeline.candidates[self.pipeline.selected]
        return {"pos_err_5s_m": c.cv_pos_err_5s_m, "yaw_err_5s_deg": c.cv_yaw_err_5s_deg, "pos_err_5s_se_m": c.cv_se_m}

    @property
    def beats_lag(self) -> bool | None:
        """Return whether the selected model's CV error is below the lag baseline's (None without the pipeline)."""
        return None if self.pipeline is None else self.pipeline.beats_lag

    def to_json(self) -> dict:
        """Return the ``identify --json`` summary."""
        m = self.model
        out = {"model": str(self.model_path), "hyperparameters": m.hyperparameters, "library": m.library.name,
               "complexity": m.complexity, "equations": m.equations().splitlines(),
               "cv_pos_err_5s_m": self.best["pos_err_5s_m"], "cv_yaw_err_5s_deg": self.best["yaw_err_5s_deg"],
               "condition_number": m.training.get("condition_number"), "grid_size": self.plan.grid.size,
               "selected_rank": self.search.selected + 1, "ranking": self.search.ranking(14),
               "checks_passed": bool(m.checks.get("passed", False)), "dead_time_s": list(m.dead_time_s),
               "input_lag_s": list(m.input_lag_s)}
        if self.pipeline is not None:
            p = self.pipeline
            out |= {"cv_se_m": self.best["pos_err_5s_se_m"], "cv": m.training.get("cv"),
                    "selected": p.candidates[p.selected].label, "candidates": [c.summary() for c in p.candidates],
                    "lag": {"cv_pos_err_5s_m": p.lag_cv.cv_pos_err_5s_m, "cv_se_m": p.lag_cv.cv_se_m,
                            "cv_yaw_err_5s_deg": p.lag_cv.cv_yaw_err_5s_deg, **p.lag.to_dict()},
                    "beats_lag": p.beats_lag, "not_excited": list(p.not_excited), "notes": list(p.notes)}
        return out


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
    """Return the identification of ``plan`` and its selected model, written to ``out`` when given.

    The model's training facts gain the selected candidate's cross-validated 5 s errors, the
    grid's size and why it was chosen and the campaign.

    Raises
    ------
    InputError
        No candidate passes the well-posedness checks (nothing is written), or the train runs
        cannot be cross-validated (one run).
    """
    pipe = identify_runs(list(plan.train), grid=plan.grid, n_jobs=n_jobs)
    c = pipe.candidates[pipe.selected]
    model = dataclasses.replace(pipe.model, training={
        **pipe.model.training, "cv_pos_err_5s_m": c.cv_pos_err_5s_m, "cv_yaw_err_5s_deg": c.cv_yaw_err_5s_deg,
        "grid_size": plan.grid.size, "grid": plan.why, "folds": [list(h) for h in pipe.folds.held_out],
        "campaign": plan.campaign})
    path = model.to_json(out) if out is not None else None
    return Identification(plan, pipe.search, model, path, pipe)


def coefficient_adjustment(identification: Identification) -> Adjustment:
    """Return the least-squares adjustment of the selected model's active terms on the train runs
    (eq. 5.79, their correlations are fig. 7.12)."""
    model = identification.model
    segs, names, _ = states_of_runs(list(identification.plan.train), model.hyperparameters["s"])
    # the lag structure has no window of its own: the thesis's 1 s
    problem = integral_problem(segs, model.library, model.hyperparameters.get("tau", 1.0), names)
    return adjust_coefficients(model, problem)
