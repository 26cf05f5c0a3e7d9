"""Where SINDy meets preprocessing: body states of trajectory runs, and the gap rule.

The SINDy wing (:mod:`identification.sindy`) fits and evaluates models on
:class:`~groundfloor.types.BodyStates`; how they come from poses and inputs (smoothing splines,
eqs. 5.64 to 5.68) and where a pose track has a hole are the preprocessing's business
(:mod:`identification.preprocessing`). This module is the only one of ``identification/sindy/``
that imports the preprocessing, and the preprocessing never imports SINDy: a change of either
side meets the other here.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from groundfloor.types import BodyStates, TrajectoryRun
from identification.preprocessing.smoothing_spline import noise_std_from_data
from identification.preprocessing.states import MIN_SEGMENT, body_states_segments
from identification.preprocessing.trajectory import gap_threshold_s

__all__ = ["body_states", "states_of_runs", "gap_threshold_s", "pose_noise_std"]


def body_states(run: TrajectoryRun, smoothing: float) -> list[BodyStates]:
    """Return the gap-free segments of ``run``'s body-frame states with spline smoothing ``smoothing``.

    Uses the preprocessing's :func:`identification.preprocessing.states.body_states_segments` (eqs. 5.64 to
    5.68), so nothing is integrated across a tracker dropout.
    """
    return [seg for seg in body_states_segments(run.poses, run.inputs, smoothing=smoothing)
            if len(seg.t) >= MIN_SEGMENT]


def states_of_runs(runs: Sequence[TrajectoryRun], smoothing: float) -> tuple[list[BodyStates], list[str], np.ndarray]:
    """Return the segments of all ``runs``, their names (``run`` or ``run[k]``) and run index per segment."""
    segs, names, groups = [], [], []
    for i, run in enumerate(runs):
        parts = body_states(run, smoothing)
        segs += parts
        names += [run.name] if len(parts) == 1 else [f"{run.name}[{k}]" for k in range(len(parts))]
        groups += [i] * len(parts)
    return segs, names, np.asarray(groups, dtype=int)


def pose_noise_std(run: TrajectoryRun) -> tuple[float, float]:
    """Return the noise standard deviations of ``run``'s measured positions (m) and yaw (rad).

    The poses' own sigmas where the campaign gives them (their median), else the noise level
    estimated from the data (:func:`identification.preprocessing.smoothing_spline.noise_std_from_data`,
    fourth differences), the rule the reference smoothing uses.
    """
    p = run.poses

    def sigma(values, stds) -> float:
        given = np.asarray(stds, float)
        given = given[np.isfinite(given)]
        return float(np.median(given)) if given.size else noise_std_from_data(values)

    return 0.5 * (sigma(p.x, p.x_std) + sigma(p.y, p.y_std)), sigma(p.yaw, p.yaw_std)
