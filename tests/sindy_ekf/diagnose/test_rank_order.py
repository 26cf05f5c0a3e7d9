"""The diagnosis ranking in order (issue 14, item 5; issue 15, item 6): significant families first, by
strength (out-of-sample gain in units of the threshold of the scoring that judged it), then the others
by strength; the verdict is the first significant one or ``none``."""

from __future__ import annotations

import dataclasses

import numpy as np

from sindy_ekf.diagnose.fitting import FamilyScore
from sindy_ekf.diagnose.rank import drop_unresolved, rank_families, verdict

THRESHOLDS = {"input_delay": 0.02, "heading_dependence": 0.5, "position_dependence": 0.05,
              "time_dependence": 0.1, "asymmetry": 0.02, "deadband": 0.02, "lateral_slip": 0.01}


def _score(family, gain, **estimate):
    return FamilyScore(family, np.zeros(1), np.zeros(1), gain, {}, gain, estimate)


def test_significant_families_come_first_by_strength_then_the_rest_by_strength():
    scores = [_score("deadband", 0.01), _score("input_delay", 0.05), _score("heading_dependence", 0.30),
              _score("asymmetry", 0.20), _score("time_dependence", 0.50), _score("position_dependence", 0.04)]
    ranked = rank_families(scores, THRESHOLDS)
    # by hand, gain / threshold: significant asymmetry 0.2 / 0.02 = 10, time_dependence 0.5 / 0.1 = 5,
    # input_delay 0.05 / 0.02 = 2.5; then position_dependence 0.04 / 0.05 = 0.8, heading_dependence
    # 0.3 / 0.5 = 0.6, deadband 0.01 / 0.02 = 0.5. The strength decides, not the raw gain (time_dependence's
    # 0.5 would beat asymmetry's 0.2)
    assert [c.name for c in ranked] == ["asymmetry", "time_dependence", "input_delay",
                                        "position_dependence", "heading_dependence", "deadband"]
    assert [c.significant for c in ranked] == [True, True, True, False, False, False]
    assert verdict(ranked) == "asymmetry"


def test_ranking_does_not_depend_on_the_order_of_the_scores():
    scores = [_score("asymmetry", 0.03), _score("input_delay", 0.07), _score("deadband", 0.5)]
    a = [c.name for c in rank_families(scores, THRESHOLDS)]
    b = [c.name for c in rank_families(scores[::-1], THRESHOLDS)]
    assert a == b == ["deadband", "input_delay", "asymmetry"]


def test_no_significant_family_is_none_even_with_a_large_gain_below_its_threshold():
    scores = [_score("heading_dependence", 0.45), _score("input_delay", 0.01)]
    ranked = rank_families(scores, THRESHOLDS)
    assert [c.name for c in ranked] == ["heading_dependence", "input_delay"]
    assert verdict(ranked) == "none"
    assert verdict([]) == "none"


def test_lateral_slip_without_a_lateral_law_is_reported_but_never_named():
    scores = [_score("lateral_slip", 0.9, model_has_lateral_law=False, drift_s=0.02), _score("input_delay", 0.03)]
    ranked = rank_families(scores, THRESHOLDS)
    assert [c.name for c in ranked] == ["input_delay", "lateral_slip"]
    assert verdict(ranked) == "input_delay" and "no lateral law" in ranked[1].note


def test_thresholds_are_twice_the_recorded_calibration_maxima():
    """The significance thresholds come from the calibration recorded in bench/results (raw numbers
    of ``bench.bench_diagnose --calibrate-families``): a changed constant would no longer match them."""
    import json

    from sindy_ekf.diagnose.rank import NULL_MAX_GAIN, THRESHOLDS
    from tests.support import REPO

    recorded = json.loads((REPO / "bench" / "results" / "diagnose_raw.json").read_text())["family_calibration"]
    assert NULL_MAX_GAIN == recorded["max"]
    assert len(recorded["rows"]) == 46 and {r["kind"] for r in recorded["rows"]} == {
        "real", "short simulated", "short simulator variant"}
    # by hand from the recorded maxima: 2 x, at least 0.01
    assert THRESHOLDS["fixed"]["time_dependence"] == 2 * recorded["max"]["fixed"]["time_dependence"]
    assert THRESHOLDS["refit"]["input_delay"] == 0.01 and THRESHOLDS["refit"]["deadband"] == 0.01
    assert THRESHOLDS["fixed"]["asymmetry"] == 2 * recorded["max"]["fixed"]["asymmetry"]


def test_strength_is_the_gain_in_units_of_the_familys_threshold():
    # by hand with the thresholds above: 0.05 / 0.02, 0.3 / 0.5, 0.02 / 0.02; above 1 exactly for
    # the significant families (gain over its threshold)
    scores = [_score("input_delay", 0.05), _score("heading_dependence", 0.30), _score("deadband", 0.02)]
    by_name = {c.name: c for c in rank_families(scores, THRESHOLDS)}
    assert by_name["input_delay"].strength == 2.5
    assert by_name["heading_dependence"].strength == 0.6
    assert by_name["deadband"].strength == 1.0 and not by_name["deadband"].significant  # on it: not beyond
    assert all((c.strength > 1.0) == c.significant for c in by_name.values())


def test_a_family_is_significant_by_either_scoring_against_its_own_threshold():
    refit = FamilyScore("time_dependence", np.array([0.3]), np.zeros(0), 0.025, {}, float("nan"),
                        {"decay_per_10min": 0.3, "scored_with": "refit"})
    fixed = FamilyScore("time_dependence", np.array([-0.07]), np.zeros(0), 0.11, {}, 0.11,
                        {"decay_per_10min": -0.07}, alternative=refit)
    thresholds = {"fixed": {**THRESHOLDS, "time_dependence": 0.2}, "refit": {**THRESHOLDS, "time_dependence": 0.02}}
    assert rank_families([fixed], THRESHOLDS)[0].score is fixed  # one threshold for both: the larger gain
    (c,) = rank_families([fixed], thresholds)
    assert c.significant and c.score is refit and c.gain == 0.025 and c.threshold == 0.02
    thresholds["refit"]["time_dependence"] = 0.03  # 0.83 x its threshold, the fixed scoring 0.55 x
    (c,) = rank_families([fixed], thresholds)
    assert not c.significant and c.score is refit and c.threshold == 0.03


def test_a_5s_scoring_and_a_window_scoring_are_compared_in_units_of_their_own_thresholds():
    """The lateral law judged by its 5 s prediction (a drop of squared 5 s errors, 0.6 over its threshold
    0.3: strength 2) against an asymmetry judged by its window gain (0.1 over 0.02: strength 5): by
    hand, the asymmetry first; with the asymmetry at 0.03 (strength 1.5) the lateral law first, though
    its window gain (0.02) is the smaller."""
    fixed = FamilyScore("lateral_slip", np.zeros(0), np.zeros(2), 0.02, {}, 0.02, {"model_has_lateral_law": True},
                        by_scoring={"fixed": 0.02, "multistep": 0.6})
    lateral = FamilyScore("lateral_slip", np.zeros(0), np.zeros(2), 0.6, {}, 0.02,
                          {"model_has_lateral_law": True, "scored_with": "multistep"}, by_scoring=fixed.by_scoring,
                          alternative=fixed)
    thresholds = {"fixed": {**THRESHOLDS, "lateral_slip": 0.08}, "refit": {**THRESHOLDS, "lateral_slip": 0.08},
                  "multistep": {"lateral_slip": 0.3}}
    ranked = rank_families([lateral, _score("asymmetry", 0.1)], thresholds)
    assert [(c.name, c.significant) for c in ranked] == [("asymmetry", True), ("lateral_slip", True)]
    assert ranked[1].gain == 0.6 and ranked[1].threshold == 0.3 and ranked[1].strength == 2.0
    assert verdict(ranked) == "asymmetry"
    ranked = rank_families([lateral, _score("asymmetry", 0.03)], thresholds)
    assert [c.name for c in ranked] == ["lateral_slip", "asymmetry"]
    assert verdict(ranked) == "lateral_slip"


def test_a_significant_cause_whose_estimate_is_not_resolved_is_not_named():
    """By hand at a 40 ms sample interval: a 3 ms delay (under 20 ms) and an imbalance of 0.01 with a
    jackknife std of 0.02 are not resolved; a 100 ms delay and an imbalance of 0.05 (std 0.01) are."""
    def ranked(*scores):
        return drop_unresolved(rank_families(list(scores), THRESHOLDS), 0.04)

    short = FamilyScore("input_delay", np.array([0.003]), np.zeros(0), 0.2, {}, 0.2, {"delay_s": 0.003})
    r = ranked(short, _score("asymmetry", 0.05))
    assert [(c.name, c.significant) for c in r] == [("asymmetry", True), ("input_delay", False)]
    assert "sample interval" in r[1].note and verdict(r) == "asymmetry"
    long = FamilyScore("input_delay", np.array([0.1]), np.zeros(0), 0.2, {}, 0.2, {"delay_s": 0.1},
                       {"delay_s": 0.01})
    assert verdict(ranked(long, _score("asymmetry", 0.05))) == "input_delay"
    vague = FamilyScore("asymmetry", np.array([0.01]), np.zeros(0), 0.3, {}, 0.3, {"imbalance": 0.01},
                        {"imbalance": 0.02})
    assert verdict(ranked(vague)) == "none" and "standard deviation" in ranked(vague)[0].note
    sharp = dataclasses.replace(vague, estimate={"imbalance": 0.05}, estimate_std={"imbalance": 0.01})
    assert verdict(ranked(sharp)) == "asymmetry"
