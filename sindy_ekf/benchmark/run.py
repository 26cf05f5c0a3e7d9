"""Estimators under degraded GNSS on the test runs of a campaign: the benchmark's run.

The thesis's outlook (chapter 7): the identified model as the process model of a Kalman filter,
GNSS simulated from the laser-tracker poses at several precisions, dead reckoning through
outages. Estimators (all sharing one initial state per run, taken from the smoothed truth at the
run's first pose, and one GNSS series per run):

- ``dead_reckoning``: the SINDy model alone, no GNSS;
- ``cv_ekf``, ``unicycle_ekf`` (the kinematic unicycle of the baselines), ``lag_ekf`` (the ``lag``
  baseline: first-order lag per axis with input dead time, output-error fit on the train runs),
  ``sindy_ekf``, ``oracle_ekf`` (the simulator's true dynamics, when given):
  :func:`sindy_ekf.estimation.ekf.run_ekf_batch` with each process model, Q fitted on the train runs;
- ``sindy_graph``: batch smoothing of each run (:func:`sindy_ekf.estimation.graph.smooth_batch`), started
  from the ``sindy_ekf`` estimate; ``sindy_isam2``: fixed-lag iSAM2 in real time;
- ``sindy_ekf_lateral``, ``sindy_graph_lateral``: the same with the non-holonomic ``v_y = 0``
  pseudo-measurement of a skid-steered robot (std from the train runs' lateral velocity).

A model with input dead time (``Dynamics.dead_time_s``) gets the recorded inputs shifted by it
before filtering (:func:`inputs_for`): at grid time ``t`` the filter holds the input recorded at
``t - d``. That is exact, the same as an input buffer in the process model (online, the buffer
holds the inputs of the last ``d`` seconds; offline the recording does), and keeps the filter's
state the six states of eq. 5.60.

The estimates are scored by :mod:`sindy_ekf.benchmark.scoring` (ATE, error through outages,
NEES, NIS, runtime), written by :mod:`sindy_ekf.benchmark.files` and drawn by
:mod:`sindy_ekf.benchmark.figures`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from groundfloor.angles import wrap_angle
from groundfloor.errors import InputError
from groundfloor.gnss import GnssSeries
from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
from identification.preprocessing.states import body_states_from_poses
from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel, fit_lag
from identification.sindy.data import body_states
from simulation.gnss import schedule_outages, simulate_gnss
from sindy_ekf.benchmark.result import BenchmarkResult, Estimate
from sindy_ekf.benchmark.scoring import chi2_bounds_95, score_estimator
from sindy_ekf.estimation.ekf import (
    GRID_TOL_S,
    EkfRun,
    estimation_grid,
    fit_lateral_constraint,
    run_ekf_batch,
)
from sindy_ekf.estimation.graph import smooth_batch, smooth_isam2
from sindy_ekf.estimation.process_models import (
    ProcessModel,
    StateSeries,
    body_states_from_state_series,
    fit_process_noise,
    state_series_from_body_states,
)

log = logging.getLogger(__name__)

ALIGNMENT = "none"
P0_STD = np.array([0.05, 0.05, np.radians(1.0), 0.05, 0.02, 0.05])
# sindy_ekf_lateral and sindy_graph_lateral (with the v_y = 0 pseudo-measurement of a skid-steered
# robot) run by default: on the real Warthog poses (10 Hz lidar ICP) the identified yaw equation
# holds a vy term learned from spline noise; without the constraint vy wanders, sindy_ekf diverges
# (ATE 5.5 m on warthog-drive-cmd, 0.215 m with it) and the graph's ATE is 1.7 m (0.154 m with it;
# bench/results/real_cli.md)
ESTIMATORS = ("dead_reckoning", "cv_ekf", "unicycle_ekf", "lag_ekf", "sindy_ekf", "sindy_ekf_lateral", "oracle_ekf",
              "sindy_graph", "sindy_graph_lateral", "sindy_isam2")
EKF_ESTIMATORS = ("cv_ekf", "unicycle_ekf", "lag_ekf", "sindy_ekf", "oracle_ekf")  # one process model each
OPTIONAL_ESTIMATORS: tuple[str, ...] = ()  # accepted in ``estimators`` but not run by default
LATERAL_EVERY = 10  # steps between v_y = 0 pseudo-measurements (5 Hz on the 50 Hz grid)


OUTAGE_P0_STD = np.array([0.05, 0.05, 0.02, 0.05, 0.05, 0.05])  # x, y [m], psi [rad], v [m/s, rad/s]


def outage_ekf_run(states, sel, t_out: float, t_resume: float, profile: str, seed: int,
                   name: str) -> EkfRun:
    """Return an EKF run over ``states[sel]`` with GNSS degraded from it and no fix in [t_out, t_resume].

    The filter starts from the true state at the first selected sample (std ``OUTAGE_P0_STD``)
    with the inputs interpolated on the estimation grid: the set-up for the error at the end of a
    scheduled GNSS outage.
    """
    ts = states.t[sel]
    gnss = simulate_gnss(ts, states.x[sel], states.y[sel], states.yaw[sel], profile=profile, seed=seed,
                         outages=np.array([[t_out, t_resume]]))
    grid = estimation_grid(ts, gnss.t_valid)
    u = np.column_stack([np.interp(grid, ts, states.u1[sel]), np.interp(grid, ts, states.u2[sel])])
    x0 = np.array([getattr(states, k)[sel][0] for k in ("x", "y", "yaw", "vx", "vy", "omega")])
    return EkfRun(name, grid, u, x0, np.diag(OUTAGE_P0_STD ** 2), gnss)


def _zoh(t_src: np.ndarray, v_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return ``v_src`` held from each stamp to the next, sampled at ``t`` (first value before)."""
    idx = np.clip(np.searchsorted(t_src, t + GRID_TOL_S, side="right") - 1, 0, len(t_src) - 1)
    return v_src[idx]


def train_series(train_runs, smoothing: float | None = None) -> list[StateSeries]:
    """Return the train runs' six-state series (finite segments of more than 10 samples)."""
    s = DEFAULT_SMOOTHING if smoothing is None else smoothing
    series = [state_series_from_body_states(seg, f"{r.name}[{i}]") for r in train_runs
              for i, seg in enumerate(body_states(r, s))]
    series = [x for x in series if np.all(np.isfinite(x.x6)) and len(x.t) > 10]
    if not series:
        raise InputError("campaign: no train run with usable poses to fit process noise on")
    return series


def fit_models(train_runs, sindy_body, oracle_dynamics=None, smoothing: float | None = None,
               series: list[StateSeries] | None = None, lag: bool = True) -> dict[str, ProcessModel]:
    """Return the process models of the EKFs, each with ``Q`` fitted on the train runs' states
    (``series``: those states if already computed by :func:`train_series`): the kinematic
    unicycle (gains from the states), the ``lag`` baseline (:func:`identification.sindy.baselines.fit_lag`,
    output error on the train runs; left out when ``lag`` is False), the model, the oracle."""
    series = train_series(train_runs, smoothing) if series is None else series
    unicycle = UnicycleModel().fit([body_states_from_state_series(s) for s in series])
    models = {"cv_ekf": ProcessModel(ConstantVelocityModel(), "cv"),
              "unicycle_ekf": ProcessModel(unicycle, "unicycle")}
    if lag:
        models["lag_ekf"] = ProcessModel(fit_lag(list(train_runs)), "lag")
    models["sindy_ekf"] = ProcessModel(sindy_body, "sindy")
    if oracle_dynamics is not None:
        models["oracle_ekf"] = ProcessModel(oracle_dynamics, "oracle")
    for m in models.values():
        fit_process_noise(m, series)
    return models


@dataclass(frozen=True)
class _TestRun:
    """One test run made ready for the estimators: its GNSS, grid, inputs and initial state."""

    name: str
    t_pose: np.ndarray
    truth: np.ndarray  # (n, 4) t, x, y, yaw
    grid: np.ndarray
    at_pose: np.ndarray  # grid indices of the pose times
    u: np.ndarray  # (n_grid, 2) recorded inputs, held
    u_motor: np.ndarray | None
    x0: np.ndarray
    gnss: GnssSeries
    t_in: np.ndarray  # (m,) the recorded input stamps
    u_in: np.ndarray  # (m, 2) the recorded inputs

    def inputs_for(self, dynamics) -> np.ndarray:
        """Return the held inputs on the grid a model with ``dynamics.dead_time_s`` sees, ``u(t - d)``."""
        d = getattr(dynamics, "dead_time_s", (0.0, 0.0))
        if not np.any(d):
            return self.u
        return np.column_stack([_zoh(self.t_in + d[i], self.u_in[:, i], self.grid) for i in range(2)])


def _prepare_run(run, profile: str, seed: int, oracle_dynamics, smoothing: float,
                 outage_warmup_s: float, outage_recovery_s: float) -> _TestRun:
    """Return the GNSS series, grid, inputs and initial state of one test run."""
    p = run.poses
    ok = np.isfinite(p.t) & np.isfinite(p.x) & np.isfinite(p.y) & np.isfinite(p.yaw)
    t_pose = np.asarray(p.t, float)[ok]
    if len(t_pose) < 10:
        raise InputError(f"run {run.name}: fewer than 10 usable poses to benchmark on")
    yaw = np.unwrap(np.asarray(p.yaw, float)[ok])
    truth = np.column_stack([t_pose, p.x[ok], p.y[ok], yaw])
    z = np.asarray(p.z, float)[ok] if p.z is not None else None
    outages = schedule_outages(t_pose[0], t_pose[-1], warmup_s=outage_warmup_s,
                               recovery_s=outage_recovery_s)
    gnss = simulate_gnss(t_pose, truth[:, 1], truth[:, 2], yaw, profile, seed=seed, z=z,
                         outages=outages)
    grid = estimation_grid(t_pose, gnss.t_valid)
    at_pose = np.searchsorted(grid, t_pose - GRID_TOL_S)
    inp = run.inputs
    u = _zoh(np.asarray(inp.t, float), np.column_stack([inp.u1, inp.u2]), grid)
    u_motor = None
    if oracle_dynamics is not None and hasattr(oracle_dynamics, "motor_inputs"):
        u_motor = oracle_dynamics.motor_inputs(grid - t_pose[0], np.asarray(inp.t) - t_pose[0],
                                               np.column_stack([inp.u1, inp.u2]))
    st = body_states_from_poses(p, inp, smoothing, t_eval=t_pose[:1])
    x0 = np.array([st.x[0], st.y[0], st.yaw[0], st.vx[0], st.vy[0], st.omega[0]])
    if not np.all(np.isfinite(x0)):
        x0 = np.array([truth[0, 1], truth[0, 2], truth[0, 3], 0.0, 0.0, 0.0])
    x0[2] = yaw[0] + wrap_angle(x0[2] - yaw[0])
    return _TestRun(run.name, t_pose, truth, grid, at_pose, u, u_motor, x0, gnss, np.asarray(inp.t, float),
                    np.column_stack([inp.u1, inp.u2]))


def benchmark_campaign(campaign, sindy_body, profile: str = "dgnss", seed: int = 0,
                       oracle_dynamics=None, estimators=ESTIMATORS, smoothing: float | None = None,
                       train_campaign=None, outage_warmup_s: float = 30.0,
                       outage_recovery_s: float = 30.0) -> BenchmarkResult:
    """Return the benchmark of the estimators on the test runs of ``campaign``.

    Parameters
    ----------
    campaign : ``groundfloor.types.TrajectoryCampaign`` (its test runs are scored).
    sindy_body : the identified body model (``identification.sindy.model.SindyModel``).
    profile : GNSS profile of :mod:`simulation.gnss`; ``seed`` seeds it (run ``i`` uses seed + i).
    oracle_dynamics : ``simulation.robot.TrueDynamics`` for ``oracle_ekf`` (simulated campaigns).
    estimators : names to run, a subset of :data:`ESTIMATORS` and :data:`OPTIONAL_ESTIMATORS`
        (``sindy_ekf_lateral`` and ``sindy_graph_lateral``: sindy_ekf and sindy_graph with the
        ``v_y = 0`` pseudo-measurement of :func:`sindy_ekf.estimation.ekf.fit_lateral_constraint` on the train runs, every
        :data:`LATERAL_EVERY` steps).
    train_campaign : where to fit Q, the unicycle gains and the lag (default ``campaign``'s train runs).
    outage_warmup_s, outage_recovery_s : GNSS before the first outage and between outages
        (:func:`simulation.gnss.schedule_outages`: 5, 10, 30, 60 s outages in turn).
    """
    known = ESTIMATORS + OPTIONAL_ESTIMATORS
    unknown = set(estimators) - set(known)
    if unknown:
        raise InputError(f"benchmark: unknown estimator(s) {sorted(unknown)} (known: {', '.join(known)})")
    s = DEFAULT_SMOOTHING if smoothing is None else smoothing
    test = campaign.split("test")
    train = (train_campaign or campaign).split("train")
    if not test:
        raise InputError(f"{campaign.root}: no run marked test to benchmark on")
    if not train:
        raise InputError(f"{campaign.root}: no run marked train to fit process noise on")
    series = train_series(train, s)
    models = fit_models(train, sindy_body, oracle_dynamics, s, series, lag="lag_ekf" in estimators)
    runs = [_prepare_run(r, profile, seed + i, oracle_dynamics, s, outage_warmup_s, outage_recovery_s)
            for i, r in enumerate(test)]
    P0 = np.diag(P0_STD ** 2)
    estimates: dict[str, dict[str, Estimate]] = {}
    runtimes: dict[str, float] = {}

    def keep(name, results):
        estimates[name] = {r.name: Estimate(r.t_pose, res.x[r.at_pose], res.P[r.at_pose],
                                            getattr(res, "nis", np.empty(0)))
                           for r, res in zip(runs, results)}

    ekf_names = [n for n in EKF_ESTIMATORS if n in estimators and n in models]
    for name in ekf_names:
        use_motor = name == "oracle_ekf"
        batch = [EkfRun(f"{r.name} {name}", r.grid, r.u_motor if use_motor and r.u_motor is not None
                        else r.inputs_for(models[name].dynamics), r.x0, P0, r.gnss) for r in runs]
        start = time.perf_counter()
        keep(name, run_ekf_batch(models[name], batch))
        runtimes[name] = time.perf_counter() - start
    lateral = None
    if any(n.endswith("_lateral") for n in estimators):
        lateral = fit_lateral_constraint([x.x6[:, 4] for x in series], every=LATERAL_EVERY)
    if "sindy_ekf_lateral" in estimators:
        log.info("sindy_ekf_lateral: v_y = 0 with std %.4f m/s every %d steps", lateral.vy_std_m_s,
                 lateral.every)
        start = time.perf_counter()
        keep("sindy_ekf_lateral", run_ekf_batch(models["sindy_ekf"], [
            EkfRun(f"{r.name} sindy_ekf_lateral", r.grid, r.inputs_for(sindy_body), r.x0, P0, r.gnss) for r in runs],
            lateral=lateral))
        runtimes["sindy_ekf_lateral"] = time.perf_counter() - start
    if "dead_reckoning" in estimators:
        start = time.perf_counter()
        keep("dead_reckoning", run_ekf_batch(models["sindy_ekf"], [
            EkfRun(f"{r.name} dead_reckoning", r.grid, r.inputs_for(sindy_body), r.x0, P0, None) for r in runs]))
        runtimes["dead_reckoning"] = time.perf_counter() - start
    if {"sindy_graph", "sindy_isam2", "sindy_graph_lateral"} & set(estimators):
        # batch smoothing, each started from its filter's estimate on the full grid
        for name, init_name, constraint in (("sindy_graph", "sindy_ekf", None),
                                            ("sindy_graph_lateral", "sindy_ekf_lateral", lateral)):
            if name not in estimators:
                continue
            start = time.perf_counter()
            init = estimates.get(init_name)
            results = []
            for r in runs:
                x_init = None
                if init is not None:
                    x_init = np.column_stack([np.interp(r.grid, r.t_pose, init[r.name].x[:, i])
                                              for i in range(6)])
                results.append(smooth_batch(models["sindy_ekf"], r.grid, r.inputs_for(sindy_body), r.x0, P0, r.gnss,
                                            x_init=x_init, marginal_stride=10, lateral=constraint,
                                            name=f"{r.name} {name}"))
            keep(name, results)
            runtimes[name] = time.perf_counter() - start
        if "sindy_isam2" in estimators:
            start = time.perf_counter()
            keep("sindy_isam2", [smooth_isam2(models["sindy_ekf"], r.grid, r.inputs_for(sindy_body), r.x0, P0, r.gnss,
                                              name=f"{r.name} sindy_isam2") for r in runs])
            runtimes["sindy_isam2"] = time.perf_counter() - start
    truth = {r.name: r.truth for r in runs}
    outages = {r.name: r.gnss.outages for r in runs}
    scores, curves = {}, {}
    for name in estimates:
        scores[name], curves[name] = score_estimator(estimates[name], truth, outages, runtimes[name])
    return BenchmarkResult(profile, ALIGNMENT, scores, estimates, truth, outages, curves,
                           chi2_bounds_95(3), chi2_bounds_95(2), campaign.name)
