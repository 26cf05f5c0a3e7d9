"""Factor-graph smoothing on gtsam with the identified model as the dynamics factor.

States per grid step ``k``: ``X(k)`` a ``gtsam.Pose2`` (position and heading in the local frame)
and ``V(k)`` a ``Vector3`` ``[v_x, v_y, omega]`` (body frame). Factors:

- **dynamics** (the only Python factor, a ``gtsam.CustomFactor``): between ``X(k), V(k)`` and
  ``X(k+1), V(k+1)``, error ``x_{k+1} - step(x_k, u_k)`` in local-frame coordinates
  ``[x, y, psi, v_x, v_y, omega]`` (heading wrapped) with covariance ``Q(dt_k)``; ``step`` is the
  process model's RK4 step and its Jacobian the exact chain-rule one
  (:mod:`sindy_ekf.estimation.process_models`). Pose2 perturbations ``xi`` enter through
  ``d[x, y, psi]/d xi = diag(R(psi), 1)``, the derivative of gtsam's retraction at zero.
- **GNSS** (built-in): ``KnownLandmarkFactorPose2`` with the fix as the "landmark" and the lever
  arm as its body-frame coordinates, error ``R(psi)^T (z - p) - l_body``, which for isotropic
  horizontal noise is the lever-arm GNSS factor; without a lever arm ``PoseTranslationPrior2D``
  (linear in the local frame). Robust Huber noise by default.
- **prior** (built-in): ``PoseTranslationPrior2D``, ``PoseRotationPrior2D`` and
  ``PriorFactorVector`` on the first state (block-diagonal part of ``P0``).

The Python factor costs most: on the first evaluation at a new set of values it predicts every
step at once (one vectorised model call) and caches the result, so each factor call is a table
look-up. Batch smoothing runs gtsam's Levenberg-Marquardt; :func:`smooth_isam2` adds the states
and fixes as they arrive and updates iSAM2 (fixes attach to the state at their time of validity,
so latency needs no special handling), and with each state whatever a :class:`StepFactors` gives
(:mod:`sindy_ekf.estimation.graph_motion`: gyro bias, gyro and odometry).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Protocol

import gtsam
import numpy as np

from groundfloor.errors import InputError
from groundfloor.gnss import check_gnss
from sindy_ekf.estimation.ekf import GRID_TOL_S, run_ekf
from sindy_ekf.estimation.process_models import N_X, ProcessModel

log = logging.getLogger(__name__)

FREE_SIGMA = 1e4  # sigma of a component a pseudo-measurement leaves free (m/s, rad/s): no information


def X(k: int) -> int:
    """Return the key of the pose at step ``k``."""
    return gtsam.symbol("x", k)


def V(k: int) -> int:
    """Return the key of the body velocity at step ``k``."""
    return gtsam.symbol("v", k)


def _J_world_xi(psi: np.ndarray) -> np.ndarray:
    """Return ``d[x, y, psi]/d xi`` ``(..., 3, 3)`` of a Pose2 perturbed by ``retract(xi)`` at 0."""
    c, s = np.cos(psi), np.sin(psi)
    J = np.zeros(np.shape(psi) + (3, 3))
    J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1] = c, -s, s, c
    J[..., 2, 2] = 1.0
    return J


class DynamicsFactors:
    """The SINDy (or any process-model) dynamics factors of one run, with a shared step cache."""

    def __init__(self, model: ProcessModel, t: np.ndarray, u: np.ndarray):
        self.model, self.t, self.u = model, t, u
        self.dt = np.diff(t)
        self.t_rel = t[:-1] - t[0]
        self._x = np.full((len(t) - 1, N_X), np.nan)  # states the cache was computed at
        self._pred = np.empty((len(t) - 1, N_X))
        self._F = np.empty((len(t) - 1, N_X, N_X))
        self.n_batch = 0
        self.n_single = 0

    def _fill(self, values: gtsam.Values, hi: int) -> None:
        """Predict steps ``0 .. hi-1`` from ``values`` in one vectorised call."""
        poses = gtsam.utilities.extractPose2(values)
        vels = gtsam.utilities.extractVectors(values, "v")
        m = min(hi, len(poses), len(vels), len(self.dt))
        x = np.column_stack([poses[:m], vels[:m]])
        self._x[:m] = x
        self._pred[:m], self._F[:m], _ = self.model.step_and_jac(x, self.u[:m], self.t_rel[:m],
                                                                 self.dt[:m], input_jacobian=False)
        self.n_batch += 1

    def factor(self, k: int, noise) -> gtsam.CustomFactor:
        """Return the dynamics factor between steps ``k`` and ``k + 1``."""
        kx0, kv0, kx1, kv1 = X(k), V(k), X(k + 1), V(k + 1)
        n_full = 2 * len(self.t)
        H_v1 = np.vstack([np.zeros((3, 3)), np.eye(3)])  # d e / d V(k+1), constant

        def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
            p0, p1 = values.atPose2(kx0), values.atPose2(kx1)
            v0 = values.atVector(kv0)
            x0 = np.array([p0.x(), p0.y(), p0.theta(), v0[0], v0[1], v0[2]])
            if not (x0 == self._x[k]).all():
                if values.size() >= n_full:  # a full set: predict all steps at once
                    self._fill(values, len(self.dt))
                if not (x0 == self._x[k]).all():
                    self._x[k] = x0
                    self._pred[k], self._F[k], _ = self.model.step_and_jac(
                        x0, self.u[k], self.t_rel[k], self.dt[k], input_jacobian=False)
                    self.n_single += 1
            pred, F = self._pred[k], self._F[k]
            v1 = values.atVector(kv1)
            e = np.array([p1.x() - pred[0], p1.y() - pred[1],
                          (p1.theta() - pred[2] + np.pi) % (2.0 * np.pi) - np.pi,
                          v1[0] - pred[3], v1[1] - pred[4], v1[2] - pred[5]])
            if H is not None:
                c0, s0 = np.cos(x0[2]), np.sin(x0[2])
                c1, s1 = np.cos(p1.theta()), np.sin(p1.theta())
                # d[x, y, psi]/d xi = diag(R(psi), 1) at both poses
                H[0] = -np.column_stack([F[:, 0] * c0 + F[:, 1] * s0, -F[:, 0] * s0 + F[:, 1] * c0, F[:, 2]])
                H[1] = -F[:, 3:]
                H[2] = np.array([[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0],
                                 [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
                H[3] = H_v1
            return e

        return gtsam.CustomFactor(noise, [X(k), V(k), X(k + 1), V(k + 1)], error)


def _gnss_factor(k: int, z: np.ndarray, std: np.ndarray, lever_xy: np.ndarray, robust: str | None):
    """Return the built-in GNSS factor on ``X(k)`` (module docstring), isotropic noise."""
    sigma = float(np.sqrt(np.mean(std[:2] ** 2)))
    noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma)
    if robust == "huber":
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), noise)
    elif robust == "cauchy":
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0), noise)
    elif robust is not None:
        raise InputError(f"robust noise {robust!r} unknown (huber, cauchy or None)")
    if np.allclose(lever_xy, 0.0):
        return gtsam.PoseTranslationPrior2D(X(k), np.asarray(z[:2], float), noise)
    return gtsam.KnownLandmarkFactorPose2(X(k), np.asarray(z[:2], float), lever_xy, noise)


def _prior_factors(x0: np.ndarray, P0: np.ndarray) -> list:
    """Return the built-in priors on the first state (block-diagonal part of ``P0``)."""
    P0 = np.asarray(P0, float)
    return [gtsam.PoseTranslationPrior2D(X(0), np.asarray(x0[:2], float),
                                         gtsam.noiseModel.Gaussian.Covariance(P0[:2, :2])),
            gtsam.PoseRotationPrior2D(X(0), gtsam.Pose2(0.0, 0.0, float(x0[2])),
                                      gtsam.noiseModel.Isotropic.Sigma(1, float(np.sqrt(P0[2, 2])))),
            gtsam.PriorFactorVector(V(0), np.asarray(x0[3:], float),
                                    gtsam.noiseModel.Gaussian.Covariance(P0[3:, 3:]))]


def _gnss_on_grid(gnss, t: np.ndarray, name: str):
    """Return grid indices, positions and stds of the fixes valid inside ``t`` (checked)."""
    gnss, _ = check_gnss(gnss, f"{name} GNSS")
    inside = (gnss.t_valid >= t[0] - GRID_TOL_S) & (gnss.t_valid <= t[-1] + GRID_TOL_S)
    kv = np.minimum(np.searchsorted(t, gnss.t_valid[inside] - GRID_TOL_S), len(t) - 1)
    if np.any(np.abs(t[kv] - gnss.t_valid[inside]) > GRID_TOL_S):
        raise InputError(f"{name}: GNSS times of validity are not on the estimation grid "
                         "(build it with ekf.estimation_grid)")
    return gnss, kv, gnss.p_local[inside], gnss.std[inside], gnss.t_arrival[inside]


@dataclass(frozen=True)
class GraphResult:
    """Smoothed (or incremental) estimates of one run, with marginal covariances."""

    name: str
    t: np.ndarray  # (n,)
    x: np.ndarray  # (n, 6), psi unwrapped
    P: np.ndarray  # (n, 6, 6) local-frame marginals; NaN where not computed
    runtime_s: float
    iterations: int
    error_initial: float
    error_final: float


def _values_to_states(values: gtsam.Values, n: int) -> np.ndarray:
    """Return ``(n, 6)`` states from the Pose2 and velocity values, heading unwrapped."""
    x = np.column_stack([gtsam.utilities.extractPose2(values)[:n],
                         gtsam.utilities.extractVectors(values, "v")[:n]])
    x[:, 2] = np.unwrap(x[:, 2])
    return x


def _marginals_world(graph, values, x: np.ndarray, which: np.ndarray) -> np.ndarray:
    """Return ``(n, 6, 6)`` local-frame marginal covariances at steps ``which`` (NaN elsewhere)."""
    P = np.full((len(x), N_X, N_X), np.nan)
    marg = gtsam.Marginals(graph, values)
    J = np.eye(N_X)
    for k in which:
        joint = marg.jointMarginalCovariance(gtsam.KeyVector([X(int(k)), V(int(k))])).fullMatrix()
        J[:3, :3] = _J_world_xi(x[k, 2])
        P[k] = J @ joint @ J.T
    return P


def _lateral_factor(k: int, lateral) -> gtsam.PriorFactorVector:
    """Return the ``v_y = 0`` pseudo-measurement on ``V(k)`` (built-in factor; vx and omega left free).

    The non-holonomic constraint of a skid-steered robot, as the EKF's
    (:class:`sindy_ekf.estimation.ekf.LateralConstraint`): a prior ``[0, 0, 0]`` whose vx and omega sigmas are
    :data:`FREE_SIGMA` (no information) and whose vy sigma is ``lateral.vy_std_m_s``.
    """
    sigmas = np.array([FREE_SIGMA, lateral.vy_std_m_s, FREE_SIGMA])
    return gtsam.PriorFactorVector(V(k), np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(sigmas))


def build_graph(model: ProcessModel, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                gnss=None, robust: str | None = "huber", name: str = "graph", lateral=None):
    """Return ``(graph, dynamics)``: the factor graph of one run and its dynamics-factor cache.

    ``lateral`` (a :class:`sindy_ekf.estimation.ekf.LateralConstraint`): add the ``v_y = 0`` factor at every
    ``lateral.every``-th state.
    """
    t = np.asarray(t, float)
    dyn = DynamicsFactors(model, t, np.asarray(u, float))
    graph = gtsam.NonlinearFactorGraph()
    for f in _prior_factors(x0, P0):
        graph.add(f)
    if lateral is not None:
        for k in range(0, len(t), int(lateral.every)):
            graph.add(_lateral_factor(k, lateral))
    Q = model.Q(dyn.dt)
    for k in range(len(t) - 1):
        graph.add(dyn.factor(k, gtsam.noiseModel.Gaussian.Covariance(Q[k])))
    if gnss is not None:
        gnss, kv, z, std, _ = _gnss_on_grid(gnss, t, name)
        lever = np.asarray(gnss.lever_arm_body, float)[:2]
        for k, zk, sk in zip(kv, z, std):
            graph.add(_gnss_factor(int(k), zk, sk, lever, robust))
    return graph, dyn


def _initial_values(x_init: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    for k, xk in enumerate(x_init):
        values.insert(X(k), gtsam.Pose2(float(xk[0]), float(xk[1]), float(xk[2])))
        values.insert(V(k), np.asarray(xk[3:], float))
    return values


def levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                        max_iterations: int = 20, rel_tol: float = 1e-6, lambda0: float = 1e-5):
    """Return ``(values, iterations, initial error, final error)`` of Levenberg-Marquardt.

    The same algorithm as ``gtsam.LevenbergMarquardtOptimizer`` with its defaults (damping
    ``lambda I`` in whitened units, ``lambda`` divided by 10 on success and multiplied by 10 on
    failure), on gtsam's linearisation, COLAMD ordering and multifrontal solver. It is driven
    from Python because gtsam 4.3's optimizers hand a copy of the whole ``Values`` to every
    ``CustomFactor`` call, which makes one iteration quadratic in the number of states (measured:
    0.13 s for 500 states, 2.6 s for 2000, about 5 minutes for a 7-minute run at 50 Hz), while
    ``NonlinearFactorGraph.linearize`` called from Python is linear (0.05 s for 2000).
    """
    ordering = graph.orderingCOLAMD()
    keys = list(values.keys())
    dims = [3 if gtsam.Symbol(key).chr() == ord("x") else len(values.atVector(key)) for key in keys]
    units = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims)}
    err0 = err = graph.error(values)
    lam = lambda0
    it = 0
    for it in range(1, max_iterations + 1):
        lin = graph.linearize(values)
        improved = False
        while lam < 1e10:
            damped = lin.clone()
            sq = np.sqrt(lam)
            for key, dim in zip(keys, dims):  # Pose2 and Vector3: 3 dof; a gyro bias (graph_motion): 1
                damped.add(gtsam.JacobianFactor(key, sq * np.eye(dim), np.zeros(dim), units[dim]))
            try:
                trial = values.retract(damped.optimize(ordering))
            except RuntimeError:  # indeterminate at this damping: damp more, as gtsam's LM does
                lam *= 10.0
                continue
            err_trial = graph.error(trial)
            if err_trial <= err:
                improved = True
                lam = max(lam / 10.0, 1e-12)
                break
            lam *= 10.0
        if not improved:
            break
        decrease = (err - err_trial) / max(err, 1e-300)
        values, err = trial, err_trial
        if decrease < rel_tol or err < 1e-9:
            break
    return values, it, float(err0), float(err)


def smooth_batch(model: ProcessModel, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                 gnss=None, x_init: np.ndarray | None = None, robust: str | None = "huber",
                 marginal_stride: int | None = 1, max_iterations: int = 20, rel_tol: float = 1e-6,
                 name: str = "sindy_graph", lateral=None) -> GraphResult:
    """Return the batch Levenberg-Marquardt smoothing of one run.

    ``x_init`` (n, 6) is the starting trajectory (default: the EKF's estimate with the same
    model). Marginal covariances are computed at every ``marginal_stride``-th step and at the
    last (None: only the last); the rest are NaN. ``lateral``: the ``v_y = 0`` factors
    (:func:`build_graph`).
    """
    start = time.perf_counter()
    t = np.asarray(t, float)
    graph, dyn = build_graph(model, t, u, x0, P0, gnss, robust, name, lateral)
    if x_init is None:  # the filter's estimate: close to the optimum, unlike dead reckoning
        x_init = run_ekf(model, t, u, x0, P0, gnss, name=name, lateral=lateral).x
    if not np.all(np.isfinite(x_init)):
        raise InputError(f"{name}: initial trajectory for the graph is not finite")
    values = _initial_values(np.asarray(x_init, float))
    result, iterations, err0, err1 = levenberg_marquardt(graph, values, max_iterations, rel_tol)
    x = _values_to_states(result, len(t))
    which = np.union1d(np.arange(0, len(t), marginal_stride) if marginal_stride else [], [len(t) - 1])
    which = which.astype(int)
    P = _marginals_world(graph, result, x, which)
    runtime = time.perf_counter() - start
    log.info("%s: LM %d iterations, error %.4g -> %.4g, %d vectorised and %d single model steps, "
             "%.2f s", name, iterations, err0, err1, dyn.n_batch, dyn.n_single, runtime)
    return GraphResult(name, t, x, P, runtime, iterations, float(err0), float(err1))


class StepFactors(Protocol):
    """More factors and variables for :func:`smooth_isam2`, step by step (e.g. graph_motion's gyro)."""

    def at_step(self, k: int) -> tuple[list, dict, dict]:
        """Return the factors of step ``k``, the new variables' initial values and the variables'
        timestamps (s from the run's start; a later one replaces an earlier one)."""

    def updated(self, estimate: gtsam.Values) -> None:
        """Take the smoother's estimate after an update."""


def smooth_isam2(model: ProcessModel, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                 gnss=None, robust: str | None = "huber", update_every: int = 10, lag_s: float = 3.0,
                 name: str = "sindy_isam2", more: StepFactors | None = None) -> GraphResult:
    """Return the incremental (iSAM2) estimates of one run, as they were known in real time.

    ``gtsam.IncrementalFixedLagSmoother`` (iSAM2 with states older than ``lag_s`` marginalised
    out): gtsam hands every Python factor a copy of the solver's ``Values``, so an unbounded
    iSAM2 grows quadratically in cost with the run; a bounded window keeps each update constant
    in cost. Every ``update_every`` grid steps the new states (initialised by the model step from
    the latest estimate), their dynamics factors and the fixes that have arrived (attached to
    the state at their time of validity, which must lie within the lag) are added. ``x[k]`` is
    the estimate of step ``k`` right after the update that added it; ``P[k]`` (pose and velocity
    blocks) its marginal covariance then, at the updated steps only (NaN elsewhere). ``more``: the
    factors and variables it adds with each state (:class:`StepFactors`).
    """
    start = time.perf_counter()
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    n = len(t)
    dyn = DynamicsFactors(model, t, u)
    Q = model.Q(dyn.dt)
    lever = np.zeros(2)
    if gnss is not None:
        g, kv, z, std, t_arr = _gnss_on_grid(gnss, t, name)
        lever = np.asarray(g.lever_arm_body, float)[:2]
        ka = np.minimum(np.searchsorted(t, t_arr - 1e-6), n - 1)
        order = np.argsort(ka, kind="stable")
        kv, ka, z, std = kv[order], ka[order], z[order], std[order]
        late = t[ka] - t[kv] > 0.8 * lag_s
        if late.any():
            log.warning("%s: %d GNSS fixes arrive later than the smoother's lag and are dropped",
                        name, late.sum())
            kv, ka, z, std = kv[~late], ka[~late], z[~late], std[~late]
    else:
        kv = ka = np.empty(0, int)
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(0.01)
    params.setFactorization("QR")  # the near-deterministic pose rows of Q defeat Cholesky
    smoother = gtsam.IncrementalFixedLagSmoother(lag_s, params)
    x_rt = np.empty((n, N_X))
    P_rt = np.full((n, N_X, N_X), np.nan)
    x_last = np.asarray(x0, float).copy()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    stamps: dict[int, float] = {}  # key -> time, gathered until the update (a map keeps a key's first)
    for f in _prior_factors(x0, P0):
        graph.add(f)

    def add_state(k: int, x: np.ndarray) -> None:
        values.insert(X(k), gtsam.Pose2(*x[:3]))
        values.insert(V(k), x[3:].copy())
        stamps[X(k)] = stamps[V(k)] = t[k] - t[0]
        if more is not None:
            factors, initial, times = more.at_step(k)
            for f in factors:
                graph.add(f)
            for key, value in initial.items():
                values.insert(key, value)
            stamps.update(times)

    add_state(0, x_last)
    j, k_done, n_updates = 0, 0, 0
    J = np.eye(3)
    for k in range(1, n + 1):
        if k < n:
            x_last = model.step(x_last, u[k - 1], t[k - 1] - t[0], t[k] - t[k - 1])
            add_state(k, x_last)
            graph.add(dyn.factor(k - 1, gtsam.noiseModel.Gaussian.Covariance(Q[k - 1])))
        last = min(k, n - 1)
        while j < len(ka) and ka[j] <= last:
            graph.add(_gnss_factor(int(kv[j]), z[j], std[j], lever, robust))
            j += 1
        if k % update_every and k < n:
            continue
        stamp_map = gtsam.FixedLagSmootherKeyTimestampMap()
        for key, ts in stamps.items():
            stamp_map.insert((key, ts))
        smoother.update(graph, values, stamp_map)
        n_updates += 1
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        est = smoother.calculateEstimate()
        if more is not None:
            more.updated(est)
        for i in range(k_done, last + 1):
            p_i = est.atPose2(X(i))
            x_rt[i] = [p_i.x(), p_i.y(), p_i.theta(), *est.atVector(V(i))]
        x_last = x_rt[last].copy()
        J[:2, :2] = _J_world_xi(x_last[2])[:2, :2]
        P_rt[last, :3, :3] = J @ smoother.marginalCovariance(X(last)) @ J.T
        P_rt[last, 3:, 3:] = smoother.marginalCovariance(V(last))
        k_done = last + 1
    x_rt[:, 2] = np.unwrap(x_rt[:, 2])
    runtime = time.perf_counter() - start
    log.info("%s: %d fixed-lag iSAM2 updates over %.1f s of data in %.2f s (%d model steps "
             "outside the vectorised cache)", name, n_updates, t[-1] - t[0], runtime, dyn.n_single)
    return GraphResult(name, t, x_rt, P_rt, runtime, n_updates, float("nan"), float("nan"))
