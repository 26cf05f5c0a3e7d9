"""Body-frame velocities and inputs at the pose times (thesis 5.3.4, 5.3.5, eqs. 5.64 to 5.68).

The pose components x, y and yaw are approximated by weighted cubic smoothing splines, whose
analytic derivatives give the local-frame velocities; these are rotated into the body frame
(eqs. 5.64 to 5.66)::

    vx = cos(yaw) x_dot + sin(yaw) y_dot,   vy = -sin(yaw) x_dot + cos(yaw) y_dot,   omega = yaw_dot

The splines and the meaning of the smoothing factor ``s`` (eq. 5.68, normalised by the pose
sigmas, or by a noise level estimated from the data when a track has none) are
:mod:`identification.preprocessing.smoothing_spline`'s; by default each segment's ends are
continued before the final fit (``pad_ends``), which removes the natural spline's end bias.

Inputs
------
The robot acts on the last joystick message it received, so the default ``input_hold="zoh"``
samples the inputs with a zero-order hold (before the first message: the first message).
The thesis interpolated linearly (``input_hold="linear"``); between irregular messages that
anticipates a command change the motors have not seen yet.

Gaps
----
Poses with NaN are dropped and the track is split where consecutive poses are further apart
than ``max_gap_s`` (default :func:`identification.preprocessing.trajectory.gap_threshold_s`); each segment
gets its own splines, and nothing is interpolated across a hole: samples in a gap, or in a
segment of fewer than four poses, are NaN. :func:`body_states_segments` returns the segments
separately.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from groundfloor.errors import InputError
from groundfloor.types import BodyStates, InputSeries, PoseTrack
from identification.preprocessing.smoothing_spline import (
    noise_std_from_data,
    smoothing_spline,
)
from identification.preprocessing.trajectory import gap_segments

log = logging.getLogger(__name__)

#: fewest poses in a segment for a cubic spline
MIN_SEGMENT = 4


def _component_std(std: np.ndarray, values: np.ndarray, name: str) -> np.ndarray:
    """Return per-sample sigmas: given ones, NaNs filled by their median, or estimated."""
    std = np.asarray(std, dtype=float)
    good = np.isfinite(std) & (std > 0)
    if good.any():
        if not good.all():
            std = np.where(good, std, np.median(std[good]))
        return std
    sigma = noise_std_from_data(values)
    log.info("states: no %s sigmas, using %.3g estimated from the data", name, sigma)
    return np.full(values.shape, sigma)


@dataclass(frozen=True)
class _Segment:
    """Splines of one gap-free stretch of poses."""

    t_start: float
    t_stop: float
    x: CubicSpline
    y: CubicSpline
    yaw: CubicSpline
    t: np.ndarray  # pose times of the segment


def _check_inputs(poses: PoseTrack, inputs: InputSeries, smoothing: float, input_hold: str) -> None:
    """Raise InputError naming the culprit for bad pose/input series or options."""
    if input_hold not in ("zoh", "linear"):
        raise InputError(f"input_hold: must be 'zoh' or 'linear', got {input_hold!r}")
    if smoothing is None or not np.isfinite(smoothing) or smoothing < 0:
        raise InputError(f"smoothing: must be a finite value >= 0, got {smoothing!r}")
    n = np.asarray(poses.t).size
    for key in ("x", "y", "yaw"):
        if np.asarray(getattr(poses, key)).size != n:
            raise InputError(f"poses.{key}: {np.asarray(getattr(poses, key)).size} samples, poses.t has {n}")
    if np.any(np.diff(poses.t) <= 0):
        i = int(np.flatnonzero(np.diff(poses.t) <= 0)[0])
        raise InputError(f"poses.t: stamps not strictly increasing at sample {i + 1}")
    m = np.asarray(inputs.t).size
    if m == 0:
        raise InputError("inputs: no input samples")
    for key in ("u1", "u2"):
        if np.asarray(getattr(inputs, key)).size != m:
            raise InputError(f"inputs.{key}: {np.asarray(getattr(inputs, key)).size} samples, inputs.t has {m}")
    if np.any(np.diff(inputs.t) < 0):
        i = int(np.flatnonzero(np.diff(inputs.t) < 0)[0])
        raise InputError(f"inputs.t: stamps going backwards at sample {i + 1}")


def _fit_segments(poses: PoseTrack, smoothing: float, max_gap_s: float | None,
                  pad_ends: bool = True) -> list[_Segment]:
    """Return the x, y, yaw splines of every gap-free segment with at least MIN_SEGMENT poses."""
    t = np.asarray(poses.t, dtype=float)
    x, y, yaw = (np.asarray(v, dtype=float) for v in (poses.x, poses.y, poses.yaw))
    ok = np.isfinite(t) & np.isfinite(x) & np.isfinite(y) & np.isfinite(yaw)
    if ok.sum() < MIN_SEGMENT:
        raise InputError(f"poses: only {int(ok.sum())} finite poses (need {MIN_SEGMENT})")
    t, x, y = t[ok], x[ok], y[ok]
    yaw = np.unwrap(yaw[ok])  # wrapped input is fine; unwrapped stays as it is
    stds = [_component_std(np.broadcast_to(np.asarray(std, float), ok.shape)[ok], v, name)
            for std, v, name in ((poses.x_std, x, "x"), (poses.y_std, y, "y"), (poses.yaw_std, yaw, "yaw"))]
    segments = []
    t_base = t[0]
    for start, stop in gap_segments(t, max_gap_s):
        if stop - start < MIN_SEGMENT:
            log.info("states: segment of %d poses at t=%.3f skipped (fewer than %d)",
                     stop - start, t[start], MIN_SEGMENT)
            continue
        sl = slice(start, stop)
        tt = t[sl] - t_base  # relative times: sub-microsecond steps survive at UTC epochs
        splines = [smoothing_spline(tt, v[sl], sd[sl], smoothing, pad_ends)[0] for v, sd in zip((x, y, yaw), stds)]
        segments.append(_Segment(t_start=t[start], t_stop=t[stop - 1], x=splines[0], y=splines[1],
                                 yaw=splines[2], t=t[sl]))
    if len(segments) > 1:
        log.info("states: pose track split into %d segments at gaps", len(segments))
    return segments


def _sample_inputs(inputs: InputSeries, t_eval: np.ndarray, input_hold: str) -> tuple[np.ndarray, np.ndarray]:
    """Return u1, u2 at ``t_eval`` by zero-order hold or linear interpolation."""
    t_in = np.asarray(inputs.t, dtype=float)
    u = np.column_stack([inputs.u1, inputs.u2]).astype(float)
    if input_hold == "zoh":
        idx = np.clip(np.searchsorted(t_in, t_eval, side="right") - 1, 0, t_in.size - 1)
        out = u[idx]
    else:
        out = np.column_stack([np.interp(t_eval, t_in, u[:, k]) for k in range(2)])
    return out[:, 0], out[:, 1]


def _states_at(segments: list[_Segment], t_eval: np.ndarray, t_base: float) -> np.ndarray:
    """Return (n, 6) [x, y, yaw, vx, vy, omega] at ``t_eval``; NaN outside every segment."""
    out = np.full((t_eval.size, 6), np.nan)
    for seg in segments:
        inside = (t_eval >= seg.t_start) & (t_eval <= seg.t_stop)
        if not inside.any():
            continue
        tt = t_eval[inside] - t_base
        yaw = seg.yaw(tt)
        x_dot, y_dot = seg.x(tt, 1), seg.y(tt, 1)
        c, s = np.cos(yaw), np.sin(yaw)
        out[inside] = np.column_stack([seg.x(tt), seg.y(tt), yaw, c * x_dot + s * y_dot,
                                       -s * x_dot + c * y_dot, seg.yaw(tt, 1)])  # eqs. 5.64-5.66
    return out


def body_states_from_poses(poses: PoseTrack, inputs: InputSeries, smoothing: float, t_eval=None,
                           input_hold: str = "zoh", max_gap_s: float | None = None,
                           pad_ends: bool = True) -> BodyStates:
    """Return body-frame velocities, inputs and smoothed poses at the pose (or given) times.

    Implements eqs. 5.64 to 5.68 (thesis 5.3.5): weighted smoothing splines of x, y and yaw
    with smoothing factor ``smoothing`` (see the module docstring for its meaning), analytic
    derivatives rotated into the body frame, inputs sampled at the same times.

    Parameters
    ----------
    poses : pose track (``*_std`` used as weights when present; yaw wrapped or unwrapped).
    inputs : control inputs on their own stamps (same time base as the poses).
    smoothing : s of eq. 5.68, >= 0 (0 interpolates).
    t_eval : times to evaluate at; default the pose times.
    input_hold : ``"zoh"`` (default, what the robot acts on) or ``"linear"`` (the thesis).
    max_gap_s : split the track where poses are further apart; default
        :func:`identification.preprocessing.trajectory.gap_threshold_s`.
    pad_ends : continue each segment's ends quadratically before the final fit (see
        :func:`smoothing_spline`); False gives the plain natural smoothing spline.

    Returns
    -------
    BodyStates
        At ``t_eval``; all state fields NaN where ``t_eval`` falls in a gap or in a dropped
        pose (the inputs stay defined there).
    """
    _check_inputs(poses, inputs, smoothing, input_hold)
    segments = _fit_segments(poses, smoothing, max_gap_s, pad_ends)
    t_eval = np.asarray(poses.t if t_eval is None else t_eval, dtype=float)
    t_base = float(np.asarray(poses.t, float)[np.isfinite(poses.t)][0])
    if t_eval is poses.t or np.array_equal(t_eval, poses.t):
        # at the pose times, a dropped (NaN) pose stays a hole even inside a segment
        valid = np.isfinite(poses.x) & np.isfinite(poses.y) & np.isfinite(poses.yaw)
    else:
        valid = np.ones(t_eval.shape, bool)
    st = _states_at(segments, t_eval, t_base)
    st[~valid] = np.nan
    u1, u2 = _sample_inputs(inputs, t_eval, input_hold)
    return BodyStates(t=t_eval, vx=st[:, 3], vy=st[:, 4], omega=st[:, 5], u1=u1, u2=u2,
                      x=st[:, 0], y=st[:, 1], yaw=st[:, 2])


def body_states_segments(poses: PoseTrack, inputs: InputSeries, smoothing: float,
                         input_hold: str = "zoh", max_gap_s: float | None = None,
                         pad_ends: bool = True) -> list[BodyStates]:
    """Return one gap-free BodyStates per segment of the pose track, at its pose times.

    Same computation as :func:`body_states_from_poses`; use it where windows or integrals
    must not span a hole (identification windows, multi-step evaluation).
    """
    _check_inputs(poses, inputs, smoothing, input_hold)
    segments = _fit_segments(poses, smoothing, max_gap_s, pad_ends)
    t_base = float(np.asarray(poses.t, float)[np.isfinite(poses.t)][0])
    out = []
    for seg in segments:
        st = _states_at([seg], seg.t, t_base)
        u1, u2 = _sample_inputs(inputs, seg.t, input_hold)
        out.append(BodyStates(t=seg.t, vx=st[:, 3], vy=st[:, 4], omega=st[:, 5], u1=u1, u2=u2,
                              x=st[:, 0], y=st[:, 1], yaw=st[:, 2]))
    return out
