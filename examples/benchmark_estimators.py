"""Which estimator tracks a robot best under degraded GNSS with outages?

Problem
    A ground robot has a differential GNSS receiver (30 cm noise, 5 Hz, latency, occasional
    multipath outliers) that drops out for 5 and 10 s. Six estimators of its pose are compared
    against the ground truth of a test run: dead reckoning on the identified model (no GNSS),
    EKFs with a constant-velocity, a kinematic unicycle, a first-order lag and the identified
    SINDy model, and a factor-graph smoother (gtsam, Levenberg-Marquardt over the whole run)
    with the SINDy model.

Model
    State ``[x, y, psi, vx, vy, omega]``; the pose follows eq. 5.75, the body velocities the
    process model (SINDy eq. 5.53 identified by integral SINDy on the train runs, or a baseline),
    stepped by RK4 with its exact Jacobian (``sindy_ekf.estimation.process_models``); process noise from the
    one-step residuals on the train runs. GNSS measures the antenna at a lever arm,
    ``h(x) = p + R(psi) l``; the EKF applies each fix at its time of validity (stochastic
    cloning over the latency) behind a chi-square gate; the graph puts one dynamics factor per
    step and a Huber-robust GNSS factor per fix (``sindy_ekf.estimation.graph``). Scores: absolute
    trajectory error (RMS position and heading over the run) and the position error at the end
    of each outage.

This example wires the pieces by hand to show them; ``sindy_ekf.benchmark.run.benchmark_campaign``
(the ``sindy-ekf benchmark`` command) does the same over all test runs of a campaign, with NEES
and NIS consistency and the smoother on the full 50 Hz grid.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from identification.preprocessing.campaigns import open_campaign
from identification.preprocessing.trajectory import write_trajectory_campaign
from identification.sindy.baselines import ConstantVelocityModel, LagModel, UnicycleModel
from identification.sindy.data import states_of_runs
from identification.sindy.regression import fit_sindy
from simulation.gnss import schedule_outages, simulate_gnss
from simulation.short_campaign import simulate_trajectory_runs
from sindy_ekf.estimation.ekf import EkfRun, estimation_grid, run_ekf_batch
from sindy_ekf.estimation.graph import smooth_batch
from sindy_ekf.estimation.process_models import (
    ProcessModel,
    fit_process_noise,
    state_series_from_body_states,
)

SMOOTHING = 0.0005
TAU_S, ALPHA, THRESHOLD = 3.0, 10.0, 0.5  # a sparse model: stays tame where noisy fixes push the state
PROFILE = "dgnss"
OUTAGES_S = (5.0, 10.0)
WARMUP_S = 15.0
GRAPH_STRIDE = 5  # poses at 50 Hz -> 10 Hz for the smoother
GRAPH_ITERATIONS = 8  # Levenberg-Marquardt from the EKF's estimate converges in a few


def ate(x_est: np.ndarray, t_est: np.ndarray, st) -> tuple[float, float]:
    """Return the RMS position (m) and heading (deg) error of estimates against the states' poses."""
    x = np.interp(st.t, t_est, x_est[:, 0])
    y = np.interp(st.t, t_est, x_est[:, 1])
    psi = np.interp(st.t, t_est, x_est[:, 2])
    d_psi = (psi - st.yaw + np.pi) % (2 * np.pi) - np.pi
    return float(np.sqrt(np.mean((x - st.x) ** 2 + (y - st.y) ** 2))), float(np.degrees(np.sqrt(np.mean(d_psi ** 2))))


def main(campaign: str | Path | None = None) -> dict:
    """Run every estimator on the first test run; print and return their scores."""
    with tempfile.TemporaryDirectory(prefix="benchmark-example-") as tmp:
        if campaign is None:
            runs = [(run, None) for run in simulate_trajectory_runs(seed=7)]  # simulator truth, no bags
            campaign = write_trajectory_campaign(Path(tmp) / "campaign", "examples-seed7", runs,
                                                 ground_truth="simulator truth plus tracker-level noise")
        camp = open_campaign(campaign)
    train, _, _ = states_of_runs(camp.split("train"), SMOOTHING)
    st = states_of_runs(camp.split("test"), SMOOTHING)[0][0]
    series = [state_series_from_body_states(s, f"train{i}") for i, s in enumerate(train)]
    sindy = fit_process_noise(ProcessModel(fit_sindy(train, "poly3", tau=TAU_S, alpha=ALPHA,
                                                     threshold=THRESHOLD, smoothing=SMOOTHING)), series)
    # as the benchmark's: unicycle_ekf the kinematic unicycle, lag_ekf the first-order lag per axis
    processes = {"cv_ekf": fit_process_noise(ProcessModel(ConstantVelocityModel(), "cv"), series),
                 "unicycle_ekf": fit_process_noise(ProcessModel(UnicycleModel().fit(train), "unicycle"), series),
                 "lag_ekf": fit_process_noise(ProcessModel(LagModel().fit(train), "lag"), series),
                 "sindy_ekf": sindy}

    outages = schedule_outages(st.t[0], st.t[-1], durations=OUTAGES_S, warmup_s=WARMUP_S, recovery_s=15.0)
    gnss = simulate_gnss(st.t, st.x, st.y, st.yaw, profile=PROFILE, seed=1, outages=outages)
    grid = estimation_grid(st.t, gnss.t_valid)
    u = np.column_stack([np.interp(grid, st.t, st.u1), np.interp(grid, st.t, st.u2)])
    # every estimator starts from the ground truth's first state (the robot at rest, pose surveyed)
    x0 = np.array([st.x[0], st.y[0], st.yaw[0], st.vx[0], st.vy[0], st.omega[0]])
    P0 = np.diag([0.05, 0.05, 0.02, 0.05, 0.05, 0.05]) ** 2

    estimates = {}
    for name, proc in processes.items():
        res = run_ekf_batch(proc, [EkfRun(name, grid, u, x0, P0, gnss)])[0]
        estimates[name] = (res.t, res.x, res.runtime_s)
    dr = run_ekf_batch(sindy, [EkfRun("dead_reckoning", grid, u, x0, P0, None)])[0]
    estimates["dead_reckoning"] = (dr.t, dr.x, dr.runtime_s)
    # the smoother on a 10 Hz grid (the fixes' times plus every fifth pose): a Python dynamics
    # factor per step is the cost, and RK4 over 0.1 s is still accurate for this model
    tic = time.perf_counter()
    g_grid = estimation_grid(st.t[::GRAPH_STRIDE], gnss.t_valid, dt_max=0.1)
    g_u = np.column_stack([np.interp(g_grid, st.t, st.u1), np.interp(g_grid, st.t, st.u2)])
    g_init = np.column_stack([np.interp(g_grid, grid, c) for c in estimates["sindy_ekf"][1].T])
    graph = smooth_batch(sindy, g_grid, g_u, x0, P0, gnss=gnss, x_init=g_init, marginal_stride=None,
                         max_iterations=GRAPH_ITERATIONS)
    estimates["sindy_graph"] = (graph.t, graph.x, time.perf_counter() - tic)

    scores = {}
    for name, (t, x, runtime) in estimates.items():
        pos, yaw = ate(x, t, st)
        ends = {f"{b - a:g}": float(np.hypot(np.interp(b, t, x[:, 0]) - np.interp(b, st.t, st.x),
                                             np.interp(b, t, x[:, 1]) - np.interp(b, st.t, st.y)))
                for a, b in outages}
        scores[name] = {"ate_pos_m": pos, "ate_yaw_deg": yaw, "outage_pos_err_m": ends, "runtime_s": runtime}
    print(f"test run of {st.t[-1] - st.t[0]:.0f} s, GNSS profile {PROFILE}, outages "
          + ", ".join(f"{b - a:g} s" for a, b in outages))
    print(f"{'estimator':16} {'ATE pos m':>9} {'ATE yaw deg':>11}  error at end of outage m   runtime s")
    for name, s in scores.items():
        ends = "  ".join(f"{k} s: {v:6.3f}" for k, v in s["outage_pos_err_m"].items())
        print(f"{name:16} {s['ate_pos_m']:9.3f} {s['ate_yaw_deg']:11.2f}  {ends:24} {s['runtime_s']:9.2f}")
    return {"estimators": scores, "outages": outages}


if __name__ == "__main__":
    import sys

    main(sys.argv[1] if len(sys.argv) > 1 else None)
