"""iSAM2 against the EKF on a linear-Gaussian case: with a lag longer than the run and every fix
arrived, the real-time estimate of the last state is the filter's (both are the exact posterior).

The grid holds the fixes' times of validity, so its steps are uneven and each step's process
noise (``Q_rate dt``) differs from its neighbours': a dynamics factor with another step's noise
moves the estimate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from simulation.gnss import PROFILES, simulate_gnss
from sindy_ekf.estimation.ekf import estimation_grid, run_ekf
from sindy_ekf.estimation.graph import smooth_isam2
from tests.support.estimation_helpers import linear_gaussian_model, simulate_truth

P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.02, 0.05]) ** 2


def test_isam2_last_state_equals_the_ekf_on_a_linear_gaussian_case():
    rng = np.random.default_rng(11)
    model = linear_gaussian_model()
    truth = simulate_truth(model, 8.0, rng)
    prof = replace(PROFILES["dgnss"], outlier_prob=0.0, latency_jitter_s=0.01)
    gnss = simulate_gnss(truth.t, truth.x6[:, 0], truth.x6[:, 1], truth.x6[:, 2], prof, seed=1,
                         lever_arm_body=(0, 0, 0), outages=np.empty((0, 2)))
    keep = gnss.t_arrival < truth.t[-1] - 0.1  # every fix in both estimators by the last step
    # times of validity 7 ms off the 50 Hz truth grid: steps of 7 and 13 ms around each fix
    gnss = replace(gnss, t_valid=gnss.t_valid[keep] + 0.007, t_arrival=gnss.t_arrival[keep] + 0.007,
                   p_local=gnss.p_local[keep], std=gnss.std[keep], flags=gnss.flags[keep])
    t = estimation_grid(truth.t, gnss.t_valid)
    dt = np.diff(t)
    assert dt.max() > 1.5 * dt.min()  # uneven steps
    u = truth.u[np.clip(np.searchsorted(truth.t, t, side="right") - 1, 0, None)]
    x0 = truth.x6[0] + np.sqrt(np.diag(P0)) * rng.standard_normal(6)
    ekf = run_ekf(model, t, u, x0, P0, gnss, gate_prob=1.0)
    isam = smooth_isam2(model, t, u, x0, P0, gnss, robust=None, update_every=1, lag_s=100.0)
    np.testing.assert_allclose(isam.x[-1], ekf.x[-1], atol=1e-6)
