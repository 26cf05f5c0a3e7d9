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

Only the batch smoother takes them; the fixed-lag iSAM2 does not (yet).
"""

from __future__ import annotations

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


def add_motion_factors(graph, t: np.ndarray, sensors: MotionSensors, gyro_noise: GyroNoise = GyroNoise(),
                       odometry_noise: OdometryNoise = OdometryNoise()) -> int:
    """Add the gyro, bias and odometry factors of one run to ``graph``; return the number of bias variables."""
    t = np.asarray(t, float)
    segment = np.floor((t - t[0]) / BIAS_SEGMENT_S).astype(int)
    n_bias = int(segment[-1]) + 1 if sensors.t_gyro is not None else 0
    if n_bias:
        graph.add(gtsam.PriorFactorVector(B(0), np.zeros(1),
                                          gtsam.noiseModel.Isotropic.Sigma(1, gyro_noise.bias_std_rad_s)))
        walk = gtsam.noiseModel.Isotropic.Sigma(1, gyro_noise.bias_walk_rad_s_sqrt_s * np.sqrt(BIAS_SEGMENT_S))
        for j in range(n_bias - 1):
            graph.add(gtsam.BetweenFactorVector(B(j), B(j + 1), np.zeros(1), walk))
    for k, items in _measurements(t, sensors, gyro_noise, odometry_noise).items():
        for kind, z, R in items:
            if kind == "gyro":
                graph.add(_gyro_factor(k, int(segment[k]), float(z[0]), float(np.sqrt(R[0, 0]))))
            else:
                sigmas = np.array([np.sqrt(R[0, 0]), FREE_SIGMA, np.sqrt(R[1, 1])])
                graph.add(gtsam.PriorFactorVector(V(k), np.array([z[0], 0.0, z[1]]),
                                                  gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    return n_bias


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
