"""Scoring that does not depend on the candidate: reference states, reference windows, groups.

Every model (each candidate of the search, the baselines, the simulator's true dynamics) is
scored on the same 5 s windows from the same start states:

- **Reference states**: the body velocities of one smoothing chosen from the data's own noise,
  the discrepancy principle ``s = 1`` of eq. 5.68 (the spline may deviate from the poses by
  their noise and no more: the given pose sigmas, or a noise level estimated per segment and
  component from the poses' fourth differences when a track has none). Each segment gets its
  own splines, so the rule needs nothing but that segment's poses. Why this rule and not
  generalised cross-validation: ``docs/identification.md`` (GCV is known to interpolate
  correlated errors; the comparison against simulator truth over the simulator variants is
  still to be made).
- **Reference windows**: every window starts from the reference state (smoothed pose and
  velocities) at a pose sample; its pose truth is the measured poses interpolated linearly,
  never smoothed; its inputs are the recorded inputs, held from message to message, with the
  history before the window's start for a model's input dead time.
- **Groups** for cross-validation: the ``group`` of a run in campaign.yaml, else a date in the
  run's name (``2024_7_29``, ``2024-07-29``, ``20240729``), else the run itself.
  :func:`cv_folds` leaves one group out; with a single group it falls back to runs and says so,
  and a single run is cut into contiguous blocks (:func:`blocks_of_single_run`).

A candidate is trained on states at its own smoothing ``s`` (a hyperparameter of the
regression), but scored here.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, fields, replace
from typing import Sequence

import numpy as np

from groundfloor.errors import InputError
from groundfloor.input_chain import chain_inputs
from groundfloor.types import BodyStates, PoseTrack, TrajectoryRun
from identification.sindy.data import states_of_runs
from identification.sindy.evaluate import Windows, make_windows

log = logging.getLogger(__name__)

#: smoothing of the reference states: the discrepancy principle (residual = the poses' noise)
REFERENCE_SMOOTHING = 1.0
#: at most this many folds; more groups are dealt round-robin into this many
MAX_FOLDS = 10
#: a single train run is cut into blocks of at least this long for cross-validation (:func:`blocks_of_single_run`)
MIN_BLOCK_S = 60.0

_DATE = (re.compile(r"(?<!\d)(20\d\d)[_-](\d{1,2})[_-](\d{1,2})(?!\d)"),
         re.compile(r"(?<!\d)(20\d\d)(\d\d)(\d\d)(?!\d)"))


@dataclass(frozen=True)
class Reference:
    """Reference states of some runs, cut into gap-free segments, with their runs and groups."""

    states: tuple[BodyStates, ...]  # one per segment, at the reference smoothing
    names: tuple[str, ...]  # segment names (``run`` or ``run[k]``)
    run_index: np.ndarray  # (segments,) index of the run of each segment
    runs: tuple[TrajectoryRun, ...]
    smoothing: float

    @property
    def groups(self) -> np.ndarray:
        """Return the group label of each segment (:func:`run_group`)."""
        labels = [run_group(r) for r in self.runs]
        return np.array([labels[i] for i in self.run_index], dtype=object)

    def windows(self, window_s: float = 5.0, overlap: float = 0.5, dt: float = 0.02) -> Windows:
        """Return the reference windows of all segments (measured pose truth, recorded inputs)."""
        runs = [self.runs[i] for i in self.run_index]
        return make_windows(self.states, window_s, overlap, dt, self.names,
                            poses=[r.poses for r in runs], inputs=[r.inputs for r in runs])


def reference(runs: Sequence[TrajectoryRun], smoothing: float = REFERENCE_SMOOTHING) -> Reference:
    """Return the reference states of ``runs`` (see the module docstring)."""
    segs, names, index = states_of_runs(runs, smoothing)
    if not segs:
        raise InputError(f"runs {', '.join(r.name for r in runs)}: no segment of four or more poses")
    return Reference(states=tuple(segs), names=tuple(names), run_index=np.asarray(index), runs=tuple(runs),
                     smoothing=float(smoothing))


def select_windows(windows: Windows, keep: np.ndarray) -> Windows:
    """Return the windows where ``keep`` (boolean per window) holds, with everything they carry."""
    keep = np.asarray(keep, bool)
    return replace(windows, run=windows.run[keep], t0=windows.t0[keep], x0=windows.x0[keep],
                   u_half=windows.u_half[keep], pose_truth=windows.pose_truth[keep],
                   t0_run=None if windows.t0_run is None else windows.t0_run[keep])


def thin_windows(windows: Windows, n_max: int) -> Windows:
    """Return at most ``n_max`` of ``windows``, evenly spread over them (all when fewer)."""
    if windows.n_windows <= n_max:
        return windows
    keep = np.zeros(windows.n_windows, bool)
    keep[np.round(np.linspace(0, windows.n_windows - 1, n_max)).astype(int)] = True
    return select_windows(windows, keep)


def run_group(run: TrajectoryRun) -> str:
    """Return the group of a run: its ``group`` key, else the date in its name, else its name."""
    if run.group:
        return str(run.group)
    for pattern in _DATE:
        m = pattern.search(run.name)
        if m and 1 <= int(m[2]) <= 12 and 1 <= int(m[3]) <= 31:
            return f"{m[1]}-{int(m[2]):02d}-{int(m[3]):02d}"
    return run.name


@dataclass(frozen=True)
class Folds:
    """Cross-validation folds over segments: which fold holds each segment out, and how they were made."""

    fold: np.ndarray  # (segments,) fold index
    kind: str  # "leave-one-group-out", "k-fold by group", "leave-one-run-out", "k-fold by run" or "leave-one-block-out"
    note: str  # one line for logs and the model file
    held_out: tuple[tuple[str, ...], ...]  # per fold, the group (or run) labels held out

    @property
    def n_folds(self) -> int:
        """Number of folds."""
        return int(self.fold.max()) + 1


def cv_folds(groups: Sequence[str], runs: Sequence, max_folds: int = MAX_FOLDS) -> Folds:
    """Return folds that leave one group out (one-standard-error selection runs over them).

    ``groups`` and ``runs`` label each segment with its group and its run. Two or more groups:
    leave-one-group-out (k-fold by group, round-robin, above ``max_folds`` groups). One group:
    the fallback to runs (leave-one-run-out, or k-fold by run above ``max_folds`` runs), logged
    as a warning and said in :attr:`Folds.note`.

    Raises
    ------
    InputError
        If there is only one run: nothing to hold out.
    """
    groups = np.asarray(groups, dtype=object)
    runs = np.asarray(runs)
    uniq_g = list(dict.fromkeys(groups.tolist()))
    if len(uniq_g) >= 2:
        labels, unit = groups, "group"
        note = f"leave-one-group-out over {len(uniq_g)} groups ({', '.join(map(str, uniq_g))})"
    else:
        labels, unit = runs, "run"
        if len(np.unique(runs)) < 2:
            raise InputError(f"cross-validation: the train runs form one group ({uniq_g[0]}) of one run; "
                             "holding something out needs 2 runs")
        note = (f"one group only ({uniq_g[0]}): cross-validation falls back to leaving out runs "
                f"({len(np.unique(runs))} runs)")
        log.warning("cross-validation: %s", note)
    uniq = list(dict.fromkeys(labels.tolist()))
    index = np.array([uniq.index(v) for v in labels.tolist()])
    if len(uniq) > max_folds:
        fold = index % max_folds
        kind = f"k-fold by {unit}"
        note += f"; {max_folds} folds dealt round-robin"
    else:
        fold = index
        kind = f"leave-one-{unit}-out"
    n = int(fold.max()) + 1
    held = tuple(tuple(str(uniq[j]) for j in range(len(uniq)) if j % n == f) for f in range(n))
    return Folds(fold=fold, kind=kind, note=note, held_out=held)


def blocks_of_single_run(runs: Sequence[TrajectoryRun], n_blocks: int) -> tuple[tuple[TrajectoryRun, ...], str]:
    """Return ``runs`` as they are and "" when there are two or more; one run cut into contiguous
    time blocks (of at least :data:`MIN_BLOCK_S`, at most ``n_blocks``) and a note saying so.

    Cross-validation needs something to hold out. A user with one long recording gets blocked
    cross-validation (the standard for a time series: each block held out whole, its neighbours
    trained on), each block a group of its own so that :func:`cv_folds` leaves one block out. The
    blocks keep the run's whole input track (a model's dead time reaches back before a block).

    Raises
    ------
    InputError
        One run shorter than two blocks.
    """
    if len(runs) != 1:
        return tuple(runs), ""
    run = runs[0]
    t = np.asarray(run.poses.t, float)
    duration = float(t[-1] - t[0])
    k = min(int(n_blocks), int(duration // MIN_BLOCK_S))
    if k < 2:
        raise InputError(f"cross-validation: one train run ({run.name}, {duration:.0f} s); holding something out "
                         f"needs 2 runs or one of at least {2 * MIN_BLOCK_S:.0f} s")
    block = np.minimum(((t - t[0]) / duration * k).astype(int), k - 1)
    out = []
    for i in range(k):
        keep = block == i
        poses = PoseTrack(**{f.name: np.asarray(getattr(run.poses, f.name))[keep] for f in fields(PoseTrack)})
        out.append(replace(run, name=f"{run.name}:{i + 1}", poses=poses, group=f"{run.name}:{i + 1}"))
    note = (f"one train run ({run.name}, {duration:.0f} s): cross-validation leaves out each of {k} contiguous "
            f"blocks of {duration / k:.0f} s ({run.name}:1 to {run.name}:{k})")
    return tuple(out), note


def delayed_inputs(states: Sequence[BodyStates], dead_time_s, input_lag_s=(0.0, 0.0)) -> list[BodyStates]:
    """Return ``states`` with the inputs each seen ``dead_time_s = (d1, d2)`` later, ``u_i(t - d_i)``,
    after first-order lags ``input_lag_s`` (:func:`groundfloor.input_chain.chain_inputs`).

    The inputs at the pose times are interpolated linearly (the first sample holds before the
    segment): what the integral regression needs; the windows take the recorded inputs instead.
    """
    out = []
    for st in states:
        w = chain_inputs(st.t, st.t, st.inputs, dead_time_s, input_lag_s)
        out.append(replace(st, u1=w[:, 0], u2=w[:, 1]))
    return out
