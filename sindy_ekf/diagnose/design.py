"""The linear algebra of the diagnosis's integral regression, and the input-gain null.

The window integrals of a model's accelerations (eqs. 5.55 to 5.57), the weighted per-run normal
equations of candidates and their solution (:mod:`sindy_ekf.diagnose.fitting` builds the families'
columns on them), and the model with its input gains fitted on the train runs: the null of the
fixed-model scoring of the input-side families, with the gain columns of its linear nuisance.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from identification.sindy.library import LIBRARY_INPUT_NAMES, FeatureLibrary
from identification.sindy.model import SindyModel
from sindy_ekf.diagnose.data import Split

_MAX_CHUNK_ELEMENTS = 6_000_000  # candidates x samples x features per chunk (memory bound)


@dataclass(frozen=True)
class Design:
    """Weighted per-run normal equations of candidates: ``G (C, R, m, m)``, ``b (C, R, m)``, ``yy (C, R)``."""

    G: np.ndarray
    b: np.ndarray
    yy: np.ndarray


class ActiveTerms:
    """The model restricted to its active features: same ``f``, fewer columns to evaluate."""

    def __init__(self, model):
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


# degree of a variable in each atom code of the library (x, x^2, x^3, |x|, x|x|): every atom is
# positively homogeneous, so scaling an input by g > 0 scales an atom by g to this power
_ATOM_DEGREE = (1, 2, 3, 1, 2)
INPUT_GAIN_BOUNDS = (0.5, 2.0)


def input_degrees(library: FeatureLibrary) -> np.ndarray:
    """Return ``(k, 2)``: the degree of ``u1`` and ``u2`` in every feature of ``library``."""
    ins = [library.variables.index(n) for n in LIBRARY_INPUT_NAMES]
    deg = np.zeros((library.n_features, 2))
    for j, atoms in enumerate(library.atoms):
        for v, code in atoms:
            if v in ins:
                deg[j, ins.index(v)] = _ATOM_DEGREE[code]
    return deg


def with_input_gains(model, gains) -> SindyModel:
    """Return ``model`` whose motors see ``g_i u_i``: each coefficient times ``g1^a g2^b`` of its term.

    Exact for ``g > 0`` (every atom is positively homogeneous), and the same under the model's dead
    times and input lags, which are linear in the inputs.
    """
    scale = np.prod(np.asarray(gains, float)[None, :] ** input_degrees(model.library), axis=1)
    return replace(model, coef=np.asarray(model.coef) * scale)


def fit_input_gains(model, train: Split, weights: np.ndarray) -> np.ndarray:
    """Return the per-input gains ``(2,)`` of the motors relative to ``model``, fitted on the train windows.

    The model is kept fixed but for ``u_i -> g_i u_i``; ``g`` minimises the weighted window residual
    (eq. 5.55) in ``INPUT_GAIN_BOUNDS``. An input the model has no term of keeps gain 1.
    """
    act = ActiveTerms(model)
    deg = input_degrees(act.library)
    feats = train.integrate(act.library.transform(np.concatenate([train.v_body, train.u], axis=-1)))  # (p, k)
    dv, sw = train.delta_v, np.sqrt(weights)
    used = deg[np.any(act.coef != 0, axis=0)].any(axis=0)
    if not used.any():
        return np.ones(2)

    def resid(log_g_used):
        log_g = np.zeros(2)
        log_g[used] = log_g_used
        return ((dv - feats @ (act.coef * np.exp(deg @ log_g)).T) * sw).ravel()

    lo, hi = np.log(INPUT_GAIN_BOUNDS)
    sol = least_squares(resid, np.zeros(int(used.sum())), bounds=(lo, hi), x_scale=0.1)
    gains = np.ones(2)
    gains[used] = np.exp(sol.x)
    return gains


def gain_recalibrated(model, train: Split, weights: np.ndarray):
    """Return ``(model with its input gains fitted on train, gains)``: the null of the fixed-model scoring
    of the input-side families.

    A given model whose input gains are off on a campaign (a stiff output-error model amplifies any gain
    mismatch in its window residual, a real robot's motors drift between days) lets any gain-shaped
    mechanism buy that mismatch out of sample: time_dependence 0.117 on the clean real wheels runs
    (bench/results/diagnose_notes.md). Against the recalibrated model a mechanism is credited only for
    what a constant gain per input cannot explain: the per-campaign null of the gain-shaped families.
    """
    gains = fit_input_gains(model, train, weights)
    return with_input_gains(model, gains), gains


def equation_weights(model, split: Split) -> np.ndarray:
    """Return ``1 / var`` (3,) of the model's window residual per equation on ``split`` (train)."""
    r = split.delta_v - null_prediction(model, split)
    return 1.0 / np.maximum(np.mean(r * r, axis=0), 1e-12)


def chunks(n_cand: int, per_candidate: int):
    size = max(1, _MAX_CHUNK_ELEMENTS // max(per_candidate, 1))
    for a in range(0, n_cand, size):
        yield slice(a, min(a + size, n_cand))


def gain_derivative_coefs(act: ActiveTerms) -> np.ndarray:
    """Return ``(3 + 6, k)``: the active coefficients and their derivatives by ``log g_1``, ``log g_2``
    at ``g = 1`` (each feature's coefficient times its degree in the input), stacked by rows."""
    deg = input_degrees(act.library)
    return np.concatenate([act.coef, act.coef * deg[:, 0], act.coef * deg[:, 1]])


def model_and_gain_columns(act: ActiveTerms, split: Split, u_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the window integrals of the model's accelerations ``(C, p, 3)`` on the motor inputs
    ``u_m (C, N, 2)`` and of their derivatives by the log input gains ``(C, p, 3, 2)``."""
    x = np.broadcast_to(split.v_body, u_m.shape[:-1] + (3,))
    feats = act.library.transform(np.concatenate([x, u_m], axis=-1))  # (C, N, k)
    integ = split.integrate(feats @ gain_derivative_coefs(act).T)  # (C, p, 9)
    return integ[..., :3], np.moveaxis(integ[..., 3:].reshape(integ.shape[:-1] + (2, 3)), -2, -1)


def normal_equations(y: np.ndarray, X: np.ndarray, weights: np.ndarray, window_run: np.ndarray,
                     n_runs: int) -> Design:
    """Return the weighted normal equations per candidate and per run (sums over windows of a run).

    One batched matrix product per run: a three-operand einsum with a one-hot run matrix cost
    minutes on an 8-minute campaign with a dense model (100 columns; measured in the demo). A run's
    windows are a slice where the windows come in run order (:func:`run_groups`), so ``X`` is not
    copied per run; targets ``y`` shared by every candidate (a broadcast view, an additive family's)
    are summed once, not once per candidate (the floor patch's thousands of candidates: this function
    took 67 s of a 138 s diagnosis of the real wheels campaign before, 14 s after; the same sums to the
    last bit, ``tests/sindy_ekf/diagnose/test_kernels.py``; the whole diagnosis before and after:
    ``bench/results/diagnose_kernels.md``).
    """
    C, m = y.shape[0], X.shape[-1]
    G, b, yy = np.zeros((C, n_runs, m, m)), np.zeros((C, n_runs, m)), np.zeros((C, n_runs))
    shared = C > 1 and y.strides[0] == 0
    y1 = y[:1] if shared else y
    wy = y1 * weights
    wX = X * weights[:, None] if m else X
    for r, sel in enumerate(run_groups(window_run, n_runs)):
        # copies, as a boolean selection made them: the reduction's rounding does not depend on where a slice starts
        y_r, wy_r = y1[:, sel].reshape(len(y1), -1).copy(), wy[:, sel].reshape(len(y1), -1).copy()
        yy[:, r] = np.einsum("ck,ck->c", wy_r, y_r)
        if m:
            wX_r, X_r = wX[:, sel].reshape(C, -1, m), X[:, sel].reshape(C, -1, m)
            G[:, r] = np.swapaxes(wX_r, 1, 2) @ X_r
            b[:, r] = np.einsum("ckm,ck->cm", wX_r, np.broadcast_to(y_r, (C, y_r.shape[1])) if shared else y_r)
    return Design(G, b, yy)


def run_groups(window_run: np.ndarray, n_runs: int) -> list:
    """Return each run's windows: a slice where ``window_run (p,)`` is in run order, else a boolean mask."""
    if np.all(np.diff(window_run) >= 0):
        edges = np.searchsorted(window_run, np.arange(n_runs + 1))
        return [slice(int(a), int(c)) for a, c in zip(edges[:-1], edges[1:])]
    return [window_run == r for r in range(n_runs)]


def concat_designs(parts, axis: int = 0) -> Design:
    """Return the designs ``parts`` as one: candidates one after another (``axis`` 0) or runs (``axis`` 1)."""
    return Design(*(np.concatenate([getattr(p, k) for p in parts], axis=axis) for k in ("G", "b", "yy")))


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
