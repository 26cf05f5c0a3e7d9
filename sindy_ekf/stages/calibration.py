"""Calibration and synchronisation stages of a tracker campaign, for the report's figures.

The preprocessing (:mod:`identification.preprocessing`) already calibrated and synchronised
every run when it wrote the trajectory campaign; what it keeps are poses, inputs and the
numbers of ``preprocess.json``. The report shows the survey's adjustment and one run's
synchronisation in figures, which need the survey and the raw stamps: these stages compute
them once more (a second or two).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from groundfloor.types import RawRun, Survey, TrajectoryCampaign
from identification.preprocessing.calibration import Calibration, calibrate
from identification.preprocessing.io_survey import read_survey
from identification.preprocessing.io_tracker import read_tracker_run
from identification.preprocessing.preprocess import RunResult, preprocess_run


@dataclass(frozen=True)
class SurveyCalibration:
    """The raw survey of a tracker campaign and its calibration (thesis 5.1, 5.2.1)."""

    survey: Survey
    calibration: Calibration


@dataclass(frozen=True)
class Showcase:
    """One run read raw and preprocessed again in memory: the run the report shows in detail."""

    raw: RawRun
    run: RunResult


def calibration_stage(campaign_path: str | Path) -> SurveyCalibration:
    """Return the calibration from the raw survey (``calibration.yaml``): transform, body frame, lever arms."""
    survey = read_survey(Path(campaign_path) / "calibration.yaml")
    return SurveyCalibration(survey, calibrate(survey))


def synchronisation_stage(campaign_path: str | Path, campaign: TrajectoryCampaign, calibration: Calibration,
                          smoothing: float) -> Showcase:
    """Return the first test run that preprocessing kept, read and synchronised again (thesis 5.2.2).

    ``smoothing`` is the spline smoothing the campaign was preprocessed with.
    """
    run = campaign.split("test")[0]
    raw = read_tracker_run(Path(campaign_path) / "runs" / run.name, run.name, run.split)
    return Showcase(raw, preprocess_run(raw, calibration, smoothing))
