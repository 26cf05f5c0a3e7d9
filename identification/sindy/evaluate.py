"""Multi-step prediction in the local frame, all windows at once (thesis 5.3.7 and 5.3.8).

The test runs are cut into windows of ``window_s`` (5 s) overlapping by 50 %. Each window
starts from the data (pose and body velocities at a sample), is driven by the recorded inputs
interpolated linearly, and is integrated over the combined local-frame ODE of eq. 5.75, the
six-state derivative of the model (any :class:`groundfloor.dynamics.Dynamics`: the SINDy model,
the baselines, the simulator's true dynamics as the oracle), with time counted from the start of
each window's run.

All windows (and, in the search, all candidate models) form one array ``(..., n_windows, 6)``
integrated by one fixed-step RK4 loop over time (eqs. 5.70, 5.71); the thesis's two-step method
(body velocities first, then the pose by explicit Euler, eq. 5.74) is there for comparison, and
:func:`evaluate_reference` integrates one ``solve_ivp`` per window as the thesis did.
Errors per window: position ``eps_p`` (eq. 5.76) and heading ``eps_h``; their RMS over windows
``s_p(t)``, ``s_h(t)`` (eqs. 5.77, 5.78) at the end of the window are ``pos_err_5s_m`` and
``yaw_err_5s_deg``.

Windows know their runs' input history (:class:`InputTrack`), so a model with input dead time
(``Dynamics.dead_time_s``) is fed ``u(t - d)`` from the recorded inputs before the window's
start; they may take their pose truth from the measured poses rather than from the states they
start from (:func:`make_windows` with ``poses``; the reference windows of
:mod:`identification.sindy.reference`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np
from scipy.integrate import solve_ivp

from groundfloor.dynamics import Dynamics, pose_rate, rk4_rollout_step
from groundfloor.errors import InputError
from groundfloor.types import BodyStates, InputSeries, PoseTrack
from identification.sindy.data import gap_threshold_s, states_of_runs
from identification.sindy.input_track import InputTrack

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Windows:
    """Prediction windows of several runs, sampled on one relative time grid.

    Attributes
    ----------
    run : (W,) index of the run of each window; ``t0`` (W,) start time (a sample time);
    ``t0_run`` (W,) the start time of the window in seconds since the start of its run.
    x0 : (W, 6) initial ``[x, y, psi, vx, vy, omega]`` from the data.
    t_rel : (n,) relative times ``0, dt, ..., window_s``.
    u_half : (W, 2n - 1, 2) inputs at ``t_rel`` and the midpoints between (for RK4), no dead time.
    pose_truth : (W, n, 3) ``[x, y, yaw]`` of the data at ``t0 + t_rel``.
    tracks : one :class:`InputTrack` per run index: the inputs for any dead time (:meth:`inputs_for`).
    """

    run: np.ndarray
    t0: np.ndarray
    x0: np.ndarray
    t_rel: np.ndarray
    u_half: np.ndarray
    pose_truth: np.ndarray
    run_names: tuple[str, ...] = ()
    t0_run: np.ndarray | None = None
    tracks: tuple[InputTrack, ...] = ()

    @property
    def n_windows(self) -> int:
        """Number of windows."""
        return len(self.t0)

    @property
    def t_half(self) -> np.ndarray:
        """Return the relative times of :attr:`u_half` ``(2n - 1,)``: the grid and its midpoints."""
        return np.arange(2 * len(self.t_rel) - 1) * (0.5 * (self.t_rel[1] - self.t_rel[0]))

    def inputs_for(self, delay_s=(0.0, 0.0), rate: bool = False, lag_s=(0.0, 0.0)) -> np.ndarray:
        """Return the inputs a model with dead times ``delay_s`` and input lags ``lag_s`` sees,
        ``(W, 2n - 1, 2)`` (:mod:`groundfloor.input_chain`).

        ``delay_s`` ``(2,)``, or ``(M, 2)`` for ``M`` models at once (then ``(M, W, 2n - 1, 2)``;
        ``lag_s`` is ``(2,)``, shared by them); ``rate`` returns their time derivatives instead.
        Zero dead times and lags give :attr:`u_half`.
        """
        d = np.asarray(delay_s, dtype=float)
        lag = np.asarray(lag_s, dtype=float)
        if not rate and not np.any(d) and not np.any(lag):
            return self.u_half if d.ndim == 1 else np.broadcast_to(self.u_half, d.shape[:1] + self.u_half.shape)
        if not self.tracks:
            raise InputError("windows without input tracks cannot apply an input dead time or lag")
        out = np.empty(d.shape[:-1] + self.u_half.shape)
        for r, sel, tq in self.run_queries:
            track = self.tracks[r].lagged(lag)
            out[..., sel, :, :] = track.rate(tq, d) if rate else track.at(tq, d)
        return out

    @cached_property
    def run_queries(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Return per run index its windows (indices) and their :attr:`t_half` times since the run's start."""
        t0 = self.t0_run if self.t0_run is not None else np.zeros_like(self.t0)
        return [(r, sel, t0[sel][:, None] + self.t_half[None, :])
                for r in np.unique(self.run) for sel in [np.flatnonzero(self.run == r)]]


@dataclass(frozen=True)
class EvaluationResult:
    """Multi-step prediction errors of one model (thesis 5.3.8, figs. 5.11 and 7.8)."""

    t_rel: np.ndarray  # (n,)
    s_p: np.ndarray  # (n,) RMS position error over windows, m (eq. 5.77)
    s_h: np.ndarray  # (n,) RMS heading error over windows, rad (eq. 5.78)
    eps_p: np.ndarray  # (W, n) position error per window, m (eq. 5.76)
    eps_h: np.ndarray  # (W, n) signed heading error per window, rad
    method: str
    name: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def n_windows(self) -> int:
        """Number of windows."""
        return self.eps_p.shape[0]

    @property
    def pos_err_5s_m(self) -> float:
        """RMS position error at the end of the windows, m."""
        return float(self.s_p[-1])

    @property
    def yaw_err_5s_deg(self) -> float:
        """RMS heading error at the end of the windows, degrees."""
        return float(np.degrees(self.s_h[-1]))

    def summary(self) -> dict:
        """Return the INTERFACES.md keys ``pos_err_5s_m``, ``yaw_err_5s_deg``, ``n_windows``."""
        return {"pos_err_5s_m": self.pos_err_5s_m, "yaw_err_5s_deg": self.yaw_err_5s_deg,
                "n_windows": int(self.n_windows)}


def make_windows(states: Sequence[BodyStates], window_s: float = 5.0, overlap: float = 0.5, dt: float = 0.02,
                 names: Sequence[str] | None = None, max_gap_s: float | None = None,
                 poses: Sequence[PoseTrack] | None = None, inputs: Sequence[InputSeries] | None = None) -> Windows:
    """Return the windows of ``window_s`` with ``overlap`` over all runs (thesis 5.3.8).

    Windows start at the data sample nearest to every ``window_s * (1 - overlap)``; windows
    that cross the end of a run or a data gap longer than ``max_gap_s`` are left out. The
    default gap is the data's own, per run: :func:`identification.sindy.data.gap_threshold_s`
    (``max(0.5 s, 10 x`` the median interval), so 10 Hz poses with a 0.5 s hole keep their windows).

    Each window starts from the state of ``states`` at its first sample. Its pose truth is the
    states' own poses, or, given ``poses`` (one pose track per entry of ``states``, e.g. the
    measured poses of the segment's run), those poses interpolated linearly, never smoothed.
    Its inputs are the states' inputs interpolated linearly, or, given ``inputs`` (the recorded
    inputs of the segment's run), those held from sample to sample (:class:`InputTrack`, averaged
    over ``dt``); either way a model's input dead time reads the history before the window.

    Raises
    ------
    InputError
        If no run is long enough for a single window.
    """
    names = tuple(names) if names is not None else tuple(f"#{i}" for i in range(len(states)))
    if not 0 <= overlap < 1:
        raise InputError(f"overlap={overlap}: must be in [0, 1)")
    n = int(round(window_s / dt))
    t_rel = np.arange(n + 1) * dt
    t_half = np.arange(2 * n + 1) * (dt / 2)
    runs, t0s, t0_runs, x0s, us, truths, tracks = [], [], [], [], [], [], []
    for i, st in enumerate(states):
        t = np.asarray(st.t, dtype=float)
        tr = t - t[0]
        if inputs is not None:
            ins = inputs[i]
            tracks.append(InputTrack(np.asarray(ins.t, float) - t[0], np.column_stack([ins.u1, ins.u2]), "zoh", dt))
        else:
            tracks.append(InputTrack(tr, np.column_stack([st.u1, st.u2]), "linear"))
        if len(t) < 2 or t[-1] - t[0] < window_s:
            continue
        # chosen in time since the run's start, so that the windows do not depend on the time base
        # (UTC stamps near 1.7e9 s resolve 2.4e-7 s: a window ending on the run's last sample was kept
        # or dropped by the base, and the diagnosis compared 8 windows with 9)
        nominal = np.arange(0.0, tr[-1] - window_s + 1e-9, window_s * (1 - overlap))
        k = np.clip(np.searchsorted(tr, nominal), 0, len(t) - 1)
        k = np.unique(k[tr[k] + window_s <= tr[-1] + 1e-9])
        gap_s = gap_threshold_s(t) if max_gap_s is None else max_gap_s
        big_gap = np.concatenate([[0], np.cumsum(np.diff(t) > gap_s)])
        k_end = np.searchsorted(tr, tr[k] + window_s)
        k = k[big_gap[np.minimum(k_end, len(t) - 1)] == big_gap[k]]
        if not len(k):
            continue
        tq = t[k][:, None] - t[0] + t_half[None, :]  # relative to run start: keeps float precision
        us.append(tracks[-1].at(tq))
        tq = tq[:, ::2]
        if poses is None:
            tp, px, py, pyaw = tr, st.x, st.y, st.yaw
        else:
            p = poses[i]
            ok = np.isfinite(p.t) & np.isfinite(p.x) & np.isfinite(p.y) & np.isfinite(p.yaw)
            tp, px, py, pyaw = np.asarray(p.t, float)[ok] - t[0], p.x[ok], p.y[ok], np.unwrap(p.yaw[ok])
        truths.append(np.stack([np.interp(tq, tp, px), np.interp(tq, tp, py), np.interp(tq, tp, pyaw)], -1))
        x0s.append(np.column_stack([st.x[k], st.y[k], st.yaw[k], st.vx[k], st.vy[k], st.omega[k]]))
        runs.append(np.full(len(k), i))
        t0s.append(t[k])
        t0_runs.append(t[k] - t[0])
    if not t0s:
        raise InputError(f"runs {', '.join(names)}: none is longer than one {window_s:g} s window")
    return Windows(run=np.concatenate(runs), t0=np.concatenate(t0s), x0=np.vstack(x0s), t_rel=t_rel,
                   u_half=np.concatenate(us), pose_truth=np.concatenate(truths), run_names=names,
                   t0_run=np.concatenate(t0_runs), tracks=tuple(tracks))


def rollout(model: Dynamics, windows: Windows, method: str = "rk4", batch_shape: tuple[int, ...] = ()) -> np.ndarray:
    """Return predicted states ``(*batch_shape, W, n, 6)`` of all windows integrated together.

    ``method="rk4"`` integrates the model's six-state derivative (eq. 5.75) with classical RK4
    (:func:`groundfloor.dynamics.rk4_rollout_step`, eqs. 5.70, 5.71); ``"euler2"`` is the thesis's
    two-step method: body velocities by RK4 on their own (the pose held), then the pose by
    explicit Euler with the velocities that move it at the step's start (eqs. 5.72 to 5.74).
    ``batch_shape`` lets a model with stacked coefficients predict for many models at once.
    Time passed to the model: seconds since the start of each window's run. The model sees the
    recorded inputs delayed by its ``dead_time_s`` (``(2,)``, or ``(*batch_shape, 2)`` for a
    stacked model with one dead time per model).
    """
    if method not in ("rk4", "euler2"):
        raise InputError(f"method {method!r}: expected 'rk4' or 'euler2'")
    dt = windows.t_rel[1] - windows.t_rel[0]
    n = len(windows.t_rel)
    s = np.broadcast_to(windows.x0, batch_shape + windows.x0.shape).copy()
    t0 = windows.t0_run if windows.t0_run is not None else np.zeros_like(windows.t0)
    out = np.empty(s.shape[:-1] + (n, 6))
    out[..., 0, :] = s
    delay = np.asarray(model.dead_time_s, dtype=float)
    lag = np.asarray(getattr(model, "input_lag_s", (0.0, 0.0)), dtype=float)
    u_half = windows.inputs_for(delay.reshape(-1, 2), lag_s=lag).reshape(delay.shape[:-1] + windows.u_half.shape) \
        if delay.ndim > 1 else windows.inputs_for(delay, lag_s=lag)
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(n - 1):
            u0, um, u1 = (u_half[..., 2 * i + j, :] for j in range(3))
            t = t0 + windows.t_rel[i]
            if method == "rk4":
                s = rk4_rollout_step(model, s, u0, um, u1, t, dt)
            else:
                pose_next = s[..., :3] + dt * pose_rate(s[..., 2], model.pose_velocity(s, u0))
                v = s[..., 3:]

                def accel(v_stage, u, tt):
                    return model.accel(np.concatenate([s[..., :3], v_stage], -1), u, tt)

                k1 = accel(v, u0, t)
                k2 = accel(v + dt / 2 * k1, um, t + dt / 2)
                k3 = accel(v + dt / 2 * k2, um, t + dt / 2)
                k4 = accel(v + dt * k3, u1, t + dt)
                s = np.concatenate([pose_next, v + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], -1)
            out[..., i + 1, :] = s
    return out


def errors_from_rollout(pred: np.ndarray, windows: Windows) -> tuple[np.ndarray, np.ndarray]:
    """Return ``eps_p`` and signed ``eps_h`` ``(..., W, n)``; diverged predictions give ``inf``."""
    d = pred[..., :3] - windows.pose_truth
    with np.errstate(invalid="ignore"):
        eps_p = np.hypot(d[..., 0], d[..., 1])
        eps_h = (d[..., 2] + np.pi) % (2 * np.pi) - np.pi
    eps_p = np.where(np.isfinite(eps_p), eps_p, np.inf)
    eps_h = np.where(np.isfinite(eps_h), eps_h, np.inf)
    return eps_p, eps_h


def rms_over_windows(eps: np.ndarray) -> np.ndarray:
    """Return ``sqrt(mean(eps^2))`` over the window axis (-2): eqs. 5.77, 5.78."""
    with np.errstate(over="ignore"):
        return np.sqrt(np.mean(np.square(eps), axis=-2))


def _six_states(states: Sequence[BodyStates]) -> tuple[np.ndarray, np.ndarray]:
    """Return the six states ``(n, 6)`` and inputs ``(n, 2)`` of all samples of ``states``."""
    x6 = np.vstack([np.column_stack([st.x, st.y, st.yaw, st.vx, st.vy, st.omega]) for st in states])
    return x6, np.vstack([st.inputs for st in states])


def evaluate_model(model: Dynamics, states: Sequence[BodyStates] | Windows, method: str = "rk4", names=None,
                   window_s: float = 5.0, overlap: float = 0.5, dt: float = 0.02, name: str = "") -> EvaluationResult:
    """Return the multi-step prediction errors of ``model`` on ``states`` (thesis 5.3.8).

    ``model`` is any :class:`groundfloor.dynamics.Dynamics`. Given runs (not windows), warns
    when the test data leave the model's training envelope (``model.warn_outside_envelope``).
    """
    windows = states if isinstance(states, Windows) else make_windows(states, window_s, overlap, dt, names)
    if not isinstance(states, Windows):
        model.warn_outside_envelope(*_six_states(states), name="test runs")
    pred = rollout(model, windows, method)
    eps_p, eps_h = errors_from_rollout(pred, windows)
    return EvaluationResult(t_rel=windows.t_rel, s_p=rms_over_windows(eps_p), s_h=rms_over_windows(eps_h),
                            eps_p=eps_p, eps_h=eps_h, method=method, name=name or model.name)


def evaluate_reference(model: Dynamics, states: Sequence[BodyStates], names=None, window_s: float = 5.0,
                       overlap: float = 0.5, dt: float = 0.02, rtol: float = 1e-8,
                       atol: float = 1e-10) -> EvaluationResult:
    """Return the same errors as :func:`evaluate_model` with one ``solve_ivp`` (RK45) per window.

    This is the thesis's way (section 5.3.7, adaptive Dormand-Prince per window), kept as the
    reference the batched integration is checked and timed against. Same windows, same linear
    input interpolation, same combined ODE.
    """
    windows = make_windows(states, window_s, overlap, dt, names)
    n = len(windows.t_rel)
    pred = np.empty((windows.n_windows, n, 6))
    delay = np.asarray(model.dead_time_s, dtype=float)
    lag = getattr(model, "input_lag_s", (0.0, 0.0))
    for w in range(windows.n_windows):  # deliberately one solve per window: the reference
        track = windows.tracks[windows.run[w]].lagged(lag)
        t0 = windows.t0_run[w]

        def rhs(tt, s, track=track, t0=t0):
            return model.derivative(s, track.at(np.array(t0 + tt), delay), t0 + tt)

        sol = solve_ivp(rhs, (0.0, windows.t_rel[-1]), windows.x0[w], t_eval=windows.t_rel, rtol=rtol,
                        atol=atol, method="RK45")
        pred[w, : sol.y.shape[1]] = sol.y.T
        pred[w, sol.y.shape[1]:] = np.nan
    eps_p, eps_h = errors_from_rollout(pred, windows)
    return EvaluationResult(t_rel=windows.t_rel, s_p=rms_over_windows(eps_p), s_h=rms_over_windows(eps_h),
                            eps_p=eps_p, eps_h=eps_h, method="solve_ivp", name=model.name)


def evaluate_on_runs(models: dict, runs, smoothing: float, methods=("rk4",)) -> dict[str, dict[str, EvaluationResult]]:
    """Return ``{model name: {method: EvaluationResult}}`` on the gap-free segments of ``runs``.

    ``runs`` are :class:`~groundfloor.types.TrajectoryRun` (the test runs); their body
    states are computed with smoothing ``smoothing`` (the model's ``s``), so every model sees
    the same windows.
    """
    segs, names, _ = states_of_runs(runs, smoothing)
    windows = make_windows(segs, names=names)
    out = {}
    for name, model in models.items():
        model.warn_outside_envelope(*_six_states(segs), name=f"test runs ({name})")
        out[name] = {m: evaluate_model(model, windows, method=m, name=name) for m in methods}
    return out
