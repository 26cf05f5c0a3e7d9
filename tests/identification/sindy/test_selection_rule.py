"""The one-standard-error rule over cross-validation folds (selection.select_candidate), on
candidates whose fold errors are written by hand, and the error when none may be selected."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from identification.sindy.selection import Candidate, select_candidate


def _c(label, folds, complexity, passed=True, failed=()):
    folds = np.asarray(folds, float)
    return Candidate(label=label, hyperparameters=None, fold_rms_m=folds, fold_n=np.full(len(folds), 20),
                     fold_yaw_deg=np.full(len(folds), 2.0), complexity=complexity, passed=passed, failed=failed)


def test_the_sparsest_candidate_within_one_standard_error_of_the_best_is_taken():
    # by hand: "big" scores RMS(7, 9, 11, 9) = 9.11 cm, SE = std(ddof 1) / sqrt(4) = 1.633 / 2 = 0.816 cm,
    # so the limit is 9.93 cm: "small" at 9.8 cm lies within, "tiny" at 20 cm does not, "broken"
    # (the best error of all) fails its checks
    cands = [_c("big", [0.07, 0.09, 0.11, 0.09], 30), _c("small", [0.098, 0.098, 0.098, 0.098], 6),
             _c("tiny", [0.20, 0.20, 0.20, 0.20], 3), _c("broken", [0.01, 0.01, 0.01, 0.01], 2, False, ("held_input",))]
    assert cands[0].cv_pos_err_5s_m == pytest.approx(np.sqrt(0.0332 / 4), rel=1e-12)
    assert cands[0].cv_se_m == pytest.approx(np.sqrt(0.0008 / 3) / 2, rel=1e-12)
    assert select_candidate(cands) == 1
    # with "small" just beyond the limit, the best itself is taken
    cands[1] = _c("small", [0.1, 0.1, 0.1, 0.1], 6)
    assert select_candidate(cands) == 0


def test_no_admissible_candidate_is_an_error_naming_what_each_failed():
    cands = [_c("lag", [0.1, 0.1], 5, False, ("held_input",)),
             _c("grid rank 1", [0.1, np.inf], 20, True),
             _c("grid rank 2", [0.1, 0.1], 20, False, ("stable_at_rest", "dissipative"))]
    with pytest.raises(InputError, match=r"^identification: no candidate passed the well-posedness checks in most "
                                         r"folds \(lag: fails held_input; grid rank 1: diverged in 1 of 2 folds; "
                                         r"grid rank 2: fails stable_at_rest, dissipative\)$"):
        select_candidate(cands)
