"""Checks of a trajectory run's poses and inputs against the data contract (part 2), beside the
reader (:mod:`identification.preprocessing.trajectory`, which applies them): the pose gaps'
threshold, the time and yaw units, the poses beyond the inputs' span and the holes in the inputs.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from groundfloor.errors import InputError

log = logging.getLogger("identification.preprocessing.trajectory")  # the reader's warnings, under its name

#: a pose interval counts as a gap when longer than this many median intervals ...
GAP_FACTOR = 10.0
#: ... and than this many seconds (the 50 Hz trigger skips a pulse every 3 s on purpose)
GAP_MIN_S = 0.5
#: a median pose interval above this is a time unit other than seconds (a 5 s prediction window
#: would hold two poses): the data contract's t is in seconds
MAX_POSE_INTERVAL_S = 2.0
#: a 95th percentile of the yaw rate above this is yaw in degrees (57 times its radians) ...
MAX_YAW_RATE_RAD_S = 10.0
#: ... taken over this long, so that the noise of a fast pose rate stays well below it
YAW_RATE_BASELINE_S = 0.2
#: inputs silent this long while the poses go on are named (held, not cut: see :func:`input_holes`)
INPUT_HOLE_S = 2.0

def gap_threshold_s(t: np.ndarray) -> float:
    """Return the pose interval (s) above which a hole counts as a gap for stamps ``t``.

    ``max(GAP_MIN_S, GAP_FACTOR * median(diff(t)))``: 1 s for 10 Hz ICP poses, 0.5 s for
    50 Hz tracker poses.
    """
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size == 0:
        return GAP_MIN_S
    return float(max(GAP_MIN_S, GAP_FACTOR * np.median(dt)))


def check_time_unit(t: np.ndarray, path: Path) -> None:
    """Raise a one-line InputError when the poses ``t`` are more than :data:`MAX_POSE_INTERVAL_S`
    apart (median): a time unit other than the contract's seconds (milliseconds, nanoseconds)."""
    step = float(np.median(np.diff(t)))
    if step > MAX_POSE_INTERVAL_S:
        raise InputError(f"{path}: the poses are {step:.4g} s apart (median) over {np.ptp(t) / 3600:.3g} h: "
                         "t must be in seconds (milliseconds or nanoseconds?)")


def check_yaw_unit(t: np.ndarray, yaw: np.ndarray, path: Path) -> None:
    """Raise a one-line InputError when the yaw turns faster than a ground robot can: degrees.

    The yaw rate is taken over about :data:`YAW_RATE_BASELINE_S` (so that a high pose rate's noise
    does not count) within stretches without gaps; its 95th percentile (so that a glitch or a
    wrap at +-180 degrees does not count) above :data:`MAX_YAW_RATE_RAD_S` is yaw in degrees.
    The shared, default and variant campaigns stay at or below 1.02 rad/s (variant 1).
    """
    step = float(np.median(np.diff(t)))
    k = max(int(round(YAW_RATE_BASELINE_S / step)), 1) if step > 0 else 1
    if t.size <= k:
        return
    dt = t[k:] - t[:-k]
    ok = dt <= k * gap_threshold_s(t)
    if not ok.any():
        return
    rate = float(np.percentile(np.abs(yaw[k:] - yaw[:-k])[ok] / dt[ok], 95))
    if rate > MAX_YAW_RATE_RAD_S:
        raise InputError(f"{path}: column yaw turns at {rate:.3g} rad/s (95th percentile), faster than a ground robot "
                         "turns: yaw must be in radians (degrees?)")


def within_inputs(pc: dict[str, np.ndarray], t_i: np.ndarray, name: str, poses_path: Path
                   ) -> tuple[dict[str, np.ndarray], int]:
    """Return the pose columns ``pc`` within the inputs' time span, and the pose rows left out.

    Before its first and after its last sample an input track holds its end values; beyond
    :func:`gap_threshold_s` of the inputs' own stamps that hold is a guess (a recording that
    stopped, a logger started late), and a run whose inputs end half-way would otherwise be
    fitted and scored on motion under inputs it never recorded. Those poses are left out,
    counted and named with their duration.
    """
    t_p = pc["t"]
    hold_s = gap_threshold_s(t_i)
    inside = (t_p >= t_i[0] - hold_s) & (t_p <= t_i[-1] + hold_s)
    n_out = int(np.count_nonzero(~inside))
    if n_out == 0:
        return pc, 0
    if np.count_nonzero(inside) < 2:
        raise InputError(f"run {name}: fewer than 2 poses ({poses_path}) within the inputs' time span "
                         f"({t_i[0]:.3f} to {t_i[-1]:.3f} s)")
    kept = t_p[inside]
    log.warning("run %s: %d poses (%.1f s before the first input, %.1f s after the last) left out: "
                "the inputs there were not recorded", name, n_out, max(kept[0] - t_p[0], 0.0),
                max(t_p[-1] - kept[-1], 0.0))
    return {c: v[inside] for c, v in pc.items()}, n_out


def input_holes(t_i: np.ndarray, t_p: np.ndarray, name: str, inputs_path: Path) -> int:
    """Return the number of holes in the inputs longer than :data:`INPUT_HOLE_S` while the poses
    go on, named in a warning with the longest (the data are kept: a joystick that publishes on
    change leaves such holes while the stick is held, a recorder's pause leaves them too, and
    only the user can tell which)."""
    if t_i.size < 2:
        return 0
    dt = np.diff(t_i)
    holes = np.flatnonzero(dt > INPUT_HOLE_S)
    # a hole counts where poses were recorded inside it (a pause of the whole recording is a pose gap)
    inside = np.searchsorted(t_p, t_i[holes + 1], "left") - np.searchsorted(t_p, t_i[holes], "right")
    holes = holes[inside > 1]
    if holes.size:
        k = holes[np.argmax(dt[holes])]
        log.warning("run %s: %s holds its inputs through %d holes longer than %g s while the poses go on, the "
                    "longest %.1f s from t = %.3f s: a command held that long, or a recorder's pause",
                    name, inputs_path.name, len(holes), INPUT_HOLE_S, dt[k], t_i[k])
    return int(holes.size)
