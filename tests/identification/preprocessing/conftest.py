"""The survey of ``simulation/data/calibration.yaml``, parsed and raw, for the calibration tests."""

from __future__ import annotations

import pytest
import yaml

from identification.preprocessing.io_survey import read_survey
from tests.support.survey_tables import SURVEY_YAML


@pytest.fixture(scope="session")
def survey():
    return read_survey(SURVEY_YAML)


@pytest.fixture(scope="session")
def raw():
    return yaml.safe_load(SURVEY_YAML.read_text())
