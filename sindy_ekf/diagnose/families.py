"""One mechanism-specific extension per family of discrepancy, fitted on train runs, scored on test runs.

A family explains what the given model gets wrong by one physical mechanism with a few
parameters, added to the model *as it is* (its coefficients ``Xi`` stay fixed: the question is
what the model lacks, not how a refit would bend it). Two kinds:

- **input side** (``input_delay``, ``deadband``, ``time_dependence``, ``asymmetry``): the motors
  see a transform ``u_m = T_theta(u)`` of the recorded inputs, one scalar ``theta`` found by a
  profile search (grid, then a bounded 1-D refinement);
- **additive** (``heading_dependence``, ``position_dependence``, ``lateral_slip``): the body
  accelerations gain columns ``sum_j beta_j c_j(x6, u, t)``, linear in ``beta`` (weighted least
  squares), possibly with nonlinear ``theta`` (the patch centre and radius, found by a grid and
  Nelder-Mead on the variable-projection objective).

Everything is scored on the integral regression (eqs. 5.55 to 5.57): over windows of ``tau``
the residual ``Delta v - int f(x, T_theta(u)) dt - int C beta dt`` per equation, each equation
weighted by the inverse of the model's residual variance on the train runs. ``theta`` and
``beta`` come from the train runs; the gain is the relative drop of the weighted residual sum
of squares on the *test* runs (out of sample, by run). Per-run sums are kept so that the
leave-one-run-out (jackknife) uncertainty of every estimate costs no new design matrices.

Mechanisms and their parameters follow :mod:`simulation.effects` (the catalogue of what a
Husky-like robot plausibly suffers from), but nothing here reads a simulator.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from identification.sindy.library import LIBRARY_STATE_NAMES, parse_term
from identification.sindy.checks import (
    STABILITY_TOL,
    max_re_eig_at_rest,
    stable_at_rest,
)
from sindy_ekf.diagnose.data import Split

log = logging.getLogger(__name__)

FAMILIES = ("input_delay", "heading_dependence", "position_dependence", "time_dependence", "asymmetry",
            "deadband", "lateral_slip")
G_M_S2 = 9.81
PATCH_EDGE_M = 0.2  # 10-90 % width of the patch's logistic edge (assumed, not estimated)
PATCH_GRID_SPACING_M = 0.4  # candidate patch centres over the driven area, before Nelder-Mead
PATCH_RADII_M = (0.5, 0.8, 1.2, 1.8)  # candidate radii of the grid
_MAX_CHUNK_ELEMENTS = 6_000_000  # candidates x samples x features per chunk (memory bound)


def _clip(u: np.ndarray) -> np.ndarray:
    return np.clip(u, -1.0, 1.0)


# -- input-side mechanisms ---------------------------------------------------------------------
def inputs_delayed(t_run: np.ndarray, u: np.ndarray, slices, delay_s: np.ndarray) -> np.ndarray:
    """Return inputs ``(C, N, 2)`` delayed by each ``delay_s`` (C,): ``u_m(t) = u(t - d)`` per run.

    Linear interpolation between samples, the first sample held before a run's start.
    """
    delay_s = np.atleast_1d(np.asarray(delay_s, float))
    out = np.empty((len(delay_s),) + u.shape)
    for sl in slices:  # a handful of runs; vectorised over candidates and samples
        t = t_run[sl]
        tq = (t[None, :] - delay_s[:, None]).ravel()
        for j in range(2):
            out[:, sl, j] = np.interp(tq, t, u[sl, j]).reshape(len(delay_s), -1)
    return out


def inputs_deadband(u: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """Return ``sign(u) max(|u| - v, 0) / (1 - v)`` per threshold ``v`` (C,), shape ``(C, N, 2)``."""
    v = np.atleast_1d(np.asarray(threshold, float))[:, None, None]
    return _clip(np.sign(u) * np.maximum(np.abs(u) - v, 0.0) / (1.0 - v))


def inputs_battery(u: np.ndarray, t_run: np.ndarray, decay_per_10min: np.ndarray) -> np.ndarray:
    """Return ``u (1 - r t / 600 s)`` per decay ``r`` (C,) with ``t`` since the run start, ``(C, N, 2)``."""
    r = np.atleast_1d(np.asarray(decay_per_10min, float))[:, None]
    return _clip(u[None] * np.maximum(1.0 - r * t_run[None, :] / 600.0, 0.0)[..., None])


def inputs_imbalance(u: np.ndarray, imbalance: np.ndarray) -> np.ndarray:
    """Return track-imbalance inputs ``[u1 + a/2 u2, u2 + a/2 u1]`` per imbalance ``a`` (C,), ``(C, N, 2)``."""
    h = np.atleast_1d(np.asarray(imbalance, float))[:, None, None] / 2.0
    return _clip(u[None] + h * u[None, :, ::-1])


# -- additive mechanisms -----------------------------------------------------------------------
def patch_indicator(x: np.ndarray, y: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, ...]:
    """Return the smooth disc ``s`` and ``ds/dx``, ``ds/dy`` for patches ``theta (C, 3) = [cx, cy, r]``.

    Logistic edge rising from 10 % to 90 % over :data:`PATCH_EDGE_M`; shapes ``(C, N)``.
    """
    theta = np.atleast_2d(theta)
    h = PATCH_EDGE_M / (2.0 * math.log(9.0))
    dx = x[None, :] - theta[:, 0:1]
    dy = y[None, :] - theta[:, 1:2]
    d = np.sqrt(dx * dx + dy * dy + 1e-12)
    th = np.tanh((theta[:, 2:3] - d) / h)
    s = 0.5 * (1.0 + th)
    ds_dd = -0.5 * (1.0 - th * th) / h
    return s, ds_dd * dx / d, ds_dd * dy / d


@dataclass(frozen=True)
class Family:
    """A mechanism: its inputs transform or its additive columns, grid, bounds and estimates."""

    name: str
    kind: str  # "input" or "additive"
    theta_names: tuple[str, ...] = ()
    column_names: tuple[str, ...] = ()
    bounds: tuple[tuple[float, float], ...] = ()
    doc: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def n_columns(self) -> int:
        """Number of linear coefficients ``beta``."""
        return len(self.column_names)

    def grid(self, split: Split) -> np.ndarray:
        """Return candidate ``theta (C, d)`` for the search (``(1, 0)`` when there is none)."""
        if self.name == "position_dependence":
            lo = np.percentile(split.pose_local[:, :2], 2, axis=0)
            hi = np.percentile(split.pose_local[:, :2], 98, axis=0)
            cx = np.arange(lo[0], hi[0] + 1e-9, PATCH_GRID_SPACING_M)
            cy = np.arange(lo[1], hi[1] + 1e-9, PATCH_GRID_SPACING_M)
            return np.stack(np.meshgrid(cx, cy, PATCH_RADII_M, indexing="ij"), -1).reshape(-1, 3)
        if not self.theta_names:
            return np.zeros((1, 0))
        lo, hi = self.bounds[0]
        step = self.extra["step"]
        return np.arange(lo, hi + step / 2, step)[:, None]

    def motor_inputs(self, t_run: np.ndarray, u: np.ndarray, slices, theta: np.ndarray) -> np.ndarray:
        """Return the inputs the motors see ``(C, N, 2)`` for candidates ``theta (C, d)``."""
        theta = np.atleast_2d(theta)
        if self.kind != "input":
            return np.broadcast_to(u, (len(theta),) + u.shape)
        v = theta[:, 0]
        if self.name == "input_delay":
            return inputs_delayed(t_run, u, slices, v)
        if self.name == "deadband":
            return inputs_deadband(u, v)
        if self.name == "time_dependence":
            return inputs_battery(u, t_run, v)
        return inputs_imbalance(u, v)

    def columns(self, x6: np.ndarray, u: np.ndarray, t_run: np.ndarray, theta: np.ndarray,
                with_jacobian: bool = False):
        """Return additive columns ``(C, N, 3, m)`` (and ``d/dx6`` ``(C, N, 3, m, 6)``) at samples ``x6 (N, 6)``."""
        theta = np.atleast_2d(theta)
        C, N, m = len(theta), len(x6), self.n_columns
        cols = np.zeros((C, N, 3, m))
        jac = np.zeros((C, N, 3, m, 6)) if with_jacobian else None
        psi, vx, vy, om = x6[:, 2], x6[:, 3], x6[:, 4], x6[:, 5]
        if self.name == "heading_dependence":
            # gravity along a tilted floor: A = g sin(tilt) cos(psi_down), B = g sin(tilt) sin(psi_down)
            # vx and vy apart: the lateral share is balanced by the tyres' lateral force, which a
            # model without a lateral law (eq. 7.8: vy_dot = 0) cannot carry; tilt from vx
            c, s = np.cos(psi), np.sin(psi)
            cols[:, :, 0, 0], cols[:, :, 0, 1] = c, s
            cols[:, :, 1, 2], cols[:, :, 1, 3] = -s, c
            if with_jacobian:
                jac[:, :, 0, 0, 2], jac[:, :, 0, 1, 2] = -s, c
                jac[:, :, 1, 2, 2], jac[:, :, 1, 3, 2] = -c, -s
        elif self.name == "position_dependence":
            s, ds_x, ds_y = patch_indicator(x6[:, 0], x6[:, 1], theta)
            cols[:, :, 0, 0] = s * vx
            cols[:, :, 2, 1] = s * om
            if with_jacobian:
                jac[:, :, 0, 0, 0], jac[:, :, 0, 0, 1], jac[:, :, 0, 0, 3] = ds_x * vx, ds_y * vx, s
                jac[:, :, 2, 1, 0], jac[:, :, 2, 1, 1], jac[:, :, 2, 1, 5] = ds_x * om, ds_y * om, s
        elif self.name == "lateral_slip":
            cols[:, :, 1, 0] = vx * om
            cols[:, :, 1, 1] = vy
            if with_jacobian:
                jac[:, :, 1, 0, 3], jac[:, :, 1, 0, 5] = om, vx
                jac[:, :, 1, 1, 4] = 1.0
        return (cols, jac) if with_jacobian else cols

    def estimate(self, theta: np.ndarray, beta: np.ndarray, model) -> dict[str, float | list]:
        """Return the physical parameters of the mechanism from ``theta (d,)`` and ``beta (m,)``."""
        theta, beta = np.asarray(theta, float), np.asarray(beta, float)
        if self.name == "input_delay":
            return {"delay_s": float(theta[0])}
        if self.name == "deadband":
            return {"threshold": float(theta[0])}
        if self.name == "time_dependence":
            return {"decay_per_10min": float(theta[0])}
        if self.name == "asymmetry":
            return {"imbalance": float(theta[0])}
        if self.name == "heading_dependence":
            a = float(np.hypot(beta[0], beta[1]))
            return {"tilt_deg": math.degrees(math.asin(min(a / G_M_S2, 1.0))),
                    "psi_down_rad": float(math.atan2(beta[1], beta[0])), "accel_m_s2": a}
        if self.name == "position_dependence":
            c_vx = model_coefficient(model, "vx", "vx")
            c_om = model_coefficient(model, "omega", "omega")
            ref = np.array([c_vx, c_om])
            # the patch multiplies the model's linear damping terms by (1 + v s): beta = v ref
            frac = float(beta @ ref / (ref @ ref)) if ref @ ref > 0 else float("nan")
            return {"patch_center_local_m": [float(theta[0]), float(theta[1])],
                    "patch_radius_m": float(theta[2]), "damping_fraction": frac}
        if self.name == "lateral_slip":
            # In turns vy settles at (c / k) vx omega within 1/k (about 0.1 s): the integral
            # regression sees the drift ratio c / k well, c and k apart poorly. The slip gain is
            # the drift relative to the model's own.
            c = model_coefficient(model, "vy", "vx omega")
            k = model_coefficient(model, "vy", "vy")
            # A model without a lateral law (eq. 7.8, vy_dot = 0) has no drift to compare with: then
            # the drift itself is the finding and the gain is left undefined (None).
            c_new, k_new = c + beta[0], k + beta[1]
            drift = float(c_new / k_new) if k_new != 0 else float("nan")
            has_law = c != 0 and k != 0
            return {"coupling": float(c_new), "damping_1_s": float(-k_new), "drift_s": drift,
                    "slip_gain": float(drift / (c / k)) if has_law else None, "model_has_lateral_law": has_law}
        return {}


def model_coefficient(model, equation: str, term: str) -> float:
    """Return the coefficient of ``term`` in ``equation`` of a SINDy model (0 when absent)."""
    lib = model.library
    atoms = parse_term(term, lib.variables)
    for j, a in enumerate(lib.atoms):
        if a == atoms:
            return float(model.coef[LIBRARY_STATE_NAMES.index(equation), j])
    return 0.0


FAMILY_SPECS: dict[str, Family] = {
    "input_delay": Family("input_delay", "input", ("delay_s",), bounds=((0.0, 0.6),),
                          doc="the motors see the inputs late", extra={"step": 0.04}),
    "deadband": Family("deadband", "input", ("threshold",), bounds=((0.0, 0.45),),
                       doc="small inputs do not move the motors", extra={"step": 0.03}),
    "time_dependence": Family("time_dependence", "input", ("decay_per_10min",),
                              bounds=((-1.0, 1.5),), doc="input gain drifts with time since the run start",
                              extra={"step": 0.1}),
    "asymmetry": Family("asymmetry", "input", ("imbalance",), bounds=((-0.6, 0.6),),
                        doc="left and right tracks respond unequally", extra={"step": 0.05}),
    "heading_dependence": Family("heading_dependence", "additive",
                                 column_names=("A_x_m_s2", "B_x_m_s2", "A_y_m_s2", "B_y_m_s2"),
                                 doc="gravity on a tilted floor depends on the heading"),
    "position_dependence": Family("position_dependence", "additive", ("cx_m", "cy_m", "radius_m"),
                                  column_names=("patch_vx", "patch_omega"),
                                  bounds=((-1e3, 1e3), (-1e3, 1e3), (0.2, 4.0)),
                                  doc="a floor patch with more rolling resistance"),
    "lateral_slip": Family("lateral_slip", "additive", column_names=("vx_omega", "vy"),
                           doc="the lateral drift in turns is larger than the model's"),
}


# -- fitting and scoring -----------------------------------------------------------------------
@dataclass(frozen=True)
class Design:
    """Weighted per-run normal equations of candidates: ``G (C, R, m, m)``, ``b (C, R, m)``, ``yy (C, R)``."""

    G: np.ndarray
    b: np.ndarray
    yy: np.ndarray


class ActiveTerms:
    """The model restricted to its active features: same ``f``, fewer columns to evaluate."""

    def __init__(self, model):
        from identification.sindy.library import FeatureLibrary

        keep = np.flatnonzero(np.any(model.coef != 0, axis=0))
        names = tuple(model.library.feature_names[j] for j in keep) or ("1",)
        self.library = FeatureLibrary(name=model.library.name, feature_names=names,
                                      variables=model.library.variables)
        self.coef = model.coef[:, keep] if len(keep) else np.zeros((3, 1))

    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return ``(..., 3)`` accelerations (eq. 5.53)."""
        x, u = np.asarray(x, float)[..., :3], np.asarray(u, float)[..., :2]
        lead = np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1])
        z = np.concatenate([np.broadcast_to(x, lead + (3,)), np.broadcast_to(u, lead + (2,))], axis=-1)
        return self.library.transform(z) @ self.coef.T


def null_prediction(model, split: Split) -> np.ndarray:
    """Return the window integrals ``(p, 3)`` of the model's accelerations on the recorded inputs."""
    return split.integrate(model.f(split.v_body, split.u))


def equation_weights(model, split: Split) -> np.ndarray:
    """Return ``1 / var`` (3,) of the model's window residual per equation on ``split`` (train)."""
    r = split.delta_v - null_prediction(model, split)
    return 1.0 / np.maximum(np.mean(r * r, axis=0), 1e-12)


def _chunks(n_cand: int, per_candidate: int):
    size = max(1, _MAX_CHUNK_ELEMENTS // max(per_candidate, 1))
    for a in range(0, n_cand, size):
        yield slice(a, min(a + size, n_cand))


def residual_and_columns(family: Family, model, split: Split, theta: np.ndarray,
                         base_pred: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return window targets ``y (C, p, 3)`` after the fixed part and columns ``X (C, p, 3, m)``."""
    theta = np.atleast_2d(theta)
    C, p, m = len(theta), split.n_windows, family.n_columns
    dv = split.delta_v
    if family.kind == "input":
        y = np.empty((C, p, 3))
        model = ActiveTerms(model)
        k = model.library.n_features
        for sl in _chunks(C, len(split.t_run) * k):
            u_m = family.motor_inputs(split.t_run, split.u, split.runs_slices(), theta[sl])
            y[sl] = dv - split.integrate(model.f(split.v_body, u_m))
        return y, np.zeros((C, p, 3, 0))
    base_pred = null_prediction(model, split) if base_pred is None else base_pred
    y = np.broadcast_to(dv - base_pred, (C, p, 3))
    X = np.empty((C, p, 3, m))
    x6 = split.x6
    for sl in _chunks(C, len(split.t_run) * 3 * m):
        cols = family.columns(x6, split.u, split.t_run, theta[sl])
        n = cols.shape[0]
        X[sl] = split.integrate(cols.reshape(n, len(x6), 3 * m)).reshape(n, p, 3, m)
    return y, X


def normal_equations(y: np.ndarray, X: np.ndarray, weights: np.ndarray, window_run: np.ndarray,
                     n_runs: int) -> Design:
    """Return the weighted normal equations per candidate and per run (sums over windows of a run)."""
    onehot = (window_run[:, None] == np.arange(n_runs)[None, :]).astype(float)  # (p, R)
    wy = y * weights
    yy = np.einsum("cpe,cpe,pr->cr", wy, y, onehot, optimize=True)
    if X.shape[-1] == 0:
        C = y.shape[0]
        return Design(np.zeros((C, n_runs, 0, 0)), np.zeros((C, n_runs, 0)), yy)
    wX = X * weights[:, None]
    G = np.einsum("cpem,cpen,pr->crmn", wX, X, onehot, optimize=True)
    b = np.einsum("cpem,cpe,pr->crm", wX, y, onehot, optimize=True)
    return Design(G, b, yy)


def design_for(family: Family, model, split: Split, grid: np.ndarray, weights: np.ndarray,
               base_pred: np.ndarray | None = None) -> Design:
    """Return the per-run normal equations of all candidates ``grid``, built in memory-bounded chunks."""
    parts = []
    per = split.n_windows * 3 * max(family.n_columns, 1)
    for sl in _chunks(len(grid), per):
        y, X = residual_and_columns(family, model, split, grid[sl], base_pred)
        parts.append(normal_equations(y, X, weights, split.window_run, len(split.names)))
    return Design(*(np.concatenate([getattr(d, k) for d in parts]) for k in ("G", "b", "yy")))


def solve_design(d: Design, runs: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return ``beta (C, m)`` and the weighted residual sum of squares ``(C,)`` over ``runs``."""
    sel = slice(None) if runs is None else runs
    G, b, yy = d.G[:, sel].sum(1), d.b[:, sel].sum(1), d.yy[:, sel].sum(1)
    m = G.shape[-1]
    if m == 0:
        return np.zeros((len(yy), 0)), yy
    # a tiny ridge keeps candidates without support (a patch nobody drove through) solvable
    ridge = 1e-9 * np.trace(G, axis1=-2, axis2=-1)[:, None, None] * np.eye(m) + 1e-12 * np.eye(m)
    beta = np.linalg.solve(G + ridge, b[..., None])[..., 0]
    return beta, yy - np.einsum("cm,cm->c", beta, b)


@dataclass
class FamilyScore:
    """One family fitted on the train runs and scored on the test runs.

    ``gain`` is ``1 - SSE_ext / SSE_model`` of the weighted window residuals on the test runs;
    ``gain_per_run`` the same per test run; ``estimate`` the physical parameters and
    ``estimate_std`` their leave-one-train-run-out (jackknife) standard deviations.
    """

    family: str
    theta: np.ndarray
    beta: np.ndarray
    gain: float
    gain_per_run: dict[str, float]
    train_gain: float
    estimate: dict
    estimate_std: dict = field(default_factory=dict)
    profile: dict = field(default_factory=dict)  # theta grid and train SSE (1-D families)

    def to_dict(self) -> dict:
        """Return a JSON-ready dict."""
        return {"gain": self.gain, "gain_per_test_run": self.gain_per_run, "train_gain": self.train_gain,
                "estimate": self.estimate, "estimate_std": self.estimate_std,
                "theta": [float(v) for v in self.theta], "beta": [float(v) for v in self.beta]}


def _sse_at(family, model, split, theta, weights, base_pred):
    y, X = residual_and_columns(family, model, split, theta, base_pred)
    d = normal_equations(y, X, weights, split.window_run, len(split.names))
    return solve_design(d)[1][0]


def _refine(family: Family, model, split: Split, grid: np.ndarray, sse: np.ndarray, weights, base_pred):
    """Return the train-SSE minimiser near the best grid point (bounded 1-D search or Nelder-Mead)."""
    i = int(np.argmin(sse))
    if grid.shape[1] == 1:
        lo_b, hi_b = family.bounds[0]
        lo = grid[max(i - 1, 0), 0]
        hi = grid[min(i + 1, len(grid) - 1), 0]
        if hi <= lo:
            return grid[i]
        res = minimize_scalar(lambda v: _sse_at(family, model, split, [[v]], weights, base_pred),
                              bounds=(max(lo, lo_b), min(hi, hi_b)), method="bounded",
                              options={"xatol": 2e-3 * (hi_b - lo_b)})
        return np.array([res.x]) if res.fun <= sse[i] else grid[i]
    if grid.shape[1] == 3:
        def obj(th):
            th = np.array([th[0], th[1], np.clip(th[2], *family.bounds[2])])
            return _sse_at(family, model, split, th[None], weights, base_pred)

        res = minimize(obj, grid[i], method="Nelder-Mead",
                       options={"xatol": 0.01, "fatol": 1e-6 * sse[i], "maxfev": 150,
                                "initial_simplex": grid[i] + np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0],
                                                                       [0, 0, 0.2]])})
        th = res.x.copy()
        th[2] = np.clip(th[2], *family.bounds[2])
        return th if res.fun <= sse[i] else grid[i]
    return grid[i]


def _parabolic_argmin(grid: np.ndarray, sse: np.ndarray) -> np.ndarray:
    """Return the vertex of the parabola through the best grid point and its neighbours (1-D)."""
    i = int(np.argmin(sse))
    if grid.shape[1] != 1 or i == 0 or i == len(grid) - 1 or not np.all(np.isfinite(sse[i - 1:i + 2])):
        return grid[i]
    x, y = grid[i - 1:i + 2, 0], sse[i - 1:i + 2]
    den = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / den
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / den
    return np.array([-b / (2 * a)]) if a > 0 else grid[i]


def _jackknife(values: list[dict]) -> dict:
    """Return jackknife standard deviations of the numeric (and list) entries of estimate dicts."""
    if len(values) < 2:
        return {}
    R = len(values)
    out = {}
    for key in values[0]:
        if isinstance(values[0][key], (bool, str)):
            continue
        arr = np.array([np.nan if v[key] is None else v[key] for v in values], dtype=float)
        if key == "psi_down_rad":  # circular: deviations wrapped to (-pi, pi]
            dev = np.angle(np.exp(1j * (arr - np.angle(np.exp(1j * arr).mean()))))
        else:
            dev = arr - arr.mean(axis=0)
        std = np.sqrt((R - 1) / R * np.sum(dev ** 2, axis=0))
        out[key] = std.tolist() if np.ndim(std) else float(std)
    return out


def refit_columns(family: Family, model, split: Split, theta: np.ndarray) -> np.ndarray:
    """Return the re-identification columns ``(p, 3, n)`` at ``theta``: the model's terms per equation
    (integrated library features on the motor inputs, eq. 5.56) and then the mechanism's columns."""
    theta = np.asarray(theta, float).reshape(-1)
    act = ActiveTerms(model)
    u_m = family.motor_inputs(split.t_run, split.u, split.runs_slices(), theta[None])[0]
    feats = split.integrate(act.library.transform(np.concatenate([split.v_body, u_m], axis=-1)))  # (p, k)
    support = act.coef != 0
    blocks = [np.flatnonzero(support[e]) for e in range(3)]
    n_xi, m = sum(len(b) for b in blocks), family.n_columns
    X = np.zeros((split.n_windows, 3, n_xi + m))
    col = 0
    for e, b in enumerate(blocks):
        X[:, e, col:col + len(b)] = feats[:, b]
        col += len(b)
    if m:
        cols = family.columns(split.x6, split.u, split.t_run, theta[None])[0]
        X[:, :, n_xi:] = split.integrate(cols.reshape(len(cols), 3 * m)).reshape(-1, 3, m)
    return X


def _coefs_from_refit(model, sols: np.ndarray) -> np.ndarray:
    """Return coefficient arrays ``(C, 3, k)`` with the model's support refitted to each row of
    ``sols (C, n)`` (their xi part: the support's coefficients equation by equation)."""
    sols = np.atleast_2d(sols)
    rows, cols = np.nonzero(model.coef)  # row-major: equation by equation, as refit_columns orders them
    coefs = np.zeros((len(sols),) + model.coef.shape)
    coefs[:, rows, cols] = sols[:, :len(rows)]
    return coefs


def _coef_from_refit(model, sol: np.ndarray):
    """Return a model-like object with the model's support refitted to ``sol`` (the xi part)."""
    from identification.sindy.model import SindyModel

    return SindyModel(library=model.library, coef=_coefs_from_refit(model, sol)[0],
                      hyperparameters=dict(model.hyperparameters))


def refit_score(family: Family, model, train: Split, test: Split, weights: np.ndarray,
                theta_fixed: np.ndarray) -> dict:
    """Return the family scored with the model re-identified around it (same support, eqs. 5.55 to 5.59).

    The null is the model re-identified on the train runs without the mechanism. This is what
    finds a mechanism the given model has partly absorbed (a model identified on the very runs
    that hold the effect). Input-side families search ``theta`` on the grid (train residual);
    additive families keep the geometry ``theta_fixed`` of the fixed-model search.
    """
    R = len(train.names)
    y_tr = train.delta_v[None]
    null_theta = np.zeros(len(family.theta_names)) if family.kind == "input" else theta_fixed
    null_fam = Family(family.name, family.kind, family.theta_names) if family.kind == "additive" else family
    grid = family.grid(train) if family.kind == "input" else np.asarray(theta_fixed, float)[None]
    designs = [normal_equations(y_tr, refit_columns(family, model, train, th)[None], weights, train.window_run, R)
               for th in grid]
    d = Design(*(np.concatenate([getattr(x, k) for x in designs]) for k in ("G", "b", "yy")))
    sols, sse = solve_design(d)
    # Admissible as in the identification's search (identification.sindy.search.admissible): a
    # re-identified model that runs away at rest is no explanation, however well its windows fit
    # (on 10 Hz real data a long input delay refits to positive self-damping: measured, wheels).
    ok = (max_re_eig_at_rest(model.library, _coefs_from_refit(model, sols)) <= STABILITY_TOL) | \
        ~stable_at_rest(model)
    if not ok.any():
        return {"gain": float("-inf"), "gain_runs": {}, "theta": np.asarray(grid[0], float),
                "beta": np.zeros(family.n_columns), "estimate": family.estimate(grid[0], np.zeros(family.n_columns),
                                                                                model),
                "std": {}, "profile": {}}
    sse = np.where(ok, sse, np.inf)

    def refit_at(th):
        X = refit_columns(family, model, train, th)
        return X, solve_design(normal_equations(y_tr, X[None], weights, train.window_run, R))[0][0]

    theta = _parabolic_argmin(grid, sse) if grid.shape[1] == 1 else grid[0]
    X_tr, sol = refit_at(theta)
    if not stable_at_rest(_coef_from_refit(model, sol)):
        theta = grid[int(np.argmin(sse))]  # the vertex between grid points is not admissible: the best point
        X_tr, sol = refit_at(theta)
    X0_tr = refit_columns(null_fam, model, train, null_theta)
    sol0 = solve_design(normal_equations(y_tr, X0_tr[None], weights, train.window_run, R))[0][0]
    r1 = test.delta_v - np.einsum("pen,n->pe", refit_columns(family, model, test, theta), sol)
    r0 = test.delta_v - np.einsum("pen,n->pe", refit_columns(null_fam, model, test, null_theta), sol0)
    w1, w0 = np.sum(r1 * r1 * weights, 1), np.sum(r0 * r0 * weights, 1)
    gain_runs = {n: float(1 - w1[test.window_run == i].sum() / w0[test.window_run == i].sum())
                 for i, n in enumerate(test.names) if np.any(test.window_run == i)}
    m = family.n_columns
    beta = sol[len(sol) - m:] if m else np.zeros(0)
    std = {}
    if family.kind == "input" and R > 1:
        loo = [{family.theta_names[0]: float(_parabolic_argmin(
                   grid, np.where(ok, solve_design(d, np.flatnonzero(np.arange(R) != r))[1], np.inf))[0])}
               for r in range(R)]
        std = _jackknife(loo)
    return {"gain": float(1 - w1.sum() / w0.sum()), "gain_runs": gain_runs, "theta": np.asarray(theta, float),
            "beta": beta, "estimate": family.estimate(theta, beta, _coef_from_refit(model, sol)), "std": std,
            "profile": {"theta": grid[:, 0].tolist(), "train_sse": sse.tolist()} if grid.shape[1] == 1 else {}}


def score_family(family: Family | str, model, train: Split, test: Split, weights: np.ndarray | None = None,
                 base_pred: dict | None = None, uncertainty: bool = True, refit: bool = True) -> FamilyScore:
    """Return ``family`` fitted on ``train`` (grid, refinement, linear part) and scored on ``test``.

    Two scorings, the better kept: the mechanism added to the given model as it is, and (``refit``)
    the model re-identified around the mechanism against the model re-identified without it
    (:func:`refit_score`), which finds what a model identified on the same runs has absorbed.

    Parameters
    ----------
    family : Family or its name.
    model : the given model (``f``, ``library``, ``coef``): kept fixed.
    weights : (3,) equation weights; default :func:`equation_weights` on ``train``.
    base_pred : optional cache ``{"train": (p, 3), "test": (p, 3)}`` of :func:`null_prediction`.
    uncertainty : compute leave-one-train-run-out standard deviations of the estimates.
    """
    family = FAMILY_SPECS[family] if isinstance(family, str) else family
    weights = equation_weights(model, train) if weights is None else weights
    base_pred = base_pred or {"train": null_prediction(model, train), "test": null_prediction(model, test)}
    grid = family.grid(train)
    design = design_for(family, model, train, grid, weights, base_pred["train"])
    _, sse_grid = solve_design(design)
    theta = _refine(family, model, train, grid, sse_grid, weights, base_pred["train"])
    y, X = residual_and_columns(family, model, train, theta[None], base_pred["train"])
    d_best = normal_equations(y, X, weights, train.window_run, len(train.names))
    beta, sse_train = solve_design(d_best)
    beta = beta[0]
    r0 = train.delta_v - base_pred["train"]
    sse0_train = float(np.sum(r0 * r0 * weights))
    # out of sample: the test runs with theta and beta from the train runs
    y_t, X_t = residual_and_columns(family, model, test, theta[None], base_pred["test"])
    res_t = y_t[0] - np.einsum("pem,m->pe", X_t[0], beta)
    r0_t = test.delta_v - base_pred["test"]
    per_win_ext = np.sum(res_t * res_t * weights, axis=1)
    per_win_0 = np.sum(r0_t * r0_t * weights, axis=1)
    run_w = test.window_run
    gain_runs = {}
    for i, name in enumerate(test.names):
        sel = run_w == i
        if sel.any():
            gain_runs[name] = float(1.0 - per_win_ext[sel].sum() / per_win_0[sel].sum())
    gain = float(1.0 - per_win_ext.sum() / per_win_0.sum())
    estimate = family.estimate(theta, beta, model)
    std = {}
    if uncertainty and len(train.names) > 1:
        loo = []
        for r in range(len(train.names)):
            keep = np.flatnonzero(np.arange(len(train.names)) != r)
            _, sse_r = solve_design(design, keep)
            th_r = _parabolic_argmin(grid, sse_r) if grid.shape[1] == 1 else grid[int(np.argmin(sse_r))]
            if grid.shape[1] == 3:  # patch geometry kept at the full-data optimum (the grid is coarser
                th_r = theta  # than the patch); the spread of beta given the patch is resampled
            yr, Xr = residual_and_columns(family, model, train, np.atleast_1d(th_r)[None], base_pred["train"])
            b_r = solve_design(normal_equations(yr, Xr, weights, train.window_run, len(train.names)), keep)[0][0]
            loo.append(family.estimate(np.atleast_1d(th_r), b_r, model))
        std = _jackknife(loo)
    profile = {}
    if grid.shape[1] == 1:
        profile = {"theta": grid[:, 0].tolist(), "train_sse": sse_grid.tolist()}
    score = FamilyScore(family.name, np.asarray(theta, float), np.asarray(beta, float), gain, gain_runs,
                        float(1.0 - sse_train[0] / sse0_train), estimate, std, profile)
    if refit and family.name != "lateral_slip":  # lateral terms are library terms: a refit absorbs them
        alt = refit_score(family, model, train, test, weights, theta)
        if alt["gain"] > gain:
            score = FamilyScore(family.name, alt["theta"], alt["beta"], alt["gain"], alt["gain_runs"], float("nan"),
                                {**alt["estimate"], "scored_with": "refit"}, alt["std"], alt["profile"] or profile)
    log.debug("%s: theta %s, beta %s, test gain %.4f, estimate %s", family.name, score.theta, score.beta,
              score.gain, score.estimate)
    return score
