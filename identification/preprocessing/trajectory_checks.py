"""Checks of a trajectory run's poses and inputs against the data contract (part 2), beside the
reader (:mod:`identification.preprocessing.trajectory`, which applies them): the pose gaps'
threshold, the time and yaw units, the poses beyond the inputs' span, the holes in the inputs and
the signs of the inputs against the motion.
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
#: a correlation of an input with the motion it commands below this is an axis against the contract's
#: sign (pooled over a campaign's runs; the shared, default and ten variant campaigns: +0.70 to +0.96)
MIN_SIGN_CORRELATION = -0.3
_SIGNS_SAID: set = set()  # (campaign.yaml, correlations) whose input signs were judged in this process

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


def pose_motion(poses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the middle times, forward speed and yaw rate of ``poses`` (a :class:`PoseTrack`) over
    about :data:`YAW_RATE_BASELINE_S`, within stretches without gaps (empty with too few poses)."""
    t, yaw = np.asarray(poses.t, float), np.asarray(poses.yaw, float)
    empty = np.zeros(0)
    step = float(np.median(np.diff(t))) if t.size >= 3 else 0.0
    k = max(int(round(YAW_RATE_BASELINE_S / step)), 1) if step > 0 else 1
    if t.size < 3 or t.size <= k:
        return empty, empty, empty
    dt = t[k:] - t[:-k]
    ok = (dt > 0) & (dt <= k * gap_threshold_s(t))
    heading = 0.5 * (yaw[k:] + yaw[:-k])
    speed = (np.cos(heading) * (poses.x[k:] - poses.x[:-k]) + np.sin(heading) * (poses.y[k:] - poses.y[:-k]))[ok] / dt[ok]
    return 0.5 * (t[k:] + t[:-k])[ok], speed, (yaw[k:] - yaw[:-k])[ok] / dt[ok]


def _motion_and_inputs(run) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return the forward speed and yaw rate of a run's poses (:func:`pose_motion`) and the inputs
    ``u1, u2`` held at the middle of each interval."""
    mid, speed, rate = pose_motion(run.poses)
    i = np.clip(np.searchsorted(run.inputs.t, mid, side="right") - 1, 0, run.inputs.t.size - 1)
    return speed, rate, run.inputs.u1[i], run.inputs.u2[i]


def input_sign_correlations(runs) -> dict[str, float]:
    """Return the correlation, pooled over ``runs``, of ``u1`` with the poses' forward speed and of
    ``u2`` with their yaw rate (NaN where an input or the motion does not vary)."""
    parts = [_motion_and_inputs(r) for r in runs]
    speed, rate, u1, u2 = (np.concatenate([p[j] for p in parts]) for j in range(4))
    out = {}
    for name, u, m in (("u1", u1, speed), ("u2", u2, rate)):
        ok = np.isfinite(u) & np.isfinite(m)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[name] = float(np.corrcoef(u[ok], m[ok])[0, 1]) if ok.sum() > 2 else float("nan")
    return out


def check_input_signs(runs, source: Path) -> dict[str, float]:
    """Warn where an input moves the robot against the data contract's sign; return the correlations.

    ``u1`` is positive forward and ``u2`` positive to the left (counter-clockwise seen from above,
    the yaw's sense). An input anti-correlated with its motion over the whole campaign (below
    :data:`MIN_SIGN_CORRELATION`) is an inverted axis, or a pose frame that is not the contract's:
    a yaw 180 degrees off the robot's forward axis (``u1``), a left-handed local frame such as
    north-east-down (``u2``). A model learns either sign; recorded GNSS and a gyro contradict a
    left-handed frame, and the diagnosis reads the inputs' signs as the contract gives them.
    """
    r = input_sign_correlations(runs)
    key = (str(source), tuple(round(v, 6) for v in r.values()))
    if key in _SIGNS_SAID:  # a command that opens the campaign twice (report) says it once
        return r
    _SIGNS_SAID.add(key)
    hints = {"u1": ("the forward speed of the poses", "positive forward",
                    "a throttle axis inverted, or a pose yaw 180 degrees off the robot's forward (x) axis?"),
             "u2": ("the yaw rate of the poses", "positive to the left (counter-clockwise, as the yaw)",
                    "a steering axis inverted, or a left-handed local frame (x north, y east, as NED)?")}
    for name, (motion, sense, why) in hints.items():
        if r[name] < MIN_SIGN_CORRELATION:
            log.warning("%s: %s and %s are anti-correlated (r = %.2f over all runs); the data contract has %s %s: %s",
                        source, name, motion, r[name], name, sense, why)
    return r
