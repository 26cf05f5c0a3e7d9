"""Every model, estimator and diagnosis family the report can show is explained in its glossary."""

from __future__ import annotations

import pytest

from sindy_ekf.benchmark.run import ESTIMATORS, OPTIONAL_ESTIMATORS
from sindy_ekf.diagnose.families import FAMILIES
from sindy_ekf.report.glossary import meaning, terms_html
from sindy_ekf.stages.evaluation import MODEL, ORACLE


@pytest.mark.parametrize("name", [*ESTIMATORS, *OPTIONAL_ESTIMATORS, *FAMILIES, "none", MODEL, ORACLE,
                                  "constant_velocity", "unicycle"])
def test_every_name_the_report_shows_is_explained(name):
    assert len(meaning(name)) > 20


def test_terms_are_listed_once_in_order_and_unknown_names_fail():
    text = terms_html(["NEES", "ATE", "NEES"])
    assert text.count("<dt>") == 2 and text.index("<dt>NEES") < text.index("<dt>ATE")
    with pytest.raises(KeyError, match="no explanation of 'warp_drive'"):
        terms_html(["warp_drive"])
