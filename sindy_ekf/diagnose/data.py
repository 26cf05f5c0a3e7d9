"""Runs of one split stacked into flat arrays, with the integration windows of eqs. 5.55 and 5.56.

The diagnosis scores every candidate mechanism on the integral regression of the thesis
(section 5.3.5): over a window ``[t_j, t_j + tau]`` the change of the body velocities
``Delta x_j`` (eq. 5.55) is compared with the integral of the model's accelerations (eq. 5.56).
All runs of a split are concatenated; the trapezoidal increments across a run boundary are set
to zero, so one cumulative sum integrates every run and a window is one subtraction. Windows
start every ``stride_s`` (neighbouring windows share almost all their samples; a stride of
0.1 s loses nothing the regression can see and divides the cost by five at 50 Hz).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from groundfloor.errors import InputError
from groundfloor.input_chain import sees_recorded_inputs
from groundfloor.types import BodyStates
from identification.sindy.library import LIBRARY_INPUT_NAMES, LIBRARY_STATE_NAMES
from identification.sindy.regression import MAX_WINDOW_STEP_S, check_pose_spacing
from identification.sindy.reference import delayed_inputs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Split:
    """Samples of several runs of one split, stacked, with window start and end indices.

    Attributes
    ----------
    names : run names; ``run`` (N,) index into them per sample.
    t_run : (N,) time since the start of the sample's run, s.
    pose_local : (N, 3) ``[x, y, psi]`` in the local frame (psi unwrapped).
    v_body : (N, 3) ``[vx, vy, omega]``.
    u : (N, 2) recorded inputs ``[u1, u2]``.
    dt_next : (N,) step to the next sample of the same run, 0 at a run's last sample.
    start, end : (p,) sample indices of the windows.
    """

    names: tuple[str, ...]
    run: np.ndarray
    t_run: np.ndarray
    pose_local: np.ndarray
    v_body: np.ndarray
    u: np.ndarray
    dt_next: np.ndarray
    start: np.ndarray
    end: np.ndarray
    tau: float

    @property
    def n_windows(self) -> int:
        """Number of integration windows."""
        return len(self.start)

    @property
    def window_run(self) -> np.ndarray:
        """(p,) run index of every window."""
        return self.run[self.start]

    @property
    def delta_v(self) -> np.ndarray:
        """(p, 3) change of the body velocities over each window (eq. 5.55)."""
        return self.v_body[self.end] - self.v_body[self.start]

    @property
    def sample_interval_s(self) -> float:
        """Median step between samples of the same run, s (0 without any)."""
        step = self.dt_next[self.dt_next > 0]
        return float(np.median(step)) if step.size else 0.0

    @property
    def x6(self) -> np.ndarray:
        """(N, 6) full state ``[x, y, psi, vx, vy, omega]``."""
        return np.concatenate([self.pose_local, self.v_body], axis=-1)

    def integrate(self, values: np.ndarray) -> np.ndarray:
        """Return window integrals ``(..., p, m)`` of per-sample ``values (..., N, m)`` (eq. 5.56).

        Trapezoidal rule as one cumulative sum over all runs; increments across run boundaries
        are zero because ``dt_next`` is zero there.
        """
        cum = np.empty(values.shape)  # in place: the floor patch's thousands of candidates are memory-bound
        cum[..., 0, :] = 0.0
        inc = cum[..., 1:, :]
        np.add(values[..., :-1, :], values[..., 1:, :], out=inc)
        inc *= 0.5  # exact, so the same increments as 0.5 * (a + b) * dt to the last bit
        inc *= self.dt_next[:-1, None]
        np.cumsum(inc, axis=-2, out=inc)
        return cum[..., self.end, :] - cum[..., self.start, :]

    def integrate_sparse(self, values: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Return :meth:`integrate` of per-sample values that are zero but at the samples ``idx`` (sorted),
        from ``values (..., len(idx), m)`` there: the cumulative sum runs over the increments that touch
        them alone. The same window integrals to the last bit: the increments left out are zero, and
        adding zero leaves a running sum as it is."""
        n, lead, m = len(self.run), values.shape[:-2], values.shape[-1]
        if not len(idx):
            return np.zeros(lead + (self.n_windows, m))
        j = np.union1d(idx, idx - 1)
        j = j[(j >= 0) & (j < n - 1)]  # increments i -> i + 1 with a sample of idx at either end
        inc, at_next = np.zeros(lead + (len(j), m)), np.zeros(lead + (len(j), m))  # the values at j and j + 1
        for out, k in ((inc, j), (at_next, j + 1)):
            pos = np.minimum(np.searchsorted(idx, k), len(idx) - 1)
            given = idx[pos] == k
            out[..., given, :] = values[..., pos[given], :]
        np.add(inc, at_next, out=inc)
        inc *= 0.5  # as in integrate, to the last bit
        inc *= self.dt_next[j, None]
        cum = np.zeros(lead + (len(j) + 1, m))
        np.cumsum(inc, axis=-2, out=cum[..., 1:, :])
        # the running sum before sample k: over the increments j < k
        return cum[..., np.searchsorted(j, self.end), :] - cum[..., np.searchsorted(j, self.start), :]

    def select_windows(self, keep: np.ndarray) -> "Split":
        """Return the same samples with only the windows where ``keep (p,)`` is true."""
        return replace(self, start=self.start[keep], end=self.end[keep])

    def windows_inside(self, inside: np.ndarray) -> np.ndarray:
        """Return ``(p,)`` true for windows all of whose samples have ``inside (N,)`` true."""
        bad = np.concatenate([[0], np.cumsum(~inside)])
        return bad[self.end + 1] - bad[self.start] == 0

    def runs_slices(self) -> list[slice]:
        """Return the slice of samples of every run, in order."""
        edges = np.flatnonzero(np.diff(self.run)) + 1
        bounds = np.concatenate([[0], edges, [len(self.run)]])
        return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]


def split_from_states(states: Sequence[BodyStates], names: Sequence[str], tau: float, stride_s: float = 0.1,
                      max_gap_s: float = MAX_WINDOW_STEP_S, what: str = "runs") -> Split:
    """Return the runs ``states`` stacked as a :class:`Split` with windows of ``tau`` seconds.

    Windows that would cross a run's end or a gap longer than ``max_gap_s`` are dropped.

    Raises
    ------
    InputError
        If no run holds a single window, or a run has non-finite or non-increasing samples.
    """
    if not len(states):
        raise InputError(f"{what}: no runs")
    check_pose_spacing([st.t for st in states], names, what, max_gap_s)
    cols = {k: [] for k in ("run", "t", "pose", "v", "u", "dt")}
    starts, ends, offset = [], [], 0
    for i, (st, name) in enumerate(zip(states, names)):
        t = np.asarray(st.t, dtype=float) - float(st.t[0])
        arrays = np.column_stack([t, st.x, st.y, st.yaw, st.vx, st.vy, st.omega, st.u1, st.u2])
        if not np.all(np.isfinite(arrays)):
            bad = ("t", "x", "y", "yaw", "vx", "vy", "omega", "u1", "u2")[int(np.argmax(~np.isfinite(arrays).all(0)))]
            raise InputError(f"run {name}: column {bad} has missing or non-finite values")
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise InputError(f"run {name}: times are not strictly increasing")
        dt = np.append(np.diff(t), 0.0)
        n_stride = max(int(round(stride_s / np.median(dt[:-1]))), 1) if len(t) > 2 else 1
        k = np.arange(0, len(t), n_stride)
        k_end = np.searchsorted(t, t[k] + tau * (1 - 1e-9))
        gap_id = np.concatenate([[0], np.cumsum(np.diff(t) > max_gap_s)])
        ok = k_end < len(t)
        ok[ok] &= gap_id[k_end[ok]] == gap_id[k[ok]]
        starts.append(k[ok] + offset)
        ends.append(k_end[ok] + offset)
        cols["run"].append(np.full(len(t), i))
        cols["t"].append(t)
        cols["pose"].append(arrays[:, 1:4])
        cols["v"].append(arrays[:, 4:7])
        cols["u"].append(arrays[:, 7:9])
        cols["dt"].append(dt)
        offset += len(t)
    start = np.concatenate(starts).astype(np.intp)
    if not len(start):
        raise InputError(f"{what} {', '.join(names)}: no run is longer than one {tau:g} s integration window")
    return Split(names=tuple(names), run=np.concatenate(cols["run"]), t_run=np.concatenate(cols["t"]),
                 pose_local=np.vstack(cols["pose"]), v_body=np.vstack(cols["v"]), u=np.vstack(cols["u"]),
                 dt_next=np.concatenate(cols["dt"]), start=start, end=np.concatenate(ends).astype(np.intp),
                 tau=float(tau))


def in_envelope(model, split, margin: float = 0.1):
    """Return ``split`` without the windows that leave the model's training envelope (widened by
    ``margin`` of its width): a model cannot be judged where it was never trained, and its
    extrapolation there (cubic terms) would swamp every residual."""
    env = getattr(model, "envelope", None)
    if not env:
        return split
    z = np.concatenate([split.v_body, split.u], axis=-1)
    names = LIBRARY_STATE_NAMES + LIBRARY_INPUT_NAMES
    lo = np.array([env.get(v, [-np.inf, np.inf])[0] for v in names])
    hi = np.array([env.get(v, [-np.inf, np.inf])[1] for v in names])
    pad = margin * (hi - lo)
    keep = split.windows_inside(np.all((z >= lo - pad) & (z <= hi + pad), axis=1))
    if keep.sum() < 0.2 * len(keep):
        log.warning("%s: only %d of %d windows inside the model's training envelope; using all",
                    ", ".join(split.names), int(keep.sum()), len(keep))
        return split
    return split.select_windows(keep)


def model_split(model, states: Sequence[BodyStates], names: Sequence[str], tau: float, what: str = "runs") -> Split:
    """Return the runs as the model sees them: inputs delayed by its dead time, windows in its envelope.

    A model with input dead time ``(d1, d2)`` (``Dynamics.dead_time_s``) responds to
    ``u_i(t - d_i)`` (through its input lags ``Dynamics.input_lag_s`` when it has them); every family, the response lag and the residual structure are judged against
    that, so a mechanism is what the data hold beyond the model, not the model's own dead time
    found again (an identified wheels model with 84/141 ms read as an unexplained lag otherwise).
    """
    shifted = list(states) if sees_recorded_inputs(model) else delayed_inputs(
        states, getattr(model, "dead_time_s", (0.0, 0.0)), getattr(model, "input_lag_s", (0.0, 0.0)))
    return in_envelope(model, split_from_states(shifted, names, tau, what=what))

