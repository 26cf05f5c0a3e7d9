"""A fix valid at the last grid time is part of the factor graph (the grid's ends are inclusive)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from simulation.gnss import PROFILES, simulate_gnss
from sindy_ekf.estimation.ekf import estimation_grid
from sindy_ekf.estimation.graph import smooth_batch
from sindy_ekf.estimation.process_models import ProcessModel, fit_process_noise
from tests.support.estimation_helpers import PolyBody, inputs_at, simulate_truths

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def test_a_fix_at_the_last_grid_time_moves_the_last_state():
    model = ProcessModel(PolyBody(), name="poly")
    truth = simulate_truths(model, 6.0, np.random.default_rng(5), n_runs=1)[0]
    model = fit_process_noise(model, [truth])
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2],
                         replace(PROFILES["dgnss"], outlier_prob=0.0), seed=2, outages=np.empty((0, 2)))
    t = estimation_grid(truth.t, gnss.t_valid)
    t = t[t <= gnss.t_valid[-1] + 1e-9]  # the grid ends at the last fix's time of validity
    assert abs(t[-1] - gnss.t_valid[-1]) < 1e-9
    u = inputs_at(truth, t)
    moved_p = gnss.p_local.copy()
    moved_p[-1, 0] += 3.0  # the last state must follow a share of it (its gain, about P / (P + R))
    plain = smooth_batch(model, t, u, truth.x6[0], P0, gnss, robust=None, marginal_stride=None)
    moved = smooth_batch(model, t, u, truth.x6[0], P0, replace(gnss, p_local=moved_p), robust=None,
                         marginal_stride=None)
    shift = moved.x[-1, 0] - plain.x[-1, 0]
    assert 0.02 < shift < 1.5, shift
