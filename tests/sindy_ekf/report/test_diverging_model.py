"""A model that diverges everywhere, through `diagnose` and `report` (a user's hand-edited model file).

The model is the simulator's own with one coefficient a million times too large (as in the
benchmark's health tests). Before, `diagnose` ended in numpy's "IndexError: index -1 is out of
bounds" (binning residuals of which none was finite), the report's estimation table showed a
diverged filter's scores, covering its first 0.04 s, like any other row, and its error-band figure
drew the two SINDy filters, neither of which had an estimate (numpy's "Mean of empty slice").
"""

from __future__ import annotations

import html
import re

import numpy as np
import pytest

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf.cli import main
from sindy_ekf.diagnose.residuals import binned_effect
from tests.support.trajectory_synth import write_mini_campaign


@pytest.fixture(scope="module")
def diverging(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("diverging")
    terms = RobotParams().terms()
    terms["omega"]["u2"] *= 1e6
    return write_mini_campaign(tmp / "mini"), model_from_terms(terms).to_json(tmp / "huge.json")


def test_diagnose_names_the_model_file_and_the_windows_and_writes_nothing(diverging, tmp_path, capsys):
    root, model = diverging
    out = tmp_path / "d.json"
    assert main(["diagnose", str(root), "--model", str(model), "--json", str(out), "--no-ekf", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"sindy-ekf diagnose: error: {model}: its 5 s prediction diverges")
    n = re.search(r"\((\d+) of (\d+)\)", err[0])
    assert n and n[1] == n[2] and int(n[1]) > 0
    assert not out.exists()


def test_binning_residuals_of_which_none_is_finite_gives_no_structure():
    b = binned_effect(np.full(50, np.nan), np.linspace(0.0, 1.0, 50), "vx", n_bins=6)
    assert b.eta2 == 0.0 and b.p_value == 1.0 and np.all(b.count == 0)


@pytest.mark.filterwarnings("error::RuntimeWarning")  # numpy's "Mean of empty slice" of a filter without estimate
def test_report_marks_the_diverged_filters_and_says_why_the_diagnosis_is_missing(diverging, tmp_path, caplog):
    root, model = diverging
    assert main(["report", str(root), "--model", str(model), "--out", str(tmp_path / "rep"), "--quiet"]) == 0
    # every figure drawn: the error bands of a filter that diverged at once show one that has estimates
    assert not [r.getMessage() for r in caplog.records if "figure" in r.getMessage() and "failed" in r.getMessage()]
    text = html.unescape((tmp_path / "rep" / "report.html").read_text())
    estimation = text[text.index('<section id="estimation"'):]
    estimation = estimation[:estimation.index("</section>")]
    rows = re.findall(r"<tr><td class=l>(\w+)</td>.*?</tr>", estimation)
    assert "sindy_ekf" in rows and "cv_ekf" in rows
    sindy_row = re.search(r"<tr><td class=l>sindy_ekf</td>(.*?)</tr>", estimation)[1]
    assert "<td>diverged at 0.0" in sindy_row  # the row says how it ended ...
    assert re.search(r"sindy_ekf diverged at 0\.0\d s: run_c sindy_ekf: .*non-finite.*its scores cover the time "
                     "before", estimation)  # ... and a note why
    cv_row = re.search(r"<tr><td class=l>cv_ekf</td>(.*?)</tr>", estimation)[1]
    assert "<td>ok" in cv_row
    diagnosis = text[text.index('<section id="diagnosis"'):]
    assert "its 5 s prediction diverges in every window of the test runs" in diagnosis[:diagnosis.index("</section>")]
