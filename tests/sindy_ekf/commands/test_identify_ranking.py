"""The ranking ``identify`` prints: a candidate that diverged in a held-out fold is said so."""

from __future__ import annotations

import numpy as np

from identification.sindy.selection import Candidate
from sindy_ekf.commands.identify import candidate_row


def _candidate(fold_rms_m, label="grid rank 13, stepwise"):
    n = len(fold_rms_m)
    return Candidate(label=label, hyperparameters=None, fold_rms_m=np.asarray(fold_rms_m, float),
                     fold_n=np.full(n, 10), fold_yaw_deg=np.full(n, 3.0), complexity=10.6, passed=True,
                     failed=("dissipative",))


def test_a_candidate_diverged_in_two_folds_says_so_instead_of_inf_and_nan():
    row = candidate_row(_candidate([0.05, np.inf, 0.07, np.inf, 0.06]), 24, "fails in a minority of folds: dissipative")
    assert "inf" not in row and "nan" not in row
    assert row[24:].split()[:4] == ["10.6", "diverged", "-", "-"]
    assert row.endswith("diverged in 2 of 5 folds; fails in a minority of folds: dissipative")


def test_a_candidate_whose_fold_error_is_astronomical_counts_as_diverged():
    # seen on the real cmd campaign: a stepwise candidate's CV error printed as an 85-digit number
    row = candidate_row(_candidate([0.7, 6e81, 0.8, 0.7]), 24, "")
    assert row[24:].split()[:2] == ["10.6", "diverged"] and row.endswith("diverged in 1 of 4 folds")


def test_a_finite_candidate_prints_its_cv_error_in_cm_with_its_standard_error():
    c = _candidate([0.05, 0.07, 0.06, 0.06])
    row = candidate_row(c, 24, "selected")
    # by hand: equal fold sizes, RMS of 5, 7, 6, 6 cm
    cells = row[24:].split()
    assert cells[0] == "10.6" and float(cells[1]) == round(np.sqrt((25 + 49 + 36 + 36) / 4), 2)
    assert float(cells[2]) == round(100 * c.cv_se_m, 2) and cells[3] == "3.00" and cells[4] == "selected"
    assert candidate_row(c, 24, "", "lag baseline").startswith("lag baseline ")
