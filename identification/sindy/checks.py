"""Questions asked of an identified model and of its training data, without fitting anything.

Well-posedness (issue 13, item 4): a model the package selects must pass all of these, and its
file records them (``checks`` in the model JSON, :func:`run_checks`):

- **stable at rest**: every eigenvalue of ``J_f_x(0, 0)`` has a real part <= :data:`STABILITY_TOL`
  (a robot left alone comes to rest);
- **contribution bound**: no active nonlinear term contributes more than
  :data:`CONTRIBUTION_FACTOR` times the largest measured body acceleration of its equation at
  any training sample (:func:`contribution_bound`): a term that only fits by cancelling another
  huge one, or a huge coefficient on a feature the data barely move (powers of ``vy`` when ``vy``
  is millimetres per second), fails. Linear terms are exempt: a fast first-order lag
  (``-vx / tau + k u1 / tau`` with ``tau`` of tens of milliseconds, what measured wheel speeds
  give) has large, cancelling, well-determined linear terms, and the linear part is what the
  stability and dissipativity checks judge;
- **dissipative outside the envelope**: the linear part is stable, and from training states with
  one body velocity pushed one envelope width beyond the envelope on its own side (inputs as
  they were), that velocity's derivative points back toward the envelope (:func:`dissipativity`): the vector
  field points inward on the faces of the widened box, so an estimator's wandering state
  cannot run away;
- **bounded under a held input**: from training states, the inputs they had held constant for
  :data:`HELD_INPUT_HORIZON_S` (the scoring horizon), the model never leaves the box the
  dissipativity check uses (:func:`held_input`). A robot whose joystick is held comes to a steady
  motion (the true dynamics of all 10 simulator variants do, tests/identification/sindy/test_held_input.py);
  a polynomial fitted on passing through a state may have none there and run away. On simulator
  variant 7 (45 min) 3 of the 8 candidates refitted on all train runs leave the box this way within
  5 s, 2 of them passing every other check (and so does its true structure refitted by output
  error). Its selected model is not among them: its two runaway test windows (a turn held at
  ``u = (0.64, -0.60)``, a combination the train runs never hold) reach wrong but bounded velocities
  inside the box, and no check without data there can tell them from right ones;
- **significant terms**: every active coefficient beyond the first-order lag's is at least
  :data:`MIN_T_STAT` standard errors from zero (the output-error fit's cluster-robust standard
  errors). The lag's own terms (:func:`lag_core`: each state's damping by itself, each input's
  gain on its axis) are the model class's base and are not tested one by one: a fast lag's two
  terms are strongly correlated (only their ratio, the gain, is sharp), so each alone can look
  insignificant although dropping either destroys the model; without the damping a state drifts
  with whatever it starts from.

The search ranks grid points by stability at rest; the diagnosis asks it of the models it
extends. :func:`not_excited` says which variables the training data do not excite beyond their noise.
"""

from __future__ import annotations

import logging
from typing import Sequence

import numpy as np

from groundfloor.errors import InputError
from groundfloor.input_chain import chain_inputs
from groundfloor.types import BodyStates
from identification.sindy.library import LIBRARY_STATE_NAMES, LIBRARY_VARIABLE_NAMES, FeatureLibrary
from identification.sindy.model import SindyModel

log = logging.getLogger(__name__)

STABILITY_TOL = 1e-9  # largest real part of an eigenvalue of J_f_x at rest still counted as stable
#: a term may contribute at most this many times the largest measured acceleration of its equation
CONTRIBUTION_FACTOR = 10.0
#: how far beyond the envelope (in its widths) the dissipativity check pushes a state
DISSIPATIVE_WIDTHS = 1.0
#: how long the held-input check holds each input: the horizon a prediction is scored at (5 s windows)
HELD_INPUT_HORIZON_S = 5.0
#: RK4 step of the held-input check: the search's and the output-error fit's step (a model too stiff
#: for it diverges there too)
HELD_INPUT_DT_S = 0.05
#: training samples the held-input check starts from (evenly spread)
HELD_INPUT_SAMPLES = 400
#: percentile of |measured acceleration| taken as "the largest" (robust to a single glitch)
ACCEL_PERCENTILE = 99.0
#: smallest |coefficient| / standard error of a kept term (about 95 % two-sided)
MIN_T_STAT = 2.0
#: a body velocity is excited when, over this horizon, what it moves the robot stands out of what
#: the pose noise alone makes (:func:`not_excited`)
EXCITATION_HORIZON_S = 1.0
#: the detection limit of :func:`not_excited`, in standard deviations of the noise-only signal
EXCITATION_SIGMAS = 3.0


def max_re_eig_at_rest(library: FeatureLibrary, coef: np.ndarray) -> np.ndarray:
    """Return the largest real part of the eigenvalues of ``J_f_x`` at rest (x = 0, u = 0) for
    coefficient arrays ``coef (..., 3, k)`` of ``library`` (``J_f_x = coef @ d_theta/dx``)."""
    _, d_theta0 = library.transform_with_jacobian(np.zeros(5))
    J = np.einsum("...ek,vk->...ev", coef, d_theta0[:3])
    with np.errstate(invalid="ignore"):
        eig = np.where(np.isfinite(J).all(axis=(-2, -1)), np.linalg.eigvals(np.nan_to_num(J)).real.max(axis=-1),
                       np.inf)
    return eig


def stable_at_rest(model: SindyModel) -> bool:
    """Return whether the model comes to rest by itself: :func:`max_re_eig_at_rest` <= :data:`STABILITY_TOL`."""
    return bool(max_re_eig_at_rest(model.library, model.coef) <= STABILITY_TOL)


def measured_accel_max(states: Sequence[BodyStates]) -> np.ndarray:
    """Return the largest measured body acceleration per equation ``(3,)`` (the
    :data:`ACCEL_PERCENTILE` of ``|dv/dt|`` of the states, by central differences per segment)."""
    acc = [np.gradient(st.state, st.t, axis=0) for st in states if len(st.t) > 2]
    return np.percentile(np.abs(np.vstack(acc)), ACCEL_PERCENTILE, axis=0)


def seen_samples(model: SindyModel, states: Sequence[BodyStates]) -> np.ndarray:
    """Return ``[vx, vy, omega, u1, u2]`` ``(N, 5)`` of the training samples with the inputs as the
    model sees them (through its dead time and input lags, :mod:`groundfloor.input_chain`): what
    its features are evaluated on; a step of the recorded command never reaches a lagged model."""
    return np.vstack([np.column_stack([st.state, chain_inputs(st.t, st.t, st.inputs, model.dead_time_s,
                                                              model.input_lag_s)]) for st in states])


def contribution_bound(model: SindyModel, states: Sequence[BodyStates], accel_max: np.ndarray | None = None,
                       factor: float = CONTRIBUTION_FACTOR) -> dict:
    """Return the contribution check: the largest ``|xi_ej theta_j|`` over the training samples
    per active nonlinear term against ``factor`` times the largest measured acceleration of equation ``e``.

    Returns ``{"passed", "worst_term", "worst_ratio", "factor", "accel_max"}`` (ratio 1 = at the bound).
    """
    accel_max = measured_accel_max(states) if accel_max is None else np.asarray(accel_max, float)
    z = seen_samples(model, states)
    theta = model.features(z)
    scale = np.maximum(accel_max, damping_scale(model, z))
    worst, worst_term = 0.0, ""
    for e, j in zip(*np.nonzero(model.coef * ~model.linear_columns)):
        ratio = float(np.max(np.abs(model.coef[e, j] * theta[:, j])) / (factor * max(scale[e], 1e-9)))
        if ratio > worst:
            worst, worst_term = ratio, f"{LIBRARY_STATE_NAMES[e]}: {model.library.feature_names[j]}"
    return {"passed": bool(worst <= 1.0), "worst_term": worst_term, "worst_ratio": worst, "factor": factor,
            "accel_max": [float(a) for a in accel_max], "scale": [float(v) for v in scale]}


def damping_scale(model: SindyModel, z: np.ndarray) -> np.ndarray:
    """Return the size of each equation's own damping term over the samples ``z (N, 5)`` ``(3,)``:
    the :data:`ACCEL_PERCENTILE` of ``|xi_(e, v_e) v_e|`` (zero where the equation has none).

    A stiff equation (a lateral velocity that settles within a few tens of milliseconds on
    ``k vx omega``) holds terms much larger than the accelerations it produces, because they
    cancel; its damping says how large its forces are. A term above both this and the measured
    accelerations is what the check is for: a huge coefficient in a direction the data barely move.
    """
    names = model.library.feature_names
    out = np.zeros(len(LIBRARY_STATE_NAMES))
    for e, v in enumerate(LIBRARY_STATE_NAMES):
        if v in names and model.coef[e, names.index(v)] != 0.0:
            out[e] = np.percentile(np.abs(model.coef[e, names.index(v)] * z[:, e]), ACCEL_PERCENTILE)
    return out


def dissipativity(model: SindyModel, states: Sequence[BodyStates], n_samples: int = 200) -> dict:
    """Return the dissipativity check: from training states pushed out of the envelope, the
    derivatives point back toward it.

    Two parts. Far out, frozen extrapolation (:class:`~identification.sindy.model.SindyModel`)
    continues linearly from the envelope's edge with the model's linear part ``A``, so a state
    can come back from anywhere only when ``A`` is stable (eigenvalues in the open left half
    plane). Near the envelope, the vector field must point inward on the faces of the box widened
    by :data:`DISSIPATIVE_WIDTHS` envelope widths ``w`` (the sub-tangential condition of Nagumo's
    theorem, which makes the box forward invariant): ``n_samples`` training samples (evenly
    spread) are each pushed, one body velocity ``v_i`` at a time, onto the face on their own side
    of the envelope's centre with the other velocities and the inputs as they were, and
    ``sign(push) f_i / w_i`` must be negative there. The states are those an estimator reaches
    when one velocity wanders off from where it was, not the opposite corners of the envelope's
    box (a robot reversing at full reverse throttle carried to full forward speed), combinations
    the data never hold and where a polynomial fitted on the data means nothing. Returns ``{"passed", "worst_rate",
    "worst_state", "n_points"}`` (``worst_rate`` the largest outward ``sign(push) f_i / w_i``,
    1/s); without an envelope it passes vacuously with ``n_points`` 0.
    """
    box = widened_box(model)
    if box is None:
        return {"passed": True, "worst_rate": None, "worst_state": None, "n_points": 0}
    lo_w, hi_w = box
    w = (hi_w - lo_w) / (1.0 + 2.0 * DISSIPATIVE_WIDTHS)  # the envelope's widths
    A = model.f_and_jacobians(np.zeros(3), np.zeros(2))[1]  # the linear part: J_f_x at rest
    if not np.all(np.isfinite(A)) or np.linalg.eigvals(A).real.max() >= 0:
        return {"passed": False, "worst_rate": float("inf"), "worst_state": None, "n_points": 0,
                "reason": "linear part not stable: no way back from far outside"}
    z = seen_samples(model, states)
    z = z[np.round(np.linspace(0, len(z) - 1, min(n_samples, len(z)))).astype(int)]
    pushed, outward = [], []
    for i in range(3):
        side = np.where(z[:, i] >= 0.5 * (lo_w[i] + hi_w[i]), 1.0, -1.0)  # the face on the sample's own side
        p = z.copy()
        p[:, i] = np.where(side > 0, hi_w[i], lo_w[i])
        pushed.append(p)
        outward.append(side * model.f(p[:, :3], p[:, 3:])[:, i] / w[i])
    z, rate = np.vstack(pushed), np.concatenate(outward)
    rate = np.where(np.isfinite(rate), rate, np.inf)
    k = int(np.argmax(rate))
    return {"passed": bool(rate[k] < 0), "worst_rate": float(rate[k]),
            "worst_state": dict(zip(LIBRARY_VARIABLE_NAMES, map(float, z[k]))), "n_points": int(len(z))}


def widened_box(model: SindyModel) -> tuple[np.ndarray, np.ndarray] | None:
    """Return the envelope's box of the body velocities widened by :data:`DISSIPATIVE_WIDTHS` widths
    on each side ``(lo, hi)``, or None without an envelope."""
    env = model.envelope or {}
    if not all(v in env for v in LIBRARY_VARIABLE_NAMES):
        return None
    lo = np.array([env[v][0] for v in LIBRARY_STATE_NAMES], float)
    hi = np.array([env[v][1] for v in LIBRARY_STATE_NAMES], float)
    w = np.maximum(hi - lo, 1e-6)
    return lo - DISSIPATIVE_WIDTHS * w, hi + DISSIPATIVE_WIDTHS * w


def held_excursion(f, x0: np.ndarray, u: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   horizon_s: float = HELD_INPUT_HORIZON_S, dt: float = HELD_INPUT_DT_S) -> np.ndarray:
    """Return when each start ``x0 (N, 3)`` under its held input ``u (N, 2)`` leaves the box
    ``[lo, hi]`` of the body velocities, integrating ``dx/dt = f(x, u)`` (vectorised over
    samples) by RK4 with step ``dt`` over ``horizon_s`` ``(N,)``: seconds, ``inf`` where it stays
    (a non-finite state counts as left)."""
    x, u = np.array(x0, dtype=float), np.asarray(u, dtype=float)
    left = np.full(len(x), np.inf)
    alive = np.ones(len(x), bool)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(1, int(round(horizon_s / dt)) + 1):
            xa, ua = x[alive], u[alive]
            k1 = f(xa, ua)
            k2 = f(xa + 0.5 * dt * k1, ua)
            k3 = f(xa + 0.5 * dt * k2, ua)
            k4 = f(xa + dt * k3, ua)
            xa = xa + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            x[alive] = xa
            out = ~np.isfinite(xa).all(axis=-1) | ((xa < lo) | (xa > hi)).any(axis=-1)
            idx = np.flatnonzero(alive)
            left[idx[out]] = k * dt
            alive[idx[out]] = False
            if not alive.any():
                break
    return left


def held_input(model: SindyModel, states: Sequence[BodyStates], n_samples: int = HELD_INPUT_SAMPLES,
               horizon_s: float = HELD_INPUT_HORIZON_S) -> dict:
    """Return the held-input check: from ``n_samples`` training samples (evenly spread; the inputs
    as the model sees them, :func:`seen_samples`), each sample's inputs held constant for
    ``horizon_s``, the body velocities stay in the box of :func:`dissipativity` (the envelope
    widened by :data:`DISSIPATIVE_WIDTHS` widths, :func:`widened_box`).

    Returns ``{"passed", "n_left", "n_points", "horizon_s", "first_left_s", "worst_start"}``:
    how many starts left the box, after how long the first did and from which sample
    (``[vx, vy, omega, u1, u2]``); without an envelope it passes vacuously with ``n_points`` 0.
    """
    box = widened_box(model)
    if box is None:
        return {"passed": True, "n_left": 0, "n_points": 0, "horizon_s": horizon_s, "first_left_s": None,
                "worst_start": None}
    z = seen_samples(model, states)
    z = z[np.round(np.linspace(0, len(z) - 1, min(n_samples, len(z)))).astype(int)]
    left = held_excursion(model.f, z[:, :3], z[:, 3:], *box, horizon_s=horizon_s)
    k = int(np.argmin(left))
    gone = np.isfinite(left)
    return {"passed": bool(not gone.any()), "n_left": int(gone.sum()), "n_points": int(len(z)),
            "horizon_s": horizon_s, "first_left_s": float(left[k]) if gone.any() else None,
            "worst_start": dict(zip(LIBRARY_VARIABLE_NAMES, map(float, z[k]))) if gone.any() else None}


def self_terms(model: SindyModel) -> np.ndarray:
    """Return the mask ``(3, k)`` of each state's damping by itself (``vx`` in the ``vx`` equation, ...)."""
    return _linear_terms(model, ((0, 0), (1, 1), (2, 2)))


def lag_core(model: SindyModel) -> np.ndarray:
    """Return the mask ``(3, k)`` of the first-order lag's terms: the self-damping of each state
    and each input's gain on its axis (``u1`` in the ``vx`` equation, ``u2`` in the ``omega`` one)."""
    return _linear_terms(model, ((0, 0), (1, 1), (2, 2), (0, 3), (2, 4)))


def _linear_terms(model: SindyModel, pairs) -> np.ndarray:
    """Return the mask ``(3, k)`` of the plain-variable features ``(equation, variable index)``."""
    mask = np.zeros(model.coef.shape, bool)
    for e, v in pairs:
        if ((v, 0),) in model.library.atoms:
            mask[e, model.library.atoms.index(((v, 0),))] = True
    return mask


def significance(names: Sequence[str], t_stat: np.ndarray, protected: np.ndarray) -> dict:
    """Return the significance check of active terms ``names`` with ``t_stat`` (``protected`` exempt)."""
    t = np.asarray(t_stat, float)
    free = ~np.asarray(protected, bool)
    if not free.any():
        return {"passed": True, "min_t": None, "weakest": None, "min_t_required": MIN_T_STAT}
    k = int(np.flatnonzero(free)[np.argmin(t[free])])
    return {"passed": bool(t[k] >= MIN_T_STAT), "min_t": float(t[k]), "weakest": names[k],
            "min_t_required": MIN_T_STAT}


def excitation(states: Sequence[BodyStates]) -> dict[str, float]:
    """Return the standard deviation over ``states`` of each library variable ``{name: std}``."""
    z = np.vstack([np.column_stack([st.state, st.inputs]) for st in states])
    return {name: float(np.std(z[:, i])) for i, name in enumerate(LIBRARY_VARIABLE_NAMES)}


def not_excited(states: Sequence[BodyStates], pose_noise: Sequence[tuple[float, float]]) -> list[str]:
    """Return the library variables the train segments ``states`` do not excite beyond their noise.

    Relative to the data's own noise, no hand-set level: a body velocity is excited when the
    displacement it makes over :data:`EXCITATION_HORIZON_S` (its integral over the horizon,
    metres for ``vx``, ``vy``, radians for ``omega``) has a standard deviation above
    :data:`EXCITATION_SIGMAS` times what pose noise alone gives, ``sqrt(2)`` times the pose
    noise ``pose_noise[i] = (sigma_position_m, sigma_yaw_rad)`` of segment ``i`` (a smoothed
    velocity integrates to the difference of two smoothed poses, whose noise is at most the
    poses'). An input is excited when its standard deviation is above the same multiple of its
    recorded resolution (the smallest step between its distinct values): a constant input, or one
    jittering by a few counts, is not.
    """
    names = []
    for i, v in enumerate(LIBRARY_STATE_NAMES):
        moved, floor = [], []
        for st, (sigma_xy, sigma_yaw) in zip(states, pose_noise):
            t = np.asarray(st.t, float)
            if t[-1] - t[0] <= EXCITATION_HORIZON_S:
                continue
            integral = np.concatenate([[0.0], np.cumsum(0.5 * (st.state[1:, i] + st.state[:-1, i]) * np.diff(t))])
            ahead = np.interp(t + EXCITATION_HORIZON_S, t, integral)[t + EXCITATION_HORIZON_S <= t[-1]]
            moved.append(ahead - integral[:len(ahead)])
            floor.append(np.sqrt(2.0) * (sigma_yaw if v == "omega" else sigma_xy))
        if not moved or np.std(np.concatenate(moved)) <= EXCITATION_SIGMAS * float(np.max(floor)):
            names.append(v)
    for i, v in enumerate(LIBRARY_VARIABLE_NAMES[len(LIBRARY_STATE_NAMES):], start=len(LIBRARY_STATE_NAMES)):
        u = np.concatenate([st.inputs[:, i - len(LIBRARY_STATE_NAMES)] for st in states])
        levels = np.unique(u[np.isfinite(u)])
        if levels.size < 2 or np.std(u) <= EXCITATION_SIGMAS * float(np.min(np.diff(levels))):
            names.append(v)
    return names


def run_checks(model: SindyModel, states: Sequence[BodyStates], names: Sequence[str] = (),
               t_stat: np.ndarray | None = None, accel_max: np.ndarray | None = None) -> dict:
    """Return all checks of the module docstring as a JSON-ready dict with ``"passed"`` overall.

    ``names`` and ``t_stat`` are the output-error fit's active terms and their t statistics
    (significance is reported as not run without them).
    """
    eig = float(max_re_eig_at_rest(model.library, model.coef))
    out = {"stable_at_rest": {"passed": bool(eig <= STABILITY_TOL), "max_re_eig": eig},
           "contribution": contribution_bound(model, states, accel_max),
           "dissipative": dissipativity(model, states), "held_input": held_input(model, states)}
    if t_stat is not None:
        core = lag_core(model)
        feats = model.library.feature_names
        # the adjustment's terms by name: a fixed term (an unexcited state's damping) is not among them
        protected = np.array([core[LIBRARY_STATE_NAMES.index(n.split(": ", 1)[0]), feats.index(n.split(": ", 1)[1])]
                              for n in names], bool)
        out["significance"] = significance(names, t_stat, protected)
    out["passed"] = all(v["passed"] for v in out.values())
    return out


def failed_checks(checks: dict) -> list[str]:
    """Return the names of the checks in a model file's ``checks`` that failed."""
    return [k for k, v in checks.items() if isinstance(v, dict) and not v.get("passed", True)]


def require_checks_passed(model: SindyModel, source: str) -> None:
    """Return nothing when the model file's recorded checks passed; refuse a model that failed them.

    A model without recorded checks (format 1, or built by hand) is used with a loud warning:
    nothing says it is well posed. ``source`` names the file in the messages.

    Raises
    ------
    InputError
        The model's ``checks`` say it failed (names the failed checks).
    """
    if not model.checks:
        log.warning("%s: the model records no well-posedness checks (format 1 or built by hand); its "
                    "predictions may run away outside its training envelope: re-identify it", source)
        return
    failed = failed_checks(model.checks)
    if failed or not model.checks.get("passed", True):
        raise InputError(f"{source}: the model fails its well-posedness checks "
                         f"({', '.join(failed) or 'passed: false'}); re-identify it (sindy-ekf identify)")
