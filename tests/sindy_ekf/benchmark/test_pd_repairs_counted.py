"""A filter's covariance repairs are counted in the benchmark's output and logged once per filter.

A run whose covariance loses positive definiteness many times used to print one warning per event
(five in a row for the cv EKF on a real Warthog campaign), and the count reached nowhere. Here the
repair is forced on every 25th covariance it is asked about, counted by the test itself: the
benchmark JSON's ``pd_repairs`` must equal that count, the status column must show it, and the
terminal must carry one repair line per run's filter, not one per repair.
"""

from __future__ import annotations

import json
import logging

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf.cli import main
from sindy_ekf.estimation import ekf as ekf_module
from tests.support.trajectory_synth import MINI_RUNS, write_mini_campaign

EVERY = 25


def test_repairs_are_counted_in_the_json_and_logged_once_per_filter(tmp_path, monkeypatch, capsys, caplog):
    root = write_mini_campaign(tmp_path / "mini")
    model = model_from_terms(RobotParams().terms()).to_json(tmp_path / "model.json")
    real = ekf_module.repair_covariance
    forced = {"calls": 0, "repairs": 0}

    def every_25th(P, *args, **kwargs):
        P, repaired = real(P, *args, **kwargs)
        forced["calls"] += 1
        if forced["calls"] % EVERY == 0:
            forced["repairs"] += 1
            return P, True
        return P, repaired

    monkeypatch.setattr(ekf_module, "repair_covariance", every_25th)
    with caplog.at_level(logging.DEBUG, logger="sindy_ekf.estimation.ekf"):
        code = main(["benchmark", str(root), "--model", str(model), "--estimators", "sindy_ekf",
                     "--json", str(tmp_path / "b.json"), "--jobs", "1"])
    out = capsys.readouterr().out
    assert code == 0
    row = json.loads((tmp_path / "b.json").read_text())["estimators"]["sindy_ekf"]
    n_test = sum(1 for *_, split in MINI_RUNS if split == "test")
    assert forced["repairs"] > 2 * n_test  # several per run: the point of logging only the first
    assert row["pd_repairs"] == forced["repairs"]
    assert f"({forced['repairs']} covariance repairs)" in out
    repairs = [r for r in caplog.records if "positive definiteness" in r.getMessage()]
    assert len(repairs) == forced["repairs"]  # every repair is in the log ...
    assert sum(r.levelno >= logging.WARNING for r in repairs) == n_test  # ... one per run's filter on the terminal
