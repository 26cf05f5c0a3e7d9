"""Extended Kalman filter on filterpy with an injected six-state process model and GNSS.

:class:`ModelEKF` is a filterpy ``ExtendedKalmanFilter`` whose prediction is replaced by the
process model's RK4 step and its exact Jacobian (filterpy's own ``predict`` is linear), and whose
update is a gated Joseph-form GNSS position update with the antenna lever arm. :func:`run_ekf`
drives it over a time grid and returns an :class:`EkfResult`; without GNSS it is dead reckoning
with the same model.

GNSS latency, handled at the time of validity (stochastic cloning, Roumeliotis and Burdick
2002): the filter keeps, per grid step, its estimate and covariance and the error-transition
matrix ``M_k = (I - K_k H_k) F_k`` of the step. A fix valid at step ``v`` that arrives at step
``a`` correlates with the current error through ``C = M_{a-1} ... M_v P_v``; the update is the
Joseph form on the stacked state ``[x_a, x_v]`` with ``H = [0, H_v]``, of which only the
``x_a`` block is kept. This is exact for linear-Gaussian models when each fix arrives before the
next one is valid (the profiles of :mod:`simulation.gnss` are built so); otherwise the earlier
delayed update's correlation is neglected (first order). It costs a few 6x6 products per fix,
where re-propagating from the time of validity would cost ``latency / dt`` model steps.

Optional lateral non-holonomic pseudo-measurement (:class:`LateralConstraint`, off by default): a
skid-steered robot barely slides sideways, so ``v_y = 0`` is applied as a measurement with a
standard deviation fitted from the train runs' ``v_y`` (:func:`fit_lateral_constraint`, 2 x its RMS)
every ``every`` steps. It is a current-time update, folded into the step's error transition
``M_k`` like a fix without latency. On real data a model with a spurious ``v_y`` term in the yaw
equation diverges without it (``bench/results/real.md``).

Faults (issue 14): the stated GNSS covariance is scaled by the variance factor of
:class:`sindy_ekf.estimation.adaptive.NoiseScaler` (covariance matching on the innovations'
scatter), and the state's body velocities are projected onto the model's envelope before the model
is evaluated (:meth:`ProcessModel.velocity_bounds`) so that its cubic terms cannot run away; saturated steps
are counted (``EkfResult.saturated_steps``).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.linalg.lapack import dpotrf as potrf
from scipy.stats import chi2

from groundfloor.errors import DivergenceError, InputError
from groundfloor.gnss import GnssSeries, check_gnss
from groundfloor.progress import progress
from sindy_ekf.estimation.adaptive import NoiseScaler
from sindy_ekf.estimation.lateral import (
    LateralConstraint,
    fit_lateral_constraint,
    lateral_update,
)
from sindy_ekf.estimation.process_models import N_X, ProcessModel, outside_bounds

__all__ = ["LateralConstraint", "fit_lateral_constraint", "lateral_update", "ModelEKF", "EkfResult", "EkfRun",
           "estimation_grid", "h_gnss", "run_ekf", "run_ekf_batch"]

log = logging.getLogger(__name__)

GATE_DOF = 2  # horizontal GNSS position
GATE_PROB = 0.999
GRID_TOL_S = 1e-6  # stamps closer than this are the same instant
DT_MAX_S = 0.025  # longest step of the estimation grid (50 Hz poses with a skipped pulse: split)
_EYE = np.eye(N_X)
_J_H_POSITION = np.eye(2, N_X)  # d(antenna position)/d(x, y); the heading column is set per fix
PD_MARGIN = 1e-9  # Q's smallest eigenvalue above this times P's largest entry: F P F^T + Q is PD


def estimation_grid(t_poses: np.ndarray, t_gnss: np.ndarray | None = None,
                    dt_max: float = DT_MAX_S) -> np.ndarray:
    """Return the estimation grid: pose times and GNSS times of validity, steps cut to ``dt_max``.

    Estimates are wanted at the pose times (compared with the truth there, stamp for stamp) and
    every fix must fall on a grid point to be applied at its time of validity. Stamps within
    ``GRID_TOL_S`` are merged; longer intervals are split evenly so no step exceeds ``dt_max``.
    """
    t = np.sort(np.concatenate([np.asarray(t_poses, float),
                                np.asarray(t_gnss if t_gnss is not None else [], float)]))
    t = t[np.concatenate([[True], np.diff(t) > GRID_TOL_S])]
    n_sub = np.ceil(np.diff(t) / dt_max - 1e-9).astype(int)
    if np.all(n_sub <= 1):
        return t
    frac = np.concatenate([np.arange(m) / m for m in n_sub])
    base = np.repeat(t[:-1], n_sub)
    return np.append(base + frac * np.repeat(np.diff(t), n_sub), t[-1])


def h_gnss(x6: np.ndarray, lever_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the predicted antenna position ``(2,)`` and ``J_h_x (2, 6)``.

    ``p_antenna_local = p_local + R(psi) l_body`` (the lever arm rotated by the heading, eq. 5.65).
    """
    x, y, psi = x6[:3].tolist()
    c, s = math.cos(psi), math.sin(psi)
    lx, ly = lever_xy
    dx, dy = c * lx - s * ly, s * lx + c * ly
    J_h_x = _J_H_POSITION.copy()
    J_h_x[0, 2] = -dy
    J_h_x[1, 2] = dx
    return np.array([x + dx, y + dy]), J_h_x


def inverse_2x2(S: np.ndarray) -> np.ndarray:
    """Return the inverse of the 2 x 2 matrix ``S`` in closed form (the innovation covariance of a
    horizontal fix: cheaper than a general solve, called at every fix)."""
    (a, b), (c, d) = S.tolist()
    det = a * d - b * c
    return np.array([[d / det, -b / det], [-c / det, a / det]])


def log_repair(count: int, what: str) -> None:
    """Log a filter's ``count``-th covariance repair (``what`` happened): the first as a warning, the
    rest at debug level (they are counted: ``EkfResult.pd_repairs``, the benchmark's ``pd_repairs``)."""
    first = count == 1
    log.log(logging.WARNING if first else logging.DEBUG, "%s; eigenvalues clipped (repair %d%s)", what, count,
            "; further repairs are counted, not logged" if first else "")


def repair_covariance(P: np.ndarray, min_eig: float = 1e-12) -> tuple[np.ndarray, bool]:
    """Return ``P`` symmetrised and, if not positive definite, with eigenvalues clipped; and
    whether a repair was needed."""
    P = 0.5 * (P + P.T)
    # LAPACK's Cholesky factorisation called directly: np.linalg.cholesky's wrapper costs five
    # times the factorisation of a 6 x 6 matrix, and this runs after every GNSS update
    if potrf(P, lower=True, clean=False)[1] == 0:
        return P, False
    w, V = np.linalg.eigh(P)
    return (V * np.maximum(w, min_eig)) @ V.T, True


class ModelEKF(ExtendedKalmanFilter):
    """filterpy EKF over ``x = [x, y, psi, v_x, v_y, omega]`` with the process model injected.

    ``x`` is kept as a flat ``(6,)`` array. ``predict`` uses ``model.step_and_jac`` and
    ``model.Q(dt)``; ``update_delayed`` is the Joseph-form GNSS update (see the module
    docstring for latency). Counters: ``pd_repairs``, ``n_gated``.
    """

    def __init__(self, model: ProcessModel, x0: np.ndarray, P0: np.ndarray,
                 lever_arm_body=(0.0, 0.0), gate_prob: float = GATE_PROB):
        super().__init__(dim_x=N_X, dim_z=2)
        self.model = model
        self.x = np.asarray(x0, dtype=float).copy()
        self.P = np.asarray(P0, dtype=float).copy()
        self.lever_xy = np.asarray(lever_arm_body, dtype=float)[:2]
        self.gate_prob = gate_prob
        self.gate_nis = float(chi2.ppf(gate_prob, GATE_DOF)) if gate_prob < 1 else np.inf
        self.pd_repairs = 0
        self.n_gated = 0
        self.F = np.eye(N_X)

    def _repaired(self, P: np.ndarray, what: str) -> np.ndarray:
        """Return ``P`` through :func:`repair_covariance`, counting and logging a repair (``what`` happened)."""
        P, repaired = repair_covariance(P)
        if repaired:
            self.pd_repairs += 1
            log_repair(self.pd_repairs, f"{self.model.name} EKF: {what}")
        return P

    def predict(self, u=np.zeros(2), t: float = 0.0, dt: float = 0.02) -> np.ndarray:
        """Propagate ``x`` and ``P`` over ``dt`` with the model; return the step Jacobian ``F``.

        Overrides filterpy's linear ``predict`` (eqs. 5.70, 5.71 with the chain-rule Jacobian).
        """
        x, F, _ = self.model.step_and_jac(self.x, u, t, dt, input_jacobian=False)
        self.x = x
        self.P = self._repaired(F @ self.P @ F.T + self.model.Q(dt), "predicted covariance lost positive definiteness")
        self.F = F
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()
        return F

    def update_delayed(self, z: np.ndarray, R: np.ndarray, x_v: np.ndarray, P_v: np.ndarray,
                       transitions=()) -> tuple[float, bool, np.ndarray | None]:
        """Apply a GNSS fix valid at an earlier step; return ``(NIS, accepted, K_a H_v)``.

        ``x_v, P_v``: estimate at the time of validity; ``transitions``: the error transitions
        ``M_v, ..., M_{a-1}`` from there to now, oldest first (none for a fix without latency, which
        makes this the ordinary Joseph update). Gated by the chi-square test with
        :data:`GATE_DOF` degrees of freedom at ``gate_prob``; ``K_a H_v`` is None for a gated fix.
        """
        h, H = h_gnss(x_v, self.lever_xy)
        y = z - h
        C = P_v @ H.T
        S = H @ C + R
        S_inv = inverse_2x2(S)
        nis = float(y @ S_inv @ y)
        self.y, self.S = y, S
        if not math.isfinite(nis):
            raise InputError(f"GNSS fix {z}: non-finite innovation (state {self.x})")
        if nis > self.gate_nis:
            self.n_gated += 1
            return nis, False, None
        for M in transitions:  # cov(x_a error, H x_v error) = M_{a-1} ... M_v P_v H^T
            C = M @ C
        K = C @ S_inv
        # Joseph form of the stacked update, x_a block: stays symmetric PD under round-off
        KC = K @ C.T
        P = self.P - KC - KC.T + K @ S @ K.T
        self.x = self.x + K @ y
        self.P = self._repaired(P, "covariance lost positive definiteness after a GNSS update")
        self.K = K
        self.x_post, self.P_post = self.x.copy(), self.P.copy()
        return nis, True, K @ H


@dataclass(frozen=True)
class EkfResult:
    """Estimates of one run on its grid, with the filter's diagnostics."""

    name: str
    t: np.ndarray  # (n,) grid, s
    x: np.ndarray  # (n, 6) real-time estimate after processing everything arrived by t
    P: np.ndarray  # (n, 6, 6)
    nis: np.ndarray  # (m,) NIS of every fix processed (gated ones included)
    nis_t: np.ndarray  # (m,) time of validity of those fixes
    accepted: np.ndarray  # (m,) bool
    gate_nis: float  # chi-square bound (dof GATE_DOF, probability gate_prob)
    pd_repairs: int
    outside_envelope: np.ndarray  # (n,) bool
    runtime_s: float  # this run's share of the batch's wall time
    repairs: dict = field(default_factory=dict)
    innovation: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))  # (m, 2) z - h(x_v), m
    innovation_cov: np.ndarray = field(default_factory=lambda: np.empty((0, 2, 2)))  # (m, 2, 2) S used
    r_scale: np.ndarray = field(default_factory=lambda: np.empty(0))  # (m,) variance factor applied to R
    saturated_steps: int = 0  # steps whose model evaluation had velocities saturated at the envelope


def fixes_on_grid(gnss: GnssSeries, t: np.ndarray, name: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return the fixes of ``gnss`` inside the grid ``t`` in order of arrival: the grid steps of
    their validity ``kv`` and arrival ``ka`` (a fix arriving in ``(t_{k-1}, t_k]`` is applied at
    step ``k``), their positions ``(m, 2)`` and standard deviations ``(m, 2)``.

    Raises
    ------
    InputError
        A time of validity off the grid (names the run ``name``).
    """
    n = len(t)
    inside = (gnss.t_valid >= t[0] - GRID_TOL_S) & (gnss.t_valid <= t[-1] + GRID_TOL_S)
    kv = np.minimum(np.searchsorted(t, gnss.t_valid[inside] - GRID_TOL_S), n - 1)
    if np.any(np.abs(t[kv] - gnss.t_valid[inside]) > GRID_TOL_S):
        raise InputError(f"{name}: GNSS times of validity are not on the estimation grid "
                         "(build it with ekf.estimation_grid)")
    ka = np.minimum(np.searchsorted(t, gnss.t_arrival[inside] - GRID_TOL_S), n - 1)
    order = np.argsort(ka, kind="stable")
    return kv[order], ka[order], gnss.p_local[inside][order, :2], gnss.std[inside][order, :2]


@dataclass(frozen=True)
class EkfRun:
    """What one run gives the filter: grid, inputs, initial state and (optional) GNSS."""

    name: str
    t: np.ndarray  # (n,) strictly increasing grid, s (see estimation_grid)
    u: np.ndarray  # (n, 2) inputs held over [t_k, t_{k+1})
    x0: np.ndarray  # (6,)
    P0: np.ndarray  # (6, 6)
    gnss: object = None  # simulation.gnss.GnssSeries or None (dead reckoning)


class _RunState:
    """Per-run bookkeeping of the lockstep driver: pending fixes, the filterpy object, and views
    ``X``, ``P``, ``M`` of this run's column of the batch's stacked storage (:meth:`attach`)."""

    def __init__(self, run: EkfRun, model: ProcessModel, gate_prob: float):
        name, t = run.name, np.asarray(run.t, dtype=float)
        n = len(t)
        u = np.asarray(run.u, dtype=float)
        if t.ndim != 1 or n < 2 or np.any(np.diff(t) <= 0):
            raise InputError(f"{name}: estimation grid must be at least two strictly increasing stamps")
        if u.shape != (n, 2) or not np.all(np.isfinite(u)):
            raise InputError(f"{name}: inputs must be finite with shape ({n}, 2), got {u.shape}")
        P0 = np.asarray(run.P0, dtype=float)
        if not np.all(np.isfinite(run.x0)) or not np.all(np.isfinite(P0)):
            raise InputError(f"{name}: initial state or covariance is not finite")
        if repair_covariance(P0)[1]:
            raise InputError(f"{name}: initial covariance P0 is not positive definite")
        self.name, self.t, self.u, self.n = name, t, u, n
        self.repairs = {}
        gnss = run.gnss
        if gnss is not None:
            gnss, self.repairs = check_gnss(gnss, f"{name} GNSS")
            self.kv, self.ka, self.z, std = fixes_on_grid(gnss, t, name)
            self.R = std[:, :, None] ** 2 * np.eye(2)  # (fixes, 2, 2)
            lever = gnss.lever_arm_body
        else:
            self.kv = self.ka = np.empty(0, dtype=int)
            lever = (0.0, 0.0)
        self.ekf = ModelEKF(model, run.x0, P0, lever, gate_prob)
        self.j = 0
        self.nis, self.nis_t, self.accepted, self.y, self.S, self.r_scale = [], [], [], [], [], []
        self.scaler = NoiseScaler()
        self.saturated_steps = 0

    def attach(self, X: np.ndarray, P: np.ndarray, M: np.ndarray) -> None:
        """Keep ``X (n_max, 6)``, ``P``, ``M (n_max, 6, 6)`` (views into the batch's storage) as
        this run's estimates, covariances and error transitions ``k -> k+1`` (updates at ``k+1``
        folded in); store the initial estimate."""
        self.X, self.P, self.M = X, P, M
        self.X[0], self.P[0] = self.ekf.x, self.ekf.P

    def apply_fixes(self, k1: int) -> None:
        """Apply every fix that has arrived by step ``k1`` at its time of validity, starting from the
        predicted estimate stored at ``k1``; store the updated one."""
        ekf = self.ekf
        ekf.x, ekf.P = self.X[k1].copy(), self.P[k1].copy()
        while self.j < len(self.ka) and self.ka[self.j] <= k1:
            kv = int(self.kv[self.j])
            scale = self.scaler.scale()
            R = scale * self.R[self.j]
            if kv == k1:
                value, ok, KH = ekf.update_delayed(self.z[self.j], R, ekf.x, ekf.P)
                if ok and k1 > 0:  # fold the update into the step's error transition
                    self.M[k1 - 1] = (_EYE - KH) @ self.M[k1 - 1]
            else:
                value, ok, _ = ekf.update_delayed(self.z[self.j], R, self.X[kv], self.P[kv], self.M[kv:k1])
            self.scaler.add(ekf.y, ekf.S - R, self.R[self.j])
            self.y.append(ekf.y)
            self.S.append(ekf.S)
            self.r_scale.append(scale)
            self.nis.append(value)
            self.nis_t.append(self.t[kv])
            self.accepted.append(ok)
            self.j += 1
        if not math.isfinite(ekf.x.sum() + ekf.P.sum()):
            raise DivergenceError(f"{self.name}: state became non-finite at t={self.t[k1] - self.t[0]:.2f} s "
                                  f"(model {ekf.model.name!r} diverged)", self.t[k1] - self.t[0])
        self.X[k1], self.P[k1] = ekf.x, ekf.P


def run_ekf_batch(model: ProcessModel, runs: list[EkfRun], gate_prob: float = GATE_PROB,
                  lateral: LateralConstraint | None = None) -> list[EkfResult]:
    """Return the EKF (or, without GNSS, dead-reckoning) estimates of several runs.

    The runs are filtered independently but in lockstep over the step index, so that one
    vectorised model call predicts all of them (a loop over time is inherent to a filter). The
    runs' states, covariances and error transitions live in stacked arrays (longest run first, so
    the runs still going at a step are a leading slice); each run keeps its own
    :class:`ModelEKF` for its GNSS updates, which touch a run only at the steps a fix arrives.
    ``lateral``: optional ``v_y = 0`` pseudo-measurement (module docstring), off by default.
    """
    start = time.perf_counter()
    states = [_RunState(r, model, gate_prob) for r in runs]
    order = sorted(range(len(states)), key=lambda i: -states[i].n)  # longest first
    ss = [states[i] for i in order]
    m, n_max = len(ss), ss[0].n
    X = np.empty((n_max, m, N_X))
    P = np.empty((n_max, m, N_X, N_X))
    M = np.empty((n_max, m, N_X, N_X))
    t_rel = np.zeros((n_max, m))  # s since each run's start
    dt = np.ones((n_max, m))
    u = np.zeros((n_max, m, 2))
    fixes_at: dict[int, list[int]] = {}  # step -> runs (slots) with a fix arriving then
    for i, s in enumerate(ss):
        s.attach(X[:, i], P[:, i], M[:, i])
        t_rel[:s.n, i] = s.t - s.t[0]
        dt[:s.n - 1, i] = np.diff(s.t)
        u[:s.n, i] = s.u
        for k1 in np.unique(s.ka):
            fixes_at.setdefault(int(k1), []).append(i)
        s.apply_fixes(0)
    n_going = np.searchsorted(-np.array([s.n - 1 for s in ss]), -np.arange(n_max - 1), side="right")
    q_min = float(np.linalg.eigvalsh(model.Q(1.0)).min())  # Q(dt) = Q_rate dt
    dt_min = dt.min(axis=1)
    bounds = model.velocity_bounds()
    for k in progress(range(n_max - 1), desc="EKF", total=n_max - 1):
        a = n_going[k]
        x_k = X[k, :a]
        if bounds is not None and outside_bounds(x_k, bounds[0], bounds[1]):
            x_next, F, held = model.saturated_step_and_jac(x_k, u[k, :a], t_rel[k, :a], dt[k, :a], bounds)
            for i in np.flatnonzero(held):
                ss[i].saturated_steps += 1
        else:
            x_next, F, _ = model.step_and_jac(x_k, u[k, :a], t_rel[k, :a], dt[k, :a], input_jacobian=False)
        P_next = F @ P[k, :a] @ F.mT
        P_next += model.Q(dt[k, :a])
        if lateral is not None and (k + 1) % lateral.every == 0:
            x_next, P_next, IKH = lateral_update(x_next, P_next, lateral.vy_std_m_s)
            F = IKH @ F  # error transition of the step with the pseudo-measurement folded in
        P_max = np.abs(P_next).max()  # NaN or inf for a non-finite covariance
        if not math.isfinite(x_next.sum() + P_max):  # one test for all runs; then the culprit
            for i in range(a):
                if not (np.all(np.isfinite(x_next[i])) and np.all(np.isfinite(P_next[i]))):
                    raise DivergenceError(f"{ss[i].name}: state or covariance became non-finite at "
                                          f"t={t_rel[k + 1, i]:.2f} s (model {model.name!r} diverged)",
                                          t_rel[k + 1, i])
        P_next += P_next.mT  # symmetrised in place (numpy buffers the overlapping transpose)
        P_next *= 0.5
        # F P F^T + Q is positive definite when Q's smallest eigenvalue is far above the round-off
        # of F P F^T (relative 1e-16 of P's largest entry): then no factorisation is needed
        if lateral is not None or q_min * dt_min[k] <= PD_MARGIN * P_max:
            try:  # one factorisation for all runs; repair run by run only when one fails
                np.linalg.cholesky(P_next)
            except np.linalg.LinAlgError:
                for i in range(a):
                    P_next[i], repaired = repair_covariance(P_next[i])
                    if repaired:
                        s = ss[i]
                        s.ekf.pd_repairs += 1
                        log_repair(s.ekf.pd_repairs, f"{s.name}: predicted covariance lost positive "
                                                     f"definiteness at t={t_rel[k + 1, i]:.2f} s")
        X[k + 1, :a], P[k + 1, :a], M[k, :a] = x_next, P_next, F
        for i in fixes_at.get(k + 1, ()):
            ss[i].apply_fixes(k + 1)
    runtime = time.perf_counter() - start
    results = []
    for s in states:
        s_X, s_P = np.ascontiguousarray(s.X[:s.n]), np.ascontiguousarray(s.P[:s.n])
        outside = ~model.in_envelope(s_X, s.u)
        if outside.any():
            log.warning("%s: state outside the model's training envelope for %.1f %% of the run "
                        "(first at t=%.2f s)", s.name, 100 * outside.mean(),
                        s.t[np.argmax(outside)] - s.t[0])
        if s.ekf.n_gated:
            log.info("%s: %d of %d GNSS fixes rejected by the chi-square gate (dof %d, p %.4f)",
                     s.name, s.ekf.n_gated, len(s.ka), GATE_DOF, gate_prob)
        results.append(EkfResult(s.name, s.t, s_X, s_P, np.array(s.nis), np.array(s.nis_t),
                                 np.array(s.accepted, bool), s.ekf.gate_nis, s.ekf.pd_repairs,
                                 outside, runtime * s.n / sum(x.n for x in states), s.repairs,
                                 np.array(s.y).reshape(-1, 2), np.array(s.S).reshape(-1, 2, 2),
                                 np.array(s.r_scale, float), s.saturated_steps))
    return results


def run_ekf(model: ProcessModel, t: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray,
            gnss=None, name: str | None = None, gate_prob: float = GATE_PROB,
            lateral: LateralConstraint | None = None) -> EkfResult:
    """Return the EKF (or, with ``gnss=None``, dead-reckoning) estimates of one run.

    Parameters
    ----------
    model : process model with fitted ``Q_rate_``.
    t : (n,) strictly increasing grid, s; every GNSS time of validity must be on it
        (:func:`estimation_grid`).
    u : (n, 2) inputs held over each step ``[t_k, t_{k+1})``.
    x0, P0 : initial state (6,) and covariance (6, 6) at ``t[0]``.
    gnss : ``simulation.gnss.GnssSeries`` or None. Fixes are applied when they arrive, at their
        time of validity (module docstring).
    lateral : optional ``v_y = 0`` pseudo-measurement (:class:`LateralConstraint`, e.g. from
        :func:`fit_lateral_constraint` on the train runs' ``v_y``); None (default) = off.
    """
    run = EkfRun(name or f"{model.name}_ekf", t, u, np.asarray(x0, float), P0, gnss)
    return run_ekf_batch(model, [run], gate_prob, lateral)[0]
