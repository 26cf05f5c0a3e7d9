"""When every model of the integral-regression screening runs away on some held-out window, the
search ranks them and identification goes on: the structures are pruned, refitted by output error
and checked beside the lag, which decide. Before, ``sindy-ekf demo --effect deadband=0.1`` ended
its identification with "no grid point gave a finite prediction error".

The data: the demo's simulated campaign (8 minutes, seed 0) with a joystick deadband of 0.1, which
the simulator's motors apply and the recorded inputs do not show."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from identification.sindy.checks import run_checks
from simulation.campaign import simulate_campaign
from sindy_ekf.stages.identification import identify, plan_identification


@pytest.fixture(scope="module")
def deadband_campaign(tmp_path_factory):
    out = tmp_path_factory.mktemp("deadband") / "campaign"
    simulate_campaign(out, seed=0, minutes=8.0, effects=["deadband=0.1"])
    return out


def test_a_screening_whose_models_all_diverge_still_yields_a_checked_model(deadband_campaign, caplog):
    plan = plan_identification(deadband_campaign, quick=True)
    with caplog.at_level(logging.WARNING):
        ident = identify(plan)
    table = ident.search.table
    # the premise: every grid point's raw regression model diverged on held-out windows
    assert np.all(table["diverged_frac"] > 0) and not np.isfinite(table["pos_err_5s_m"]).any()
    assert "every grid point's model diverged on some held-out window" in caplog.text
    # ranked by how many windows diverged (all inadmissible, all infinite: that is the order left)
    assert np.all(np.diff(table["diverged_frac"]) >= 0)
    labels = [c.label for c in ident.pipeline.candidates]
    assert "lag" in labels and any(lbl.startswith("grid rank") for lbl in labels)  # the structures went on
    # the selected model passes the checks, recomputed here on the train runs' states
    model = ident.model
    assert model.checks["passed"]
    from identification.sindy.reference import reference

    assert run_checks(model, reference(list(plan.train)).states)["passed"]
    assert np.isfinite(ident.pipeline.candidates[ident.pipeline.selected].cv_pos_err_5s_m)
