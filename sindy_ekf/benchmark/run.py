"""Estimators under degraded GNSS, scored against the campaign's laser-tracker poses.

The thesis's outlook (chapter 7): the identified model as the process model of a Kalman filter,
GNSS simulated from the laser-tracker poses at several precisions, dead reckoning through
outages. Estimators (all sharing one initial state per run, taken from the smoothed truth at the
run's first pose, and one GNSS series per run):

- ``dead_reckoning``: the SINDy model alone, no GNSS;
- ``cv_ekf``, ``unicycle_ekf``, ``sindy_ekf``, ``oracle_ekf`` (the simulator's true dynamics, when
  given): :func:`sindy_ekf.estimation.ekf.run_ekf_batch` with each process model, Q fitted on the train runs;
- ``sindy_graph``: batch smoothing of each run (:func:`sindy_ekf.estimation.graph.smooth_batch`), started
  from the ``sindy_ekf`` estimate; ``sindy_isam2``: fixed-lag iSAM2 in real time;
- ``sindy_ekf_lateral``, ``sindy_graph_lateral``: the same with the non-holonomic ``v_y = 0``
  pseudo-measurement of a skid-steered robot (std from the train runs' lateral velocity).

Scores, at the pose times (the estimation grid holds them, so no interpolation): ATE of position
and heading (RMS over all test-run poses; alignment ``none``: truth and estimates share the local
frame), position and heading error against the time since each scheduled outage began (each
estimator enters the outage from its own state; RMS over outages of equal length, as eq. 5.77),
NEES of the pose (3 dof) and NIS of the fixes (2 dof) with their chi-square bounds, runtime.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from groundfloor.errors import InputError
from identification.sindy.baselines import ConstantVelocityModel, LagModel
from sindy_ekf.estimation.ekf import (
    GRID_TOL_S,
    EkfRun,
    estimation_grid,
    fit_lateral_constraint,
    run_ekf_batch,
)
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
OUTAGE_TAU_STEP_S = 0.1
# sindy_ekf_lateral and sindy_graph_lateral (with the v_y = 0 pseudo-measurement of a skid-steered
# robot) run by default: on the real Warthog poses (10 Hz lidar ICP) the identified yaw equation
# holds a vy term learned from spline noise; without the constraint vy wanders, sindy_ekf diverges
# (ATE 5.5 m on warthog-drive-cmd, 0.215 m with it) and the graph's ATE is 1.7 m (0.154 m with it;
# bench/results/real_cli.md)
ESTIMATORS = ("dead_reckoning", "cv_ekf", "unicycle_ekf", "sindy_ekf", "sindy_ekf_lateral", "oracle_ekf",
              "sindy_graph", "sindy_graph_lateral", "sindy_isam2")
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
    from simulation.gnss import simulate_gnss

    ts = states.t[sel]
    gnss = simulate_gnss(ts, states.x[sel], states.y[sel], states.yaw[sel], profile=profile, seed=seed,
                         outages=np.array([[t_out, t_resume]]))
    grid = estimation_grid(ts, gnss.t_valid)
    u = np.column_stack([np.interp(grid, ts, states.u1[sel]), np.interp(grid, ts, states.u2[sel])])
    x0 = np.array([getattr(states, k)[sel][0] for k in ("x", "y", "yaw", "vx", "vy", "omega")])
    return EkfRun(name, grid, u, x0, np.diag(OUTAGE_P0_STD ** 2), gnss)


@dataclass(frozen=True)
class Estimate:
    """One estimator's estimate of one run at the pose times."""

    t: np.ndarray  # (n,) pose times, s
    x: np.ndarray  # (n, 6)
    P: np.ndarray  # (n, 6, 6), NaN where the estimator gives none
    nis: np.ndarray = field(default_factory=lambda: np.empty(0))


@dataclass(frozen=True)
class Score:
    """Scores of one estimator over all test runs."""

    ate_pos_m: float
    ate_yaw_deg: float
    outage_pos_err_m: dict[str, float]  # duration (s, as text) -> RMS error at the outage's end
    outage_yaw_err_deg: dict[str, float]
    nees_mean: float  # pose NEES (3 dof), mean over poses with a covariance
    nees_inside_95: float  # fraction of samples inside the per-sample 95 % chi-square bounds
    nis_mean: float  # NaN for estimators without innovations
    nis_inside_95: float
    runtime_s: float
    realtime_factor: float  # seconds of data per second of computing


@dataclass(frozen=True)
class BenchmarkResult:
    """Everything the benchmark measured; files are written by :func:`write_benchmark`."""

    profile: str
    alignment: str
    scores: dict[str, Score]
    estimates: dict[str, dict[str, Estimate]]  # estimator -> run -> estimate
    truth: dict[str, np.ndarray]  # run -> (n, 4) [t, x, y, yaw] at the pose times
    outages: dict[str, np.ndarray]  # run -> (m, 2)
    outage_curves: dict[str, dict[str, np.ndarray]]  # estimator -> duration -> (k, 3) tau, pos, yaw
    nees_bounds_95: tuple[float, float]  # per-sample, 3 dof
    nis_bounds_95: tuple[float, float]  # per-sample, 2 dof

    def to_json(self) -> dict:
        """Return the ``benchmark --json`` content (INTERFACES.md keys and more)."""
        return {"profile": self.profile, "alignment": self.alignment,
                "nees_bounds_95": list(self.nees_bounds_95), "nis_bounds_95": list(self.nis_bounds_95),
                "estimators": {n: {k: (v if not isinstance(v, float) or np.isfinite(v) else None)
                                   for k, v in s.__dict__.items()} for n, s in self.scores.items()}}


def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _zoh(t_src: np.ndarray, v_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return ``v_src`` held from each stamp to the next, sampled at ``t`` (first value before)."""
    idx = np.clip(np.searchsorted(t_src, t + GRID_TOL_S, side="right") - 1, 0, len(t_src) - 1)
    return v_src[idx]


def train_series(train_runs, smoothing: float | None = None) -> list[StateSeries]:
    """Return the train runs' six-state series (finite segments of more than 10 samples)."""
    from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
    from identification.sindy.data import body_states

    s = DEFAULT_SMOOTHING if smoothing is None else smoothing
    series = [state_series_from_body_states(seg, f"{r.name}[{i}]") for r in train_runs
              for i, seg in enumerate(body_states(r, s))]
    series = [x for x in series if np.all(np.isfinite(x.x6)) and len(x.t) > 10]
    if not series:
        raise InputError("campaign: no train run with usable poses to fit process noise on")
    return series


def fit_models(train_runs, sindy_body, oracle_dynamics=None, smoothing: float | None = None,
               series: list[StateSeries] | None = None) -> dict[str, ProcessModel]:
    """Return the process models of the EKFs, each with ``Q`` fitted on the train runs' states
    (``series``: those states if already computed by :func:`train_series`)."""
    series = train_series(train_runs, smoothing) if series is None else series
    # unicycle_ekf runs the first-order lag model (what it always ran); issue 13 gives lag_ekf a
    # lag model with dead time and unicycle_ekf the kinematic unicycle of the baselines
    lag = LagModel().fit([body_states_from_state_series(s) for s in series])
    models = {"cv_ekf": ProcessModel(ConstantVelocityModel(), "cv"), "unicycle_ekf": ProcessModel(lag, "lag"),
              "sindy_ekf": ProcessModel(sindy_body, "sindy")}
    if oracle_dynamics is not None:
        models["oracle_ekf"] = ProcessModel(oracle_dynamics, "oracle")
    for m in models.values():
        fit_process_noise(m, series)
    return models


@dataclass
class _TestRun:
    name: str
    t_pose: np.ndarray
    truth: np.ndarray  # (n, 4) t, x, y, yaw
    grid: np.ndarray
    at_pose: np.ndarray  # grid indices of the pose times
    u: np.ndarray  # (n_grid, 2) recorded inputs, held
    u_motor: np.ndarray | None
    x0: np.ndarray
    gnss: object


def _prepare_run(run, profile: str, seed: int, oracle_dynamics, smoothing: float,
                 outage_warmup_s: float, outage_recovery_s: float) -> _TestRun:
    """Return the GNSS series, grid, inputs and initial state of one test run."""
    from identification.preprocessing.states import body_states_from_poses
    from simulation.gnss import schedule_outages, simulate_gnss

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
    x0[2] = yaw[0] + _wrap(x0[2] - yaw[0])
    return _TestRun(run.name, t_pose, truth, grid, at_pose, u, u_motor, x0, gnss)


def _score(est: dict[str, Estimate], runs: list[_TestRun], runtime: float) -> tuple[Score, dict]:
    """Return the scores of one estimator and its error-against-outage-time curves."""
    d_pos, d_yaw, nees, nis = [], [], [], []
    curves: dict[str, list] = {}
    for r in runs:
        e = est[r.name]
        dp = np.hypot(e.x[:, 0] - r.truth[:, 1], e.x[:, 1] - r.truth[:, 2])
        dy = _wrap(e.x[:, 2] - r.truth[:, 3])
        d_pos.append(dp)
        d_yaw.append(dy)
        err = np.column_stack([e.x[:, 0] - r.truth[:, 1], e.x[:, 1] - r.truth[:, 2], dy])
        Pp = e.P[:, :3, :3]
        has = np.all(np.isfinite(Pp), axis=(1, 2))
        if has.any():
            nees.append(np.einsum("ni,ni->n", err[has], np.linalg.solve(Pp[has], err[has][..., None])[..., 0]))
        nis.append(e.nis)
        for a, b in r.gnss.outages:
            key = f"{b - a:g}"
            tau = np.arange(0.0, b - a + 1e-9, OUTAGE_TAU_STEP_S)
            curves.setdefault(key, []).append(np.column_stack([
                np.interp(a + tau, r.t_pose, dp), np.interp(a + tau, r.t_pose, np.abs(dy))]))
    d_pos, d_yaw = np.concatenate(d_pos), np.concatenate(d_yaw)
    nees = np.concatenate(nees) if nees else np.empty(0)
    nis = np.concatenate(nis) if nis else np.empty(0)
    lo3, hi3 = chi2.ppf([0.025, 0.975], 3)
    lo2, hi2 = chi2.ppf([0.025, 0.975], 2)
    rms_curves = {}
    for key, cs in curves.items():
        c = np.sqrt(np.mean(np.stack(cs) ** 2, axis=0))  # eqs. 5.77, 5.78 over the outages
        tau = np.arange(len(c)) * OUTAGE_TAU_STEP_S
        rms_curves[key] = np.column_stack([tau, c[:, 0], np.degrees(c[:, 1])])
    duration = sum(r.t_pose[-1] - r.t_pose[0] for r in runs)
    score = Score(
        ate_pos_m=float(np.sqrt(np.mean(d_pos ** 2))),
        ate_yaw_deg=float(np.degrees(np.sqrt(np.mean(d_yaw ** 2)))),
        outage_pos_err_m={k: float(v[-1, 1]) for k, v in sorted(rms_curves.items(), key=lambda kv: float(kv[0]))},
        outage_yaw_err_deg={k: float(v[-1, 2]) for k, v in sorted(rms_curves.items(), key=lambda kv: float(kv[0]))},
        nees_mean=float(np.mean(nees)) if nees.size else float("nan"),
        nees_inside_95=float(np.mean((nees >= lo3) & (nees <= hi3))) if nees.size else float("nan"),
        nis_mean=float(np.mean(nis)) if nis.size else float("nan"),
        nis_inside_95=float(np.mean((nis >= lo2) & (nis <= hi2))) if nis.size else float("nan"),
        runtime_s=float(runtime), realtime_factor=float(duration / max(runtime, 1e-9)))
    return score, rms_curves


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
    train_campaign : where to fit Q and the unicycle gains (default ``campaign``'s train runs).
    outage_warmup_s, outage_recovery_s : GNSS before the first outage and between outages
        (:func:`simulation.gnss.schedule_outages`: 5, 10, 30, 60 s outages in turn).
    """
    from identification.preprocessing.preprocess import DEFAULT_SMOOTHING

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
    models = fit_models(train, sindy_body, oracle_dynamics, s, series)
    runs = [_prepare_run(r, profile, seed + i, oracle_dynamics, s, outage_warmup_s, outage_recovery_s)
            for i, r in enumerate(test)]
    P0 = np.diag(P0_STD ** 2)
    estimates: dict[str, dict[str, Estimate]] = {}
    runtimes: dict[str, float] = {}

    def keep(name, results, nis=None):
        estimates[name] = {r.name: Estimate(r.t_pose, res.x[r.at_pose], res.P[r.at_pose],
                                            getattr(res, "nis", np.empty(0)))
                           for r, res in zip(runs, results)}

    ekf_names = [n for n in ("cv_ekf", "unicycle_ekf", "sindy_ekf", "oracle_ekf") if n in estimators and n in models]
    for name in ekf_names:
        use_motor = name == "oracle_ekf"
        batch = [EkfRun(f"{r.name} {name}", r.grid, r.u_motor if use_motor and r.u_motor is not None else r.u,
                        r.x0, P0, r.gnss) for r in runs]
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
            EkfRun(f"{r.name} sindy_ekf_lateral", r.grid, r.u, r.x0, P0, r.gnss) for r in runs],
            lateral=lateral))
        runtimes["sindy_ekf_lateral"] = time.perf_counter() - start
    if "dead_reckoning" in estimators:
        start = time.perf_counter()
        keep("dead_reckoning", run_ekf_batch(models["sindy_ekf"], [
            EkfRun(f"{r.name} dead_reckoning", r.grid, r.u, r.x0, P0, None) for r in runs]))
        runtimes["dead_reckoning"] = time.perf_counter() - start
    if {"sindy_graph", "sindy_isam2", "sindy_graph_lateral"} & set(estimators):
        from sindy_ekf.estimation.graph import smooth_batch, smooth_isam2

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
                results.append(smooth_batch(models["sindy_ekf"], r.grid, r.u, r.x0, P0, r.gnss,
                                            x_init=x_init, marginal_stride=10, lateral=constraint,
                                            name=f"{r.name} {name}"))
            keep(name, results)
            runtimes[name] = time.perf_counter() - start
        if "sindy_isam2" in estimators:
            start = time.perf_counter()
            keep("sindy_isam2", [smooth_isam2(models["sindy_ekf"], r.grid, r.u, r.x0, P0, r.gnss,
                                              name=f"{r.name} sindy_isam2") for r in runs])
            runtimes["sindy_isam2"] = time.perf_counter() - start
    scores, curves = {}, {}
    for name in estimates:
        scores[name], curves[name] = _score(estimates[name], runs, runtimes[name])
    return BenchmarkResult(profile, ALIGNMENT, scores, estimates,
                           {r.name: r.truth for r in runs}, {r.name: r.gnss.outages for r in runs},
                           curves, tuple(chi2.ppf([0.025, 0.975], 3)), tuple(chi2.ppf([0.025, 0.975], 2)))


# -- files ------------------------------------------------------------------------------------

def tum_text(t: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> str:
    """Return a TUM trajectory (``t x y z qx qy qz qw``, z = 0, rotation about z by ``yaw``)."""
    rows = np.column_stack([t, x, y, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t),
                            np.sin(yaw / 2.0), np.cos(yaw / 2.0)])
    return "".join(f"{r[0]:.9f} " + " ".join(f"{v:.9f}" for v in r[1:]) + "\n" for r in rows)


def read_tum(path: str | Path) -> np.ndarray:
    """Return ``(n, 4)`` ``[t, x, y, yaw]`` from a TUM file (yaw from the quaternion, unwrapped)."""
    try:
        d = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable TUM trajectory ({exc})") from None
    if d.shape[1] != 8:
        raise InputError(f"{path}: TUM rows need 8 columns, found {d.shape[1]}")
    qx, qy, qz, qw = d[:, 4], d[:, 5], d[:, 6], d[:, 7]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy ** 2 + qz ** 2))
    return np.column_stack([d[:, 0], d[:, 1], d[:, 2], np.unwrap(yaw)])


def ate(ref: np.ndarray, est: np.ndarray, max_diff_s: float = 0.01) -> tuple[float, float]:
    """Return ``(ATE position m, ATE heading deg)`` of ``est`` against ``ref`` (both ``[t, x, y, yaw]``).

    Stamps are associated like evo's ``associate_trajectories`` (nearest reference stamp within
    ``max_diff_s``), no alignment; position 2-D, heading as the wrapped yaw difference.
    """
    i = np.clip(np.searchsorted(ref[:, 0], est[:, 0]), 1, len(ref) - 1)
    left_closer = np.abs(est[:, 0] - ref[i - 1, 0]) <= np.abs(ref[i, 0] - est[:, 0])
    i = np.where(left_closer, i - 1, i)
    ok = np.abs(ref[i, 0] - est[:, 0]) <= max_diff_s
    if not ok.any():
        raise InputError("ATE: no estimate stamp within max_diff of a reference stamp")
    d = est[ok, 1:3] - ref[i[ok], 1:3]
    dyaw = _wrap(est[ok, 3] - ref[i[ok], 3])
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))), float(np.degrees(np.sqrt(np.mean(dyaw ** 2))))


def write_benchmark(result: BenchmarkResult, out_dir: str | Path) -> Path:
    """Write TUM files of the truth and every estimate and the JSON; return the folder.

    The figures of the same folder are drawn by :func:`sindy_ekf.benchmark.figures.write_benchmark_figures`.
    """
    from groundfloor.files import atomic_write_json, atomic_write_text

    out = Path(out_dir)
    for run, tr in result.truth.items():
        atomic_write_text(out / "tum" / "truth" / f"{run}.tum", tum_text(*tr.T))
    for name, per_run in result.estimates.items():
        for run, e in per_run.items():
            atomic_write_text(out / "tum" / name / f"{run}.tum", tum_text(e.t, e.x[:, 0], e.x[:, 1], e.x[:, 2]))
    atomic_write_json(out / "benchmark.json", result.to_json())
    return out


def pose_nees(result: BenchmarkResult, run: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Return ``{estimator: (t since the run's first pose s, pose NEES)}`` of one test run.

    The NEES of ``(x, y, yaw)`` (3 dof) at every pose where the estimator gives a covariance;
    estimators with fewer than two such poses (dead reckoning) are left out.
    """
    tr = result.truth[run]
    out = {}
    for name, per_run in result.estimates.items():
        e = per_run[run]
        err = np.column_stack([e.x[:, 0] - tr[:, 1], e.x[:, 1] - tr[:, 2], _wrap(e.x[:, 2] - tr[:, 3])])
        has = np.all(np.isfinite(e.P[:, :3, :3]), axis=(1, 2))
        if has.sum() < 2:
            continue
        nees = np.einsum("ni,ni->n", err[has], np.linalg.solve(e.P[has, :3, :3], err[has][..., None])[..., 0])
        out[name] = (e.t[has] - tr[0, 0], nees)
    return out
