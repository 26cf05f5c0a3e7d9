"""Monte-Carlo runs of the SINDy estimators under GNSS faults (issue 14, item 3).

One Monte-Carlo run is a window of ``window_s`` seconds of one test run, at a start drawn at
random, with its own GNSS noise (:func:`simulation.gnss.simulate_gnss`) and its own fault
realisation (:mod:`simulation.gnss_faults`, one named mix per run), both from the run's seed.
The windows share the test runs' driving, so the runs are independent in their GNSS errors and
faults, not in the trajectories they drive.

Each window goes through ``sindy_ekf`` and ``sindy_ekf_lateral`` (all windows of a chunk in
lockstep through :func:`sindy_ekf.benchmark.health.guarded_ekf_batch`, with the NIS monitor and
re-initialisation) and, on the windows asked for, ``sindy_graph`` (batch smoothing started from
the ``sindy_ekf`` estimate, :func:`sindy_ekf.benchmark.health.guarded`). Each ends in one
:class:`McOutcome`: status (ok, diverged, failed), re-initialisations, pose NEES and the
position error at the end of the window's outage.

NEES inside its band, per run: the pose NEES (3 dof) sampled every ``NEES_STRIDE_S`` and
averaged over the run's ``N`` samples is, for a consistent filter, ``chi2(3 N) / N`` if the
samples are independent; the run is inside when its mean lies in that law's two-sided 95 %
interval (Bar-Shalom, Li and Kirubarajan 2001, sec. 5.4.2, with the average over time instead
of runs). The stride is there because the errors are correlated over seconds; with samples
correlated beyond it the band is too narrow and a consistent filter falls outside more often
than 5 %, so the clean mix is the yardstick.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from groundfloor.angles import wrap_angle
from groundfloor.errors import InputError
from groundfloor.input_chain import sees_recorded_inputs
from identification.preprocessing.states import body_states_from_poses
from simulation.gnss import simulate_gnss
from simulation.gnss_faults import FAULT_MIXES, GnssFaults, apply_gnss_faults, draw_gnss_faults
from sindy_ekf.benchmark.health import guarded, guarded_ekf_batch
from sindy_ekf.benchmark.run import held_inputs_for, hold_inputs
from sindy_ekf.benchmark.scoring import pose_truth
from sindy_ekf.estimation.ekf import GRID_TOL_S, EkfRun, LateralConstraint, estimation_grid
from sindy_ekf.estimation.graph import smooth_batch
from sindy_ekf.estimation.process_models import ProcessModel

log = logging.getLogger(__name__)

WINDOW_S = 150.0  # 30 s warm-up, an outage of up to 60 s, 10 s after it at least, faults around
NEES_STRIDE_S = 5.0
MC_ESTIMATORS = ("sindy_ekf", "sindy_ekf_lateral", "sindy_graph")


@dataclass(frozen=True)
class McSource:
    """One test run made ready once for cutting windows: poses, smoothed states and inputs."""

    name: str
    truth: np.ndarray  # (n, 4) t, x, y, yaw (unwrapped) at the usable pose times
    z: np.ndarray | None  # (n,) height of the body origin, or None
    x6: np.ndarray  # (n, 6) smoothed states at the pose times (NaN where the spline has none)
    t_input: np.ndarray  # (m,) input stamps
    u_input: np.ndarray  # (m, 2) inputs u1, u2


@dataclass(frozen=True)
class McWindow:
    """One Monte-Carlo run: a window of a test run with its faulted GNSS, ready for the filters."""

    index: int
    mix: str
    source: str
    truth: np.ndarray  # (n, 4) t, x, y, yaw at the window's pose times
    grid: np.ndarray
    at_pose: np.ndarray  # grid indices of the pose times
    u: np.ndarray  # (n_grid, 2) inputs held
    x0: np.ndarray
    gnss: object  # groundfloor.gnss.GnssSeries with the faults laid over it
    faults: GnssFaults
    t_input: np.ndarray | None = None  # the source run's input stamps and inputs, for models with a
    u_input: np.ndarray | None = None  # dead time or input lag (:meth:`inputs_for`)

    def inputs_for(self, dynamics) -> np.ndarray:
        """Return the inputs on the grid the model ``dynamics`` sees (``benchmark.run.held_inputs_for``)."""
        if self.t_input is None or sees_recorded_inputs(dynamics):
            return self.u
        return held_inputs_for(dynamics, self.t_input, self.u_input, self.grid)


@dataclass(frozen=True)
class McOutcome:
    """How one estimator did on one Monte-Carlo run."""

    index: int
    mix: str
    estimator: str
    status: str  # ok | diverged | failed (sindy_ekf.benchmark.health)
    recoveries: int
    nees_mean: float  # mean pose NEES over the samples every NEES_STRIDE_S (NaN if none)
    nees_in_band: bool  # nees_mean inside the two-sided 95 % interval of chi2(3 N) / N
    nees_share_95: float  # share of all pose NEES samples inside the per-sample 95 % bounds
    outage_s: float  # length of the window's outage (NaN if none)
    outage_end_err_m: float  # position error at its end (NaN if none or not reached)
    ate_pos_m: float  # RMS position error over the poses the estimator reached
    final_err_m: float  # position error at the last pose reached
    fix_steps: int = 0  # NIS alarms explained by a step of the fixes (not reset)
    window_s: float = float("nan")  # length of the window, s (recoveries per hour)
    saturated_steps: int = 0  # EKF steps with the model evaluated at velocities saturated at its envelope


def prepare_sources(test_runs, smoothing: float) -> list[McSource]:
    """Return the test runs as :class:`McSource` (smoothed states computed once per run)."""
    out = []
    for run in test_runs:
        truth, z = pose_truth(run.poses)
        st = body_states_from_poses(run.poses, run.inputs, smoothing, t_eval=truth[:, 0])
        x6 = np.column_stack([st.x, st.y, st.yaw, st.vx, st.vy, st.omega])
        inp = run.inputs
        out.append(McSource(run.name, truth, z, x6, np.asarray(inp.t, float), np.column_stack([inp.u1, inp.u2])))
    return out


def mix_of(index: int, mixes=tuple(FAULT_MIXES)) -> str:
    """Return the fault mix of Monte-Carlo run ``index``: the mixes in turn, so each gets an equal share."""
    return mixes[index % len(mixes)]


def draw_window(sources: list[McSource], index: int, seed: int, profile: str = "dgnss",
                window_s: float = WINDOW_S, mix: str | None = None) -> McWindow:
    """Return Monte-Carlo run ``index``: source run, start, GNSS and faults drawn from ``(seed, index)``."""
    usable = [s for s in sources if s.truth[-1, 0] - s.truth[0, 0] >= window_s]
    if not usable:
        raise InputError(f"Monte Carlo: no test run lasts the {window_s:g} s of a window")
    mix = mix_of(index) if mix is None else mix
    rng = np.random.default_rng([seed, index])
    src = usable[int(rng.integers(len(usable)))]
    t_all = src.truth[:, 0]
    start = rng.uniform(t_all[0], t_all[-1] - window_s)
    sel = np.flatnonzero((t_all >= start) & (t_all <= start + window_s))
    # the first pose must carry a smoothed state to start from
    sel = sel[int(np.argmax(np.all(np.isfinite(src.x6[sel]), axis=1))):]
    truth = src.truth[sel]
    gnss_seed, fault_seed = rng.integers(2 ** 31, size=2)
    gnss = simulate_gnss(truth[:, 0], truth[:, 1], truth[:, 2], truth[:, 3], profile, seed=int(gnss_seed),
                         z=None if src.z is None else src.z[sel], outages=np.empty((0, 2)))
    faults = draw_gnss_faults(gnss.t_valid, FAULT_MIXES[mix], int(fault_seed))
    gnss = apply_gnss_faults(gnss, faults)
    grid = estimation_grid(truth[:, 0], gnss.t_valid)
    at_pose = np.searchsorted(grid, truth[:, 0] - GRID_TOL_S)
    x0 = src.x6[sel[0]].copy()
    x0[2] = truth[0, 3] + wrap_angle(x0[2] - truth[0, 3])
    return McWindow(index, mix, src.name, truth, grid, at_pose, hold_inputs(src.t_input, src.u_input, grid), x0,
                    gnss, faults, src.t_input, src.u_input)


def nees_band_95(n: int, dof: int = 3) -> tuple[float, float]:
    """Return the two-sided 95 % interval of the mean of ``n`` independent ``chi2(dof)`` samples."""
    lo, hi = chi2.ppf([0.025, 0.975], dof * n)
    return float(lo / n), float(hi / n)


def outcome(w: McWindow, estimator: str, x: np.ndarray | None, P: np.ndarray | None, status,
            saturated_steps: int = 0) -> McOutcome:
    """Return the :class:`McOutcome` of an estimate ``x, P`` on ``w``'s grid (cut short if it diverged)."""
    nan = float("nan")
    n = 0 if x is None else int(np.searchsorted(w.at_pose, len(x)))
    o = w.faults.outages
    outage_s = float(o[0, 1] - o[0, 0]) if len(o) else nan
    if n < 2:
        return McOutcome(w.index, w.mix, estimator, status.status, status.recoveries, nan, False, nan,
                         outage_s, nan, nan, nan, status.fix_steps, float(w.truth[-1, 0] - w.truth[0, 0]),
                         saturated_steps)
    tr = w.truth[:n]
    xs, Ps = x[w.at_pose[:n]], P[w.at_pose[:n]]
    err = np.column_stack([xs[:, 0] - tr[:, 1], xs[:, 1] - tr[:, 2], wrap_angle(xs[:, 2] - tr[:, 3])])
    dp = np.hypot(err[:, 0], err[:, 1])
    Pp = Ps[:, :3, :3]
    has = np.all(np.isfinite(Pp), axis=(1, 2))
    nees = np.full(n, np.nan)
    if has.any():  # solving instead of inverting keeps a nearly singular covariance accurate
        nees[has] = np.einsum("ni,ni->n", err[has], np.linalg.solve(Pp[has], err[has][..., None])[..., 0])
    lo3, hi3 = chi2.ppf([0.025, 0.975], 3)
    finite = nees[np.isfinite(nees)]
    share = float(np.mean((finite >= lo3) & (finite <= hi3))) if finite.size else nan
    # one sample per stride: the pose nearest each multiple of the stride with a covariance
    t_has = tr[has, 0]
    picks = np.unique(np.searchsorted(t_has, np.arange(t_has[0], t_has[-1], NEES_STRIDE_S))) if t_has.size else []
    sampled = nees[has][picks] if len(picks) else np.empty(0)
    nees_mean, inside = nan, False
    if sampled.size:
        nees_mean = float(np.mean(sampled))
        lo, hi = nees_band_95(sampled.size)
        inside = bool(status.status == "ok" and lo <= nees_mean <= hi)
    end_err = nan
    if len(o) and o[0, 1] <= tr[-1, 0]:
        end_err = float(np.interp(o[0, 1], tr[:, 0], dp))
    return McOutcome(w.index, w.mix, estimator, status.status, status.recoveries, nees_mean, inside, share,
                     outage_s, end_err, float(np.sqrt(np.mean(dp ** 2))), float(dp[-1]), status.fix_steps,
                     float(w.truth[-1, 0] - w.truth[0, 0]), saturated_steps)


def run_windows(model: ProcessModel, lateral: LateralConstraint, windows: list[McWindow], P0: np.ndarray,
                graph_on: set[int] = frozenset()) -> list[McOutcome]:
    """Return the outcomes of the SINDy estimators on ``windows`` (the graph on indices in ``graph_on``)."""
    out: list[McOutcome] = []
    ekf_x = {}
    for name, constraint in (("sindy_ekf", None), ("sindy_ekf_lateral", lateral)):
        runs = [EkfRun(f"mc{w.index} {name}", w.grid, w.inputs_for(model.dynamics), w.x0, P0, w.gnss) for w in windows]
        for w, (res, status) in zip(windows, guarded_ekf_batch(model, runs, lateral=constraint)):
            x = None if res is None else res.x
            out.append(outcome(w, name, x, None if res is None else res.P, status,
                               0 if res is None else res.saturated_steps))
            if name == "sindy_ekf" and status.status == "ok" and x is not None and len(x) == len(w.grid):
                ekf_x[w.index] = x
    for w in windows:
        if w.index not in graph_on:
            continue
        res, status = guarded(smooth_batch, model, w.grid, w.inputs_for(model.dynamics), w.x0, P0, w.gnss, x_init=ekf_x.get(w.index),
                              marginal_stride=10, name=f"mc{w.index} sindy_graph")
        out.append(outcome(w, "sindy_graph", None if res is None else res.x, None if res is None else res.P,
                           status))
    return out
