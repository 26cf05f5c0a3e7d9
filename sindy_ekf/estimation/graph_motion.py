"""Factor-graph smoothing with the gyro (its bias as variables) and wheel odometry (issue 16 item 2).

The graph of :func:`sindy_ekf.estimation.graph.build_graph` (SINDy dynamics, GNSS, priors,
optional ``v_y = 0``) plus:

- **gyro bias** ``B(j)``: a ``Vector1`` per :data:`BIAS_SEGMENT_S` seconds, a prior (std
  ``GyroNoise.bias_std_rad_s``) on the first and built-in ``BetweenFactorVector`` random-walk
  factors (std ``q sqrt(segment)``, ``q = GyroNoise.bias_walk_rad_s_sqrt_s``) between neighbours;
- **gyro** (a ``gtsam.CustomFactor``, linear): ``wz = omega_k + b_j`` on ``V(k), B(j)``, the
  samples nearest grid step ``k`` averaged as in :mod:`sindy_ekf.estimation.ekf_motion`;
- **odometry** (built-in): a ``PriorFactorVector`` on ``V(k)`` holding ``(v, ., omega)`` with the
  lateral component free (:data:`sindy_ekf.estimation.graph.FREE_SIGMA`), its noise the stated
  std (or the assumed one of :class:`~sindy_ekf.estimation.ekf_motion.OdometryNoise`) plus the
  relative ``OdometryNoise.scale_std``.

The batch smoother (:func:`smooth_batch_motion`) adds them all at once; the fixed-lag iSAM2
(:func:`smooth_isam2_motion`) adds them with each state.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass

import gtsam
import numpy as np

from groundfloor.errors import InputError
from sindy_ekf.estimation.ekf_motion import GyroNoise, MotionSensors, OdometryNoise, _measurements
from sindy_ekf.estimation.graph import (
    FREE_SIGMA,
    GraphResult,
    V,
    _initial_values,
    _marginals_world,
    _values_to_states,
    build_graph,
    levenberg_marquardt,
    smooth_isam2,
)

log = logging.getLogger(__name__)

BIAS_SEGMENT_S = 1.0  # the gyro bias is one variable per this many seconds


@dataclass(frozen=True)
class MotionGraphResult(GraphResult):
    """:class:`GraphResult` with the smoothed gyro bias, one value per :data:`BIAS_SEGMENT_S` from ``t[0]``."""

    gyro_bias: np.ndarray | None = None  # (segments,) rad/s; None without a gyro


def B(j: int) -> int:
    """Return the key of the gyro bias of segment ``j``."""
    return gtsam.symbol("b", j)


def gyro_error(v: np.ndarray, b: np.ndarray, wz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the gyro factor's error ``omega + b - wz`` ``(1,)`` and ``J_e_v (1, 3)``, ``J_e_b (1, 1)``."""
    return np.array([v[2] + b[0] - wz]), np.array([[0.0, 0.0, 1.0]]), np.array([[1.0]])


def _gyro_factor(k: int, j: int, wz: float, std: float) -> gtsam.CustomFactor:
    kv, kb = V(k), B(j)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
        e, J_v, J_b = gyro_error(values.atVector(kv), values.atVector(kb), wz)
        if H is not None:
            H[0], H[1] = J_v, J_b
        return e

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, std), [kv, kb], error)


def _bias_prior(gyro_noise: GyroNoise) -> gtsam.PriorFactorVector:
    """Return the prior on the first bias variable: zero, std ``bias_std_rad_s``."""
    return gtsam.PriorFactorVector(B(0), np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, gyro_noise.bias_std_rad_s))


def _bias_walk(j: int, gyro_noise: GyroNoise) -> gtsam.BetweenFactorVector:
    """Return the random-walk factor from bias ``j`` to ``j + 1`` over one segment."""
    walk = gtsam.noiseModel.Isotropic.Sigma(1, gyro_noise.bias_walk_rad_s_sqrt_s * np.sqrt(BIAS_SEGMENT_S))
    return gtsam.BetweenFactorVector(B(j), B(j + 1), np.zeros(1), walk)


def _step_factors(k: int, j: int, items: list) -> list:
    """Return the gyro (on bias ``j``) and odometry factors of grid step ``k`` from its measurements."""
    out = []
    for kind, z, R in items:
        if kind == "gyro":
            out.append(_gyro_factor(k, j, float(z[0]), float(np.sqrt(R[0, 0]))))
        else:
            sigmas = np.array([np.sqrt(R[0, 0]), FREE_SIGMA, np.sqrt(R[1, 1])])
            out.append(gtsam.PriorFactorVector(V(k), np.array([z[0], 0.0, z[1]]),
                                               gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    return out


def _segments(t: np.ndarray) -> np.ndarray:
    """Return the bias segment of each grid step."""
    return np.floor((t - t[0]) / BIAS_SEGMENT_S).astype(int)


def add_motion_factors(graph, t: np.ndarray, sensors: MotionSensors, gyro_noise: GyroNoise = GyroNoise(),
                       odometry_noise: OdometryNoise = OdometryNoise()) -> int:
    """Add the gyro, bias and odometry factors of one run to ``graph``; return the number of bias variables."""
    t = np.asarray(t, float)
    segment = _segments(t)
    n_bias = int(segment[-1]) + 1 if sensors.t_gyro is not None else 0
    if n_bias:
        graph.add(_bias_prior(gyro_noise))
        for j in range(n_bias - 1):
            graph.add(_bias_walk(j, gyro_noise))
    for k, items in _measurements(t, sensors, gyro_noise, odometry_noise).items():
        for f in _step_factors(k, int(segment[k]), items):
            graph.add(f)
    return n_bias


class IncrementalMotionFactors:
    """The factors of :func:`add_motion_factors`, handed to iSAM2 with each state
    (:class:`sindy_ekf.estimation.graph.StepFactors`).

    A bias variable enters with the first state of its segment (its prior, or the random walk from
    the one before), started at the latest estimate of a bias; it is stamped with the time of the
    latest state of its segment, so that the fixed-lag smoother keeps it while its states are in
    the window. ``bias_rad_s`` holds each segment's bias as last estimated, before it left the
    window (NaN: never estimated).
    """

    def __init__(self, t: np.ndarray, sensors: MotionSensors, gyro_noise: GyroNoise = GyroNoise(),
                 odometry_noise: OdometryNoise = OdometryNoise()):
        self.t = np.asarray(t, float)
        self.segment = _segments(self.t)
        self.gyro_noise = gyro_noise
        self.with_gyro = sensors.t_gyro is not None
        self.measurements = _measurements(self.t, sensors, gyro_noise, odometry_noise)
        self.bias_rad_s = np.full(int(self.segment[-1]) + 1 if self.with_gyro else 0, np.nan)
        self._latest = 0.0  # the latest bias estimate, the starting value of a new bias variable
        self._oldest = 0  # the oldest bias variable that may still be in the window

    def at_step(self, k: int) -> tuple[list, dict, dict]:
        """Return the factors, new variables and timestamps of step ``k``."""
        j = int(self.segment[k])
        factors, initial, times = [], {}, {}
        if self.with_gyro:
            for i in range(int(self.segment[k - 1]) + 1 if k else 0, j + 1):  # a segment without a step too
                factors.append(_bias_prior(self.gyro_noise) if i == 0 else _bias_walk(i - 1, self.gyro_noise))
                initial[B(i)] = np.array([self._latest])
                times[B(i)] = self.t[k] - self.t[0]
            times[B(j)] = self.t[k] - self.t[0]
        factors += _step_factors(k, j, self.measurements.get(k, ()))
        return factors, initial, times

    def updated(self, estimate: gtsam.Values) -> None:
        """Keep the bias estimates of the variables in the window."""
        for j in range(self._oldest, len(self.bias_rad_s)):
            if not estimate.exists(B(j)):
                if np.isnan(self.bias_rad_s[j]):  # not added yet: neither is any later one
                    break
                self._oldest = j + 1  # marginalised out
                continue
            self.bias_rad_s[j] = self._latest = estimate.atVector(B(j))[0]


def smooth_isam2_motion(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray, gnss,
                        sensors: MotionSensors, robust: str | None = "huber", update_every: int = 10,
                        lag_s: float = 3.0, name: str = "sindy_isam2", gyro_noise: GyroNoise = GyroNoise(),
                        odometry_noise: OdometryNoise = OdometryNoise()) -> MotionGraphResult:
    """Return the incremental (fixed-lag iSAM2) estimates of one run with gyro and/or odometry factors.

    :func:`sindy_ekf.estimation.graph.smooth_isam2` with the factors of :func:`add_motion_factors`
    added with each state (:class:`IncrementalMotionFactors`); a step's gyro and odometry samples
    are those nearest it, as in the batch graph (up to half a grid step after it). ``gyro_bias``:
    each segment's bias as last estimated before it left the window.
    """
    more = IncrementalMotionFactors(t, sensors, gyro_noise, odometry_noise)
    res = smooth_isam2(model, t, u, x0, P0, gnss, robust, update_every, lag_s, name, more=more)
    return MotionGraphResult(**{f.name: getattr(res, f.name) for f in dataclasses.fields(res)},
                             gyro_bias=more.bias_rad_s if more.with_gyro else None)


def smooth_batch_motion(model, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray, gnss,
                        sensors: MotionSensors, x_init: np.ndarray, robust: str | None = "huber",
                        marginal_stride: int | None = 1, max_iterations: int = 20, rel_tol: float = 1e-6,
                        name: str = "sindy_graph", lateral=None, bias_init: np.ndarray | None = None,
                        gyro_noise: GyroNoise = GyroNoise(),
                        odometry_noise: OdometryNoise = OdometryNoise()) -> MotionGraphResult:
    """Return the batch smoothing of one run with gyro and/or odometry factors.

    ``x_init`` (n, 6): the starting trajectory (the seven-state EKF's estimate); ``bias_init``
    (n,): its gyro bias, sampled per segment (default 0); ``gyro_noise``, ``odometry_noise``: what
    the factors assume of the sensors (as :func:`sindy_ekf.estimation.ekf_motion.run_ekf_motion`).
    Otherwise as :func:`sindy_ekf.estimation.graph.smooth_batch`.
    """
    start = time.perf_counter()
    t = np.asarray(t, float)
    if not np.all(np.isfinite(x_init)):
        raise InputError(f"{name}: initial trajectory for the graph is not finite")
    graph, _ = build_graph(model, t, u, x0, P0, gnss, robust, name, lateral)
    n_bias = add_motion_factors(graph, t, sensors, gyro_noise, odometry_noise)
    values = _initial_values(np.asarray(x_init, float))
    starts = np.searchsorted(t - t[0], np.arange(n_bias) * BIAS_SEGMENT_S)
    for j in range(n_bias):
        values.insert(B(j), np.array([0.0 if bias_init is None else float(bias_init[starts[j]])]))
    result, iterations, err0, err1 = levenberg_marquardt(graph, values, max_iterations, rel_tol)
    x = _values_to_states(result, len(t))
    which = np.union1d(np.arange(0, len(t), marginal_stride) if marginal_stride else [], [len(t) - 1])
    P = _marginals_world(graph, result, x, which.astype(int))
    runtime = time.perf_counter() - start
    log.info("%s: LM %d iterations, error %.4g -> %.4g, gyro bias %s rad/s (%d variables), %.2f s", name, iterations,
             err0, err1, np.array2string(bias_of(result, n_bias)[:3], precision=4), n_bias, runtime)
    return MotionGraphResult(name, t, x, P, runtime, iterations, float(err0), float(err1),
                             bias_of(result, n_bias) if n_bias else None)


def bias_of(values: gtsam.Values, n_bias: int) -> np.ndarray:
    """Return the gyro bias variables ``(n_bias,)`` of a solution."""
    return np.array([values.atVector(B(j))[0] for j in range(n_bias)])
