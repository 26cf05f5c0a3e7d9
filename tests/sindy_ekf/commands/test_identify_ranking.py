"""The ranking ``identify`` prints: a candidate that diverged in a held-out fold is said so."""

from __future__ import annotations

import numpy as np

from identification.sindy.selection import Candidate
from sindy_ekf.commands.identify import candidate_row, refused_better_note


def _candidate(fold_rms_m, label="grid rank 13, stepwise", passed=True, failed=("dissipative",)):
    n = len(fold_rms_m)
    return Candidate(label=label, hyperparameters=None, fold_rms_m=np.asarray(fold_rms_m, float),
                     fold_n=np.full(n, 10), fold_yaw_deg=np.full(n, 3.0), complexity=10.6, passed=passed,
                     failed=failed)


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


def test_refused_candidates_that_predict_clearly_better_are_noted():
    # the tilted-floor demo's shape: the lag (23 cm) selected, every richer candidate refused
    lag = _candidate([0.20, 0.26, 0.23], "lag", True, ())
    rich = [_candidate([0.07, 0.08, 0.075], "grid rank 2", False, ("stable_at_rest", "held_input")),
            _candidate([0.10, 0.12, 0.11], "grid rank 1", False, ("dissipative",)),
            _candidate([0.21, 0.235, 0.225], "grid rank 4", False, ("held_input",))]  # better, within the lag's SE
    note = refused_better_note([lag, *rich], 0)
    assert note.startswith("note: 2 candidate(s) predict clearly better in cross-validation (best grid rank 2, "
                           f"{100 * rich[0].cv_pos_err_5s_m:.2f} cm against {100 * lag.cv_pos_err_5s_m:.2f} cm)")
    assert "(dissipative, held_input, stable_at_rest)" in note
    # a refused candidate only as good as the selected one within its standard error: no note
    assert refused_better_note([lag, rich[2]], 0) is None
    # nor when the better candidates passed (they would have been selected)
    assert refused_better_note([lag, _candidate([0.07, 0.08, 0.075], "grid rank 2", True, ())], 0) is None
