"""The EKF's GNSS gate against the chi-square quantile computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulation.gnss import PROFILES, simulate_gnss
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, inputs_at, simulate_truths

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


@pytest.fixture(scope="module")
def short_run():
    """One 10 s simulated run with DGNSS fixes, and the model noise fitted on it."""
    model = ProcessModel(PolyBody(), name="oracle")
    truth = simulate_truths(model, 10.0, np.random.default_rng(7), n_runs=1)[0]
    model = fit_process_noise(model, [truth])
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], PROFILES["dgnss"], seed=3,
                         outages=np.empty((0, 2)))
    t = estimation_grid(truth.t, gnss.t_valid)
    return model, EkfRun("run", t, inputs_at(truth, t), truth.x6[0], P0, gnss)


@pytest.mark.parametrize("gate_prob", [None, 0.99])
def test_gate_is_the_chi_square_quantile_of_the_two_horizontal_dof(short_run, gate_prob):
    """chi2 with 2 dof has the survival function exp(-x / 2): its quantile p is -2 ln(1 - p).

    The default gate probability is 0.999 (bound 13.82); a fix is accepted iff its NIS is below it.
    """
    model, run = short_run
    kw = {} if gate_prob is None else {"gate_prob": gate_prob}
    res = run_ekf_batch(model, [run], **kw)[0]
    p = 0.999 if gate_prob is None else gate_prob
    assert res.gate_nis == pytest.approx(-2.0 * math.log(1.0 - p), rel=1e-12)
    finite = np.isfinite(res.nis)
    assert finite.sum() >= 40
    np.testing.assert_array_equal(res.accepted[finite], res.nis[finite] <= res.gate_nis)
