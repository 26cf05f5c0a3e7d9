"""The identified SINDy model as an object and as a self-describing JSON artefact.

:class:`SindyModel` holds the library and the coefficients ``Xi`` of eq. 5.53 and evaluates
the body dynamics ``x_dot = Theta(x, u) Xi`` with its analytic Jacobians, vectorised over any
leading axes. It speaks SINDy's own terms (``f(x3, u)`` on the body states, used by the search,
the diagnosis and the adjustment) and is a :class:`groundfloor.dynamics.Dynamics` (six states,
used by the evaluation and the filters, which call it at every step: there only the model's
active terms are evaluated, :class:`~identification.sindy.active_terms.ActiveTerms`); the JSON file records
everything needed to rebuild it and to judge where it may be trusted: feature names,
coefficients per equation, library, hyperparameters ``s, tau, alpha, T``, the envelope of
states and inputs seen in training, the input dead times, how the model extrapolates beyond
that envelope, the well-posedness checks, the package version and a format version.
"""

from __future__ import annotations

import json
import logging
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from groundfloor import __version__
from groundfloor.dynamics import Dynamics, EnvelopeWarning, broadcast_inputs
from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json
from identification.sindy.active_terms import ActiveTerms, linear_columns
from identification.sindy.library import (
    LIBRARY_INPUT_NAMES,
    LIBRARY_STATE_NAMES,
    LIBRARY_VARIABLE_NAMES,
    FeatureLibrary,
    make_library,
    parse_term,
)

log = logging.getLogger(__name__)

FORMAT = "sindy-ekf-model"
#: the format of the extended models diagnose writes (sindy_ekf.diagnose.extend.FORMAT), named in errors
EXTENDED_FORMAT = "sindy-ekf-extended-model"
FORMAT_VERSION = 3  # 2: dead_time_s, extrapolation, checks; 3: input_lag_s (formats 1 and 2 still load)


#: part of the envelope's width added on both sides: where a model is still trusted (the
#: envelope warning's margin) and where frozen extrapolation begins
EXTRAPOLATION_MARGIN = 0.1


def envelope_from_data(x_body: np.ndarray, u: np.ndarray) -> dict[str, list[float]]:
    """Return the per-variable ``[min, max]`` of training states ``(n, 3)`` and inputs ``(n, 2)``."""
    z = np.column_stack([x_body, u])
    return {name: [float(np.nanmin(z[:, i])), float(np.nanmax(z[:, i]))]
            for i, name in enumerate(LIBRARY_VARIABLE_NAMES)}


@dataclass
class SindyModel(Dynamics):
    """Identified body dynamics ``[vx, vy, omega]_dot = f(x, u)`` (eqs. 5.53, 5.63, 5.66).

    Parameters
    ----------
    library : FeatureLibrary
        Candidate functions ``Theta`` on ``[vx, vy, omega, u1, u2]``.
    coef : ndarray, shape (3, k)
        ``Xi^T``: one row per equation (``vx``, ``vy``, ``omega``), one column per feature.
    hyperparameters : dict
        ``s``, ``tau``, ``alpha``, ``T`` the model was fitted with.
    envelope : dict
        Variable name to ``[min, max]`` seen in training.
    training : dict
        Free-form facts about the fit (condition number, number of windows, runs).
    dead_time_s : (d1, d2)
        Input dead times: the model sees ``u_i(t - d_i)`` (the caller delays the inputs).
    input_lag_s : (T1, T2)
        First-order lags of the inputs before the dead time (:mod:`groundfloor.input_chain`):
        the motors' response to their command; zero is none.
    extrapolation : str
        ``"polynomial"``: the polynomial everywhere (models of format 1). ``"frozen"``: outside
        the training envelope widened by :data:`EXTRAPOLATION_MARGIN` of its width, the
        nonlinear terms see the body velocities clamped to it while the constant and linear
        terms go on linearly, so what the data never constrained stays bounded and a stable
        linear part pulls a wandering state back (the check of
        :func:`identification.sindy.checks.dissipativity`). Inside, both are the same.
    checks : dict
        The well-posedness checks with their numbers (:mod:`identification.sindy.checks`).
    """

    library: FeatureLibrary
    coef: np.ndarray
    hyperparameters: dict = field(default_factory=dict)
    envelope: dict = field(default_factory=dict)
    training: dict = field(default_factory=dict)
    version: str = ""
    dead_time_s: tuple = (0.0, 0.0)
    extrapolation: str = "polynomial"
    input_lag_s: tuple = (0.0, 0.0)
    checks: dict = field(default_factory=dict)
    name = "sindy"
    _active: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self.coef = np.asarray(self.coef, dtype=float)
        if self.coef.shape != (len(LIBRARY_STATE_NAMES), self.library.n_features):
            raise InputError(f"model coefficients: shape {self.coef.shape}, expected "
                             f"{(len(LIBRARY_STATE_NAMES), self.library.n_features)} for library {self.library.name!r}")
        if self.extrapolation not in ("polynomial", "frozen"):
            raise InputError(f"model extrapolation {self.extrapolation!r}: expected 'polynomial' or 'frozen'")
        self.dead_time_s = tuple(float(d) for d in self.dead_time_s)
        if len(self.dead_time_s) != 2 or not all(np.isfinite(self.dead_time_s)) or min(self.dead_time_s) < 0:
            raise InputError(f"model dead_time_s {self.dead_time_s!r}: expected two finite values >= 0")
        self.input_lag_s = tuple(float(v) for v in self.input_lag_s)
        if len(self.input_lag_s) != 2 or not all(np.isfinite(self.input_lag_s)) or min(self.input_lag_s) < 0:
            raise InputError(f"model input_lag_s {self.input_lag_s!r}: expected two finite values >= 0")
        if not self.version:
            self.version = __version__

    def with_coefficients(self, coef: np.ndarray, dead_time_s=None, input_lag_s=None) -> "SindyModel":
        """Return a copy with other coefficients (and dead times, input lags), everything else kept."""
        return replace(self, coef=np.asarray(coef, dtype=float),
                       dead_time_s=self.dead_time_s if dead_time_s is None else tuple(dead_time_s),
                       input_lag_s=self.input_lag_s if input_lag_s is None else tuple(input_lag_s))

    # extrapolation ----------------------------------------------------------------------------
    @property
    def linear_columns(self) -> np.ndarray:
        """Return per feature whether it is the constant or a plain variable (extrapolates linearly)."""
        return linear_columns(self.library)

    def _clamp_bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Return the widened envelope ``(lo, hi)`` of the body velocities, or None when not frozen."""
        env = self.envelope or {}
        if self.extrapolation != "frozen" or not all(v in env for v in LIBRARY_STATE_NAMES):
            return None
        lo = np.array([env[v][0] for v in LIBRARY_STATE_NAMES], float)
        hi = np.array([env[v][1] for v in LIBRARY_STATE_NAMES], float)
        pad = EXTRAPOLATION_MARGIN * (hi - lo)
        return lo - pad, hi + pad

    def library_variables(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return ``[vx, vy, omega, u1, u2]`` ``(..., 5)`` at six states ``x6`` and inputs ``u``."""
        x6, u = np.asarray(x6, dtype=float), np.asarray(u, dtype=float)
        lead = np.broadcast_shapes(x6.shape[:-1], u.shape[:-1])
        return np.concatenate([np.broadcast_to(x6[..., 3:], lead + (3,)), np.broadcast_to(u, lead + (2,))], -1)

    def features(self, z: np.ndarray) -> np.ndarray:
        """Return the features ``(..., k)`` the model multiplies by its coefficients at ``z (..., 5)``.

        ``Theta(z)`` (eq. 5.53); with ``extrapolation="frozen"`` the nonlinear features are taken
        at the body velocities clamped to the widened envelope.
        """
        theta = self.library.transform(z)
        bounds = self._clamp_bounds()
        if bounds is None:
            return theta
        zc = z.copy()
        zc[..., :3] = np.clip(z[..., :3], *bounds)
        return np.where(self.linear_columns, theta, self.library.transform(zc))

    # dynamics -------------------------------------------------------------------------------
    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return body accelerations ``[vx_dot, vy_dot, omega_dot]`` ``(..., 3)``. Implements eq. 5.53."""
        return self.features(np.concatenate(_stack_xu(x, u), axis=-1)) @ self.coef.T

    def f_and_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``f (..., 3)``, ``J_f_x (..., 3, 3)`` and ``J_f_u (..., 3, 2)`` in one pass."""
        z = np.concatenate(_stack_xu(x, u), axis=-1)
        theta, d_theta = self.library.transform_with_jacobian(z)
        bounds = self._clamp_bounds()
        if bounds is not None:
            zc = z.copy()
            zc[..., :3] = np.clip(z[..., :3], *bounds)
            theta_c, d_theta_c = self.library.transform_with_jacobian(zc)
            d_theta_c[..., :3, :] *= (zc[..., :3] == z[..., :3])[..., None]  # a clamped variable moves nothing
            lin = self.linear_columns
            theta = np.where(lin, theta, theta_c)
            d_theta = np.where(lin, d_theta, d_theta_c)
        J_f_z = np.einsum("...vk,ek->...ev", d_theta, self.coef)
        return theta @ self.coef.T, J_f_z[..., :3], J_f_z[..., 3:]

    def J_f_x(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the analytic Jacobian ``d f / d x`` ``(..., 3, 3)`` (product rule on the features)."""
        return self.f_and_jacobians(x, u)[1]

    def J_f_u(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the analytic Jacobian ``d f / d u`` ``(..., 3, 2)``."""
        return self.f_and_jacobians(x, u)[2]

    # the dynamics protocol (six states) -------------------------------------------------------
    def accel(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return :meth:`f` at the body velocities of ``x6 (..., 6)``: ``(..., 3)``.

        Evaluates only the active terms (:class:`ActiveTerms`), as :meth:`accel_and_jacobians`.
        """
        x6, u = broadcast_inputs(x6, u)
        return self._active_terms()(x6[..., 3:], u, jacobians=False)

    def accel_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t=0.0):
        """Return :meth:`f` and its Jacobians padded to the six states, ``(..., 3, 6)`` and ``(..., 3, 2)``.

        Evaluates only the active terms (:class:`ActiveTerms`, rebuilt when ``coef`` changes);
        equal to :meth:`f_and_jacobians` up to the order of summation. Frozen extrapolation
        evaluates the linear terms as one product and the nonlinear ones at the clamped state.
        """
        x6, u = broadcast_inputs(x6, u)
        return self._active_terms()(x6[..., 3:], u)

    def rk4_step_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t, dt, input_jacobian: bool = True):
        """Return the held-input RK4 step and its exact Jacobians ``(x_next, F, G)``, compiled.

        The same map as :meth:`groundfloor.dynamics.Dynamics.rk4_step_and_jacobians` (which this
        overrides) in one compiled call (:meth:`ActiveTerms.rk4_step`), frozen extrapolation
        included: the filters take it once per grid step. ``t`` is not used: the identified
        dynamics do not depend on time.
        """
        return self._active_terms().rk4_step(x6, u, dt, input_jacobian)

    def _active_terms(self) -> ActiveTerms:
        """Return the :class:`ActiveTerms` of the current ``coef`` and extrapolation (built again
        when either changed)."""
        key = self.coef.tobytes() + repr((self.extrapolation, self.envelope)).encode()
        if self._active is None or self._active[0] != key:
            self._active = (key, ActiveTerms(self.library, self.coef, frozen=self._clamp_bounds()))
        return self._active[1]

    def in_envelope(self, x6: np.ndarray, u: np.ndarray, margin: float = EXTRAPOLATION_MARGIN) -> np.ndarray:
        """Return True per sample where ``[vx, vy, omega, u1, u2]`` lies in the training envelope
        widened by ``margin`` times its width on both sides (the rule of :meth:`check_envelope`)."""
        x6 = np.asarray(x6, dtype=float)
        z = np.concatenate([x6[..., 3:], np.broadcast_to(u, x6.shape[:-1] + (2,))], axis=-1)
        return ~self._outside(z, margin).any(axis=-1)

    def warn_outside_envelope(self, x6: np.ndarray, u: np.ndarray, name: str = "data") -> float:
        """Return :meth:`check_envelope` of the body velocities of ``x6``: warns naming the variables."""
        return self.check_envelope(np.asarray(x6, dtype=float)[..., 3:], u, name=name)

    def _outside(self, z: np.ndarray, margin: float) -> np.ndarray:
        """Return per variable whether ``z (..., 5)`` lies outside the widened envelope (unknown
        variables and an empty envelope: never outside)."""
        env = self.envelope or {}
        lo = np.array([env[v][0] if v in env else -np.inf for v in LIBRARY_VARIABLE_NAMES])
        hi = np.array([env[v][1] if v in env else np.inf for v in LIBRARY_VARIABLE_NAMES])
        pad = margin * np.where(np.isfinite(hi - lo), hi - lo, 0.0)
        return (z < lo - pad) | (z > hi + pad)

    # description ----------------------------------------------------------------------------
    def active_terms(self, tol: float = 0.0) -> dict[str, dict[str, float]]:
        """Return ``{equation: {feature name: coefficient}}`` of the non-zero terms."""
        return {eq: {n: float(c) for n, c in zip(self.library.feature_names, row) if abs(c) > tol}
                for eq, row in zip(LIBRARY_STATE_NAMES, self.coef)}

    @property
    def complexity(self) -> int:
        """Number of active terms over all equations (the thesis's "model complexity")."""
        return int(np.count_nonzero(self.coef))

    def equations(self, precision: int = 3) -> str:
        """Return the model as text equations in the style of eqs. 7.4 to 7.9."""
        lines = []
        for eq, terms in self.active_terms().items():
            rhs = ""
            for name, c in terms.items():
                sign = "-" if c < 0 else "+"
                rhs += f" {sign} {abs(c):.{precision}f}" + ("" if name == "1" else f" {name}")
            rhs = rhs.strip()
            rhs = rhs[2:] if rhs.startswith("+ ") else ("-" + rhs[2:] if rhs.startswith("- ") else rhs)
            lines.append(f"d{eq}/dt = {rhs or f'{0:.{precision}f}'}")
        return "\n".join(lines)

    # envelope -------------------------------------------------------------------------------
    def check_envelope(self, x: np.ndarray, u: np.ndarray, margin: float = EXTRAPOLATION_MARGIN, name: str = "data") -> float:
        """Return the fraction of samples outside the training envelope; warn naming the variables.

        The envelope is widened by ``margin`` times its width on both sides before testing.
        Issues an :class:`EnvelopeWarning` when any sample lies outside.
        """
        if not self.envelope:
            return 0.0
        z = np.concatenate(_stack_xu(x, u), axis=-1).reshape(-1, len(LIBRARY_VARIABLE_NAMES))
        out = self._outside(z, margin)
        frac = float(out.any(axis=1).mean()) if len(z) else 0.0
        if frac > 0:
            worst = [f"{v} ({100 * out[:, i].mean():.1f} %)" for i, v in enumerate(LIBRARY_VARIABLE_NAMES)
                     if out[:, i].any()]
            msg = (f"{name}: {100 * frac:.1f} % of samples outside the model's training envelope: "
                   + ", ".join(worst))
            log.warning(msg)
            warnings.warn(msg, EnvelopeWarning, stacklevel=2)
        return frac

    # files ----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Return the JSON-ready description of the model."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "package_version": self.version,
            "library": self.library.params,
            "state_names": list(LIBRARY_STATE_NAMES),
            "input_names": list(LIBRARY_INPUT_NAMES),
            "feature_names": list(self.library.feature_names),
            "coefficients": {eq: [float(c) for c in row] for eq, row in zip(LIBRARY_STATE_NAMES, self.coef)},
            "equations": self.equations().splitlines(),
            "hyperparameters": self.hyperparameters,
            "dead_time_s": list(self.dead_time_s),
            "input_lag_s": list(self.input_lag_s),
            "extrapolation": self.extrapolation,
            "envelope": self.envelope,
            "checks": self.checks,
            "training": self.training,
        }

    def to_json(self, path: str | Path) -> Path:
        """Write the model to ``path`` atomically; return the path."""
        return atomic_write_json(path, self.to_dict())

    @classmethod
    def from_dict(cls, d: dict, source: str = "model") -> "SindyModel":
        """Return the model described by ``d``; raise InputError naming what does not fit."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            if got == EXTENDED_FORMAT:
                raise InputError(f"{source}: an extended model of `sindy-ekf diagnose --extended-model` (family "
                                 f"{d.get('family')!r}), not a model file of identify: diagnose scores it itself "
                                 "(its 5 s error after the extension, its EKF through GNSS outages); Python reads it "
                                 "with sindy_ekf.diagnose.extend.ExtendedModel.load")
            raise InputError(f"{source}: not a sindy-ekf model file (format {got!r}, expected {FORMAT!r})")
        version = d.get("format_version")
        if version not in (1, 2, FORMAT_VERSION):
            raise InputError(f"{source}: model format_version {version!r} not supported "
                             f"(this is sindy-ekf reading versions 1 to {FORMAT_VERSION}); re-identify the model")
        if version == 1:
            log.warning("%s: a model of format 1 (no dead time, no well-posedness checks, polynomial "
                        "extrapolation); re-identify it with this version for the checks", source)
        for key, expected in (("state_names", LIBRARY_STATE_NAMES), ("input_names", LIBRARY_INPUT_NAMES)):
            got = d.get(key)  # a model of other variables cannot run on a campaign's states and inputs
            if got is not None and (not isinstance(got, list) or got != list(expected)):
                raise InputError(f"{source}: model trained on {key.split('_')[0]}s {got!r}, but a campaign provides "
                                 f"{list(expected)}")
        lib = d.get("library")
        lib_name = lib.get("name") if isinstance(lib, dict) else lib  # the name alone, as a user may write it
        try:
            library = make_library(lib_name)
        except InputError:
            raise InputError(f"{source}: library {lib_name!r} is unknown to this version of sindy-ekf") from None
        names = d.get("feature_names")
        if list(names or []) != list(library.feature_names):
            bad = next((f"{a!r} != {b!r}" for a, b in zip(names or [], library.feature_names) if a != b),
                       f"{len(names or [])} features, expected {library.n_features}")
            raise InputError(f"{source}: feature_names do not match library {lib_name!r}: {bad}")
        try:
            coef = np.array([d["coefficients"][eq] for eq in LIBRARY_STATE_NAMES], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: key coefficients is missing or malformed ({exc})") from None
        if not np.all(np.isfinite(coef)):
            raise InputError(f"{source}: key coefficients holds non-finite values")
        if str(d.get("package_version", "")).split(".")[:2] != __version__.split(".")[:2]:
            log.warning("%s: written by sindy-ekf %s, read by %s", source, d.get("package_version"), __version__)
        try:
            dead_time = tuple(float(v) for v in d.get("dead_time_s") or (0.0, 0.0))
        except (TypeError, ValueError):
            raise InputError(f"{source}: key dead_time_s is malformed ({d.get('dead_time_s')!r})") from None
        try:
            input_lag = tuple(float(v) for v in d.get("input_lag_s") or (0.0, 0.0))
        except (TypeError, ValueError):
            raise InputError(f"{source}: key input_lag_s is malformed ({d.get('input_lag_s')!r})") from None
        try:
            return cls(library=library, coef=coef, hyperparameters=dict(d.get("hyperparameters") or {}),
                       envelope=dict(d.get("envelope") or {}), training=dict(d.get("training") or {}),
                       version=str(d.get("package_version", "")), dead_time_s=dead_time, input_lag_s=input_lag,
                       extrapolation=str(d.get("extrapolation") or "polynomial"), checks=dict(d.get("checks") or {}))
        except InputError as exc:  # the model's own checks (dead times, lags): name the file
            raise InputError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: str | Path) -> "SindyModel":
        """Return the model stored in the JSON file ``path``.

        Raises
        ------
        InputError
            If the file is missing, not JSON, not a model file, of another format version, of an
            unknown library, or its feature names differ from that library's.
        """
        return cls.from_dict(read_model_json(path), source=str(path))


def _stack_xu(x, u) -> tuple[np.ndarray, np.ndarray]:
    """Return ``x[..., :3]`` and ``u[..., :2]`` broadcast to a common leading shape."""
    x = np.asarray(x, dtype=float)[..., :3]
    u = np.asarray(u, dtype=float)[..., :2]
    lead = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    return np.broadcast_to(x, lead + (3,)), np.broadcast_to(u, lead + (2,))


def model_from_terms(terms: dict[str, dict[str, float]], library: str | FeatureLibrary = "poly3", **kw) -> SindyModel:
    """Return a model with the given ``{equation: {term: coefficient}}`` (e.g. ``true_terms()``).

    Terms are matched by meaning (:func:`~identification.sindy.library.parse_term`), so the order of
    factors in a name does not matter.

    Raises
    ------
    InputError
        If a term is not in the library or an equation is not ``vx``, ``vy`` or ``omega``.
    """
    lib = make_library(library) if isinstance(library, str) else library
    index = {a: j for j, a in enumerate(lib.atoms)}
    coef = np.zeros((3, lib.n_features))
    for eq, row in terms.items():
        if eq not in LIBRARY_STATE_NAMES:
            raise InputError(f"terms: unknown equation {eq!r} (expected one of {', '.join(LIBRARY_STATE_NAMES)})")
        for name, c in row.items():
            j = index.get(parse_term(name))
            if j is None:
                raise InputError(f"terms: {eq}: term {name!r} is not in library {lib.name!r}")
            coef[LIBRARY_STATE_NAMES.index(eq), j] = c
    return SindyModel(library=lib, coef=coef, **kw)


def term_prevalence(models: list[SindyModel]) -> dict[str, dict[str, float]]:
    """Return ``{equation: {term: fraction of models using it}}``, most common first (fig. 7.11).

    Terms are matched by name, so models of different libraries count together (the low-rate
    grid searches ``poly1``, ``poly3`` and ``poly3_absu``); ties keep the order of first appearance.
    """
    out = {}
    for i, eq in enumerate(LIBRARY_STATE_NAMES):
        counts: dict[str, int] = {}
        for m in models:
            for j in np.flatnonzero(m.coef[i]):
                name = m.library.feature_names[j]
                counts[name] = counts.get(name, 0) + 1
        ranked = sorted(counts.items(), key=lambda kv: -kv[1])  # stable: first appearance breaks ties
        out[eq] = {name: n / len(models) for name, n in ranked}
    return out


def read_model_json(path: str | Path):
    """Return the parsed JSON of the model file ``path``; InputError if missing or not JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: model file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a JSON model file ({exc})") from None
