"""EKF fusing GNSS, an IMU gyro (with its bias as a state) and wheel odometry (issue 16 item 2).

The process model stays the injected six-state model (the identified SINDy model, or any
:class:`~sindy_ekf.estimation.process_models.ProcessModel`); the state is augmented with the gyro
bias, ``z = [x, y, psi, v_x, v_y, omega, b_g]``, a random walk (density
``bias_walk_rad_s_sqrt_s``, ``Q_b = q^2 dt``) that the model's dynamics do not touch. What the
filter assumes of the sensors is :class:`GyroNoise` and :class:`OdometryNoise` (per estimator
the ``imu`` and ``odometry`` keys of ``sindy_ekf/data/filters.yaml``; their defaults the
constants below).

Measurements (all Joseph-form updates):

- GNSS fix: the antenna position of :func:`sindy_ekf.estimation.ekf.h_gnss`, gated (chi-square, 2
  dof), applied at its time of validity with the stochastic cloning of :mod:`sindy_ekf.estimation.ekf`
  (error transitions ``M_k`` of the seven-state filter);
- gyro: ``wz = omega + b_g + n`` (:func:`h_gyro`), the samples falling nearest a grid step averaged
  into one measurement with variance ``sigma^2 / n`` (``sigma``: the stated std of each sample, or
  ``GyroNoise.rate_std_rad_s`` where the IMU states none);
- wheel odometry: ``(v, omega_odo) = (v_x, omega) + n`` (:func:`h_odometry`) with the stated std
  (or ``OdometryNoise.v_std_m_s`` / ``omega_std_rad_s`` where it states none) plus a relative
  ``OdometryNoise.scale_std`` for slip and track-width error, which the stated noise of an
  odometry message does not hold; the samples nearest a grid step averaged likewise.

Gyro and odometry are current-time updates, folded into the step's error transition ``M_k`` as the
``v_y = 0`` constraint is. One run at a time (a Python loop over the grid, 7 x 7 matrices).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from groundfloor.errors import DivergenceError, InputError
from groundfloor.gnss import check_gnss
from sindy_ekf.estimation.ekf import (
    GATE_DOF,
    GATE_PROB,
    GRID_TOL_S,
    EkfResult,
    EkfRun,
    LateralConstraint,
    fixes_on_grid,
    h_gnss,
    repair_covariance,
)
from sindy_ekf.estimation.process_models import N_X, ProcessModel

log = logging.getLogger(__name__)

N_Z = N_X + 1  # six model states and the gyro bias
I_BIAS = N_X
GYRO_STD_RAD_S = 0.01  # a sample's std when the IMU states none
BIAS_STD_RAD_S = 0.02  # prior std of the gyro bias (MEMS gyros: ~1 deg/s turn-on bias)
# random-walk density of the bias the filter assumes: a datasheet's figure, here twice the
# simulator's 2e-4 (simulation.motion_sensors.ImuSpec); 5x (1e-3) let the bias learnt while GNSS
# was there run off within a 30 s outage
BIAS_WALK_RAD_S_SQRT_S = 4e-4
ODOMETRY_STD = (0.05, 0.05)  # v m/s, omega rad/s when the odometry states none
ODOMETRY_SCALE_STD = 0.05  # relative error of odometry from slip and track width (not in its stated std)


@dataclass(frozen=True)
class GyroNoise:
    """What the filters assume of the gyro (the ``imu`` settings of an estimator in ``filters.yaml``)."""

    rate_std_rad_s: float = GYRO_STD_RAD_S  # a sample's std where the IMU states none
    bias_std_rad_s: float = BIAS_STD_RAD_S  # prior std of the bias, about zero
    bias_walk_rad_s_sqrt_s: float = BIAS_WALK_RAD_S_SQRT_S  # random-walk density of the bias


@dataclass(frozen=True)
class OdometryNoise:
    """What the filters assume of the wheel odometry (the ``odometry`` settings of an estimator)."""

    v_std_m_s: float = ODOMETRY_STD[0]  # a sample's std of v where the odometry states none
    omega_std_rad_s: float = ODOMETRY_STD[1]  # likewise of omega
    scale_std: float = ODOMETRY_SCALE_STD  # relative std added to the stated (or assumed) one


@dataclass(frozen=True)
class MotionSensors:
    """Gyro and/or wheel-odometry samples of one run, in the filter's terms (UTC or run seconds, as the grid).

    Attributes
    ----------
    t_gyro, wz, wz_std : gyro sample times (s), yaw rates and their std (rad/s); None: no gyro.
    t_odometry, v_omega, v_omega_std : odometry sample times, ``(n, 2)`` v (m/s) and omega (rad/s),
        and their stated std; None: no odometry.
    """

    t_gyro: np.ndarray | None = None
    wz: np.ndarray | None = None
    wz_std: np.ndarray | None = None
    t_odometry: np.ndarray | None = None
    v_omega: np.ndarray | None = None
    v_omega_std: np.ndarray | None = None


@dataclass(frozen=True)
class MotionEkfResult(EkfResult):
    """:class:`EkfResult` of the seven-state filter, the gyro bias estimate beside the six states."""

    gyro_bias: np.ndarray | None = None  # (n,) rad/s
    gyro_bias_std: np.ndarray | None = None  # (n,) rad/s
    n_gyro: int = 0  # gyro measurements applied (averaged per grid step)
    n_odometry: int = 0


def h_gyro(z7: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the predicted gyro rate ``(1,)`` and ``J_h_z (1, 7)``: ``wz = omega + b_g``."""
    J_h_z = np.zeros((1, N_Z))
    J_h_z[0, 5] = J_h_z[0, I_BIAS] = 1.0
    return np.array([z7[5] + z7[I_BIAS]]), J_h_z


def h_odometry(z7: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the predicted odometry ``(v, omega)`` ``(2,)`` and ``J_h_z (2, 7)``: the body ``v_x`` and yaw rate."""
    J_h_z = np.zeros((2, N_Z))
    J_h_z[0, 3] = J_h_z[1, 5] = 1.0
    return np.array([z7[3], z7[5]]), J_h_z


def h_gnss7(z7: np.ndarray, lever_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the predicted antenna position ``(2,)`` and ``J_h_z (2, 7)`` (the bias does not enter)."""
    h, J6 = h_gnss(z7[:N_X], lever_xy)
    return h, np.hstack([J6, np.zeros((2, 1))])


def _joseph(z: np.ndarray, P: np.ndarray, y: np.ndarray, H: np.ndarray, R: np.ndarray):
    """Return ``(z, P, I - K H)`` after a current-time update with innovation ``y``."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    IKH = np.eye(N_Z) - K @ H
    P = IKH @ P @ IKH.T + K @ R @ K.T
    return z + K @ y, 0.5 * (P + P.T), IKH


def _per_step(grid: np.ndarray, t: np.ndarray, values: np.ndarray, var: np.ndarray):
    """Return the grid steps holding samples, their mean values and the variances of those means.

    A sample belongs to the grid stamp nearest it; samples outside the grid are left out.
    """
    inside = (t >= grid[0] - GRID_TOL_S) & (t <= grid[-1] + GRID_TOL_S)
    t, values, var = t[inside], values[inside], var[inside]
    k = np.clip(np.searchsorted(grid, t), 1, len(grid) - 1)
    k -= (t - grid[k - 1]) < (grid[k] - t)
    steps, inv, count = np.unique(k, return_inverse=True, return_counts=True)
    mean = np.stack([np.bincount(inv, values[:, j]) / count for j in range(values.shape[1])], axis=1)
    var_mean = np.stack([np.bincount(inv, var[:, j]) / count ** 2 for j in range(var.shape[1])], axis=1)
    return steps, mean, var_mean


def _measurements(grid: np.ndarray, sensors: MotionSensors, gyro_noise: GyroNoise,
                  odometry_noise: OdometryNoise) -> dict[int, list]:
    """Return, per grid step, the gyro and odometry measurements ``(kind, z, R)`` applied there."""
    out: dict[int, list] = {}
    if sensors.t_gyro is not None:
        wz = np.asarray(sensors.wz, float)[:, None]
        assumed = gyro_noise.rate_std_rad_s
        std = np.full(wz.shape, assumed) if sensors.wz_std is None else np.asarray(sensors.wz_std, float)[:, None]
        std = np.where(np.isfinite(std) & (std > 0), std, assumed)
        for k, z, var in zip(*_per_step(grid, np.asarray(sensors.t_gyro, float), wz, std ** 2)):
            out.setdefault(int(k), []).append(("gyro", z, np.diag(var)))
    if sensors.t_odometry is not None:
        vo = np.asarray(sensors.v_omega, float).reshape(-1, 2)
        assumed = np.array([odometry_noise.v_std_m_s, odometry_noise.omega_std_rad_s])
        std = np.broadcast_to(assumed, vo.shape) if sensors.v_omega_std is None \
            else np.asarray(sensors.v_omega_std, float).reshape(-1, 2)
        std = np.where(np.isfinite(std) & (std > 0), std, assumed)
        scale_std = odometry_noise.scale_std
        for k, z, var_k in zip(*_per_step(grid, np.asarray(sensors.t_odometry, float), vo, std ** 2)):
            # the scale error is common to the samples averaged: it does not shrink with their number
            out.setdefault(int(k), []).append(("odometry", z, np.diag(var_k + (scale_std * z) ** 2)))
    return out


def run_ekf_motion(model: ProcessModel, run: EkfRun, sensors: MotionSensors, gate_prob: float = GATE_PROB,
                   lateral: LateralConstraint | None = None, gyro_noise: GyroNoise = GyroNoise(),
                   odometry_noise: OdometryNoise = OdometryNoise()) -> MotionEkfResult:
    """Return the estimates of one run by the EKF fusing GNSS (``run.gnss``), gyro and odometry.

    Parameters
    ----------
    model : process model with fitted ``Q_rate_`` (the SINDy model stays the process model).
    run : grid, held inputs, initial six-state estimate and GNSS (or None), as for
        :func:`sindy_ekf.estimation.ekf.run_ekf_batch`; every fix valid on the grid.
    sensors : gyro and/or odometry samples on the grid's time base (:class:`MotionSensors`).
    gyro_noise : a gyro sample's std where the IMU states none, the prior std (about zero) and the
        random-walk density of the gyro bias; used only when the gyro is fused.
    odometry_noise : the odometry's std where it states none, and the relative std added to it
        (module docstring).

    Raises
    ------
    DivergenceError
        The state became non-finite.
    """
    start = time.perf_counter()
    t = np.asarray(run.t, float)
    u = np.asarray(run.u, float)
    n = t.size
    if t.ndim != 1 or n < 2 or np.any(np.diff(t) <= 0):
        raise InputError(f"{run.name}: estimation grid must be at least two strictly increasing stamps")
    if u.shape != (n, 2) or not np.all(np.isfinite(u)):
        raise InputError(f"{run.name}: inputs must be finite with shape ({n}, 2), got {u.shape}")
    with_gyro = sensors.t_gyro is not None
    Z = np.zeros((n, N_Z))
    P = np.zeros((n, N_Z, N_Z))
    M = np.zeros((n, N_Z, N_Z))
    Z[0, :N_X] = run.x0
    P[0, :N_X, :N_X] = run.P0
    P[0, I_BIAS, I_BIAS] = gyro_noise.bias_std_rad_s ** 2 if with_gyro else 1.0  # unobserved without a gyro: inert
    q_bias = gyro_noise.bias_walk_rad_s_sqrt_s ** 2 if with_gyro else 0.0
    meas = _measurements(t, sensors, gyro_noise, odometry_noise)
    repairs: dict = {}
    fixes: dict[int, list] = {}
    lever = np.zeros(2)
    if run.gnss is not None:
        gnss, repairs = check_gnss(run.gnss, f"{run.name} GNSS")
        for kv, ka, z, std in zip(*fixes_on_grid(gnss, t, run.name)):
            fixes.setdefault(int(ka), []).append((int(kv), z, np.diag(std ** 2)))
        lever = np.asarray(gnss.lever_arm_body, float)[:2]
    gate_nis = float(chi2.ppf(gate_prob, GATE_DOF)) if gate_prob < 1 else np.inf
    nis, nis_t, accepted, innovation, innovation_cov = [], [], [], [], []
    n_gyro = n_odo = pd_repairs = 0
    Q6_rate = model.Q(1.0)
    for k in range(n):
        if k > 0:  # predict from k - 1
            dt = t[k] - t[k - 1]
            x6, F6, _ = model.step_and_jac(Z[k - 1, None, :N_X], u[k - 1, None], np.array([t[k - 1] - t[0]]),
                                           np.array([dt]), input_jacobian=False)
            F = np.eye(N_Z)
            F[:N_X, :N_X] = F6[0]
            Z[k, :N_X], Z[k, I_BIAS] = x6[0], Z[k - 1, I_BIAS]
            Pk = F @ P[k - 1] @ F.T
            Pk[:N_X, :N_X] += Q6_rate * dt
            Pk[I_BIAS, I_BIAS] += q_bias * dt
            P[k], M[k - 1] = Pk, F
        z, Pk = Z[k].copy(), P[k]
        if lateral is not None and k > 0 and k % lateral.every == 0:
            H = np.zeros((1, N_Z))
            H[0, 4] = 1.0
            z, Pk, IKH = _joseph(z, Pk, -z[4:5], H, np.array([[lateral.vy_std_m_s ** 2]]))
            M[k - 1] = IKH @ M[k - 1]
        for kind, y_meas, R in meas.get(k, ()):
            h, H = h_gyro(z) if kind == "gyro" else h_odometry(z)
            z, Pk, IKH = _joseph(z, Pk, y_meas - h, H, R)
            if k > 0:
                M[k - 1] = IKH @ M[k - 1]
            n_gyro += kind == "gyro"
            n_odo += kind == "odometry"
        for kv_j, y_fix, R in fixes.get(k, ()):  # fixes arrived by k, applied at their time of validity
            x_v, P_v = (z, Pk) if kv_j == k else (Z[kv_j], P[kv_j])
            h, H = h_gnss7(x_v, lever)
            y = y_fix - h
            C = P_v @ H.T
            S = H @ C + R
            S_inv = np.linalg.inv(S)
            value = float(y @ S_inv @ y)
            nis.append(value)
            nis_t.append(t[kv_j])
            innovation.append(y)
            innovation_cov.append(S)
            ok = math.isfinite(value) and value <= gate_nis
            accepted.append(ok)
            if not ok:
                continue
            for j in range(kv_j, k):  # cov(x_k error, H x_v error) = M_{k-1} ... M_v P_v H^T
                C = M[j] @ C
            K = C @ S_inv
            KC = K @ C.T
            z, Pk = z + K @ y, Pk - KC - KC.T + K @ S @ K.T
            if kv_j == k and k > 0:
                M[k - 1] = (np.eye(N_Z) - K @ H) @ M[k - 1]
        Pk, repaired = repair_covariance(Pk)
        pd_repairs += repaired
        if not math.isfinite(z.sum() + Pk.sum()):
            raise DivergenceError(f"{run.name}: state became non-finite at t={t[k] - t[0]:.2f} s "
                                  f"(model {model.name!r} diverged)", t[k] - t[0])
        Z[k], P[k] = z, Pk
    outside = ~model.in_envelope(Z[:, :N_X], u)
    log.info("%s: %d gyro and %d odometry updates, %d of %d GNSS fixes gated", run.name, n_gyro, n_odo,
             len(accepted) - int(np.sum(accepted)), len(accepted))
    return MotionEkfResult(run.name, t, Z[:, :N_X].copy(), P[:, :N_X, :N_X].copy(), np.array(nis),
                           np.array(nis_t), np.array(accepted, bool), gate_nis, pd_repairs, outside,
                           time.perf_counter() - start, repairs,
                           innovation=np.array(innovation, float).reshape(-1, 2),
                           innovation_cov=np.array(innovation_cov, float).reshape(-1, 2, 2), gyro_bias=Z[:, I_BIAS].copy(),
                           gyro_bias_std=np.sqrt(P[:, I_BIAS, I_BIAS]), n_gyro=n_gyro, n_odometry=n_odo)
