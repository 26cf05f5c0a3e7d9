"""The identified SINDy model as an object and as a self-describing JSON artefact.

:class:`SindyModel` holds the library and the coefficients ``Xi`` of eq. 5.53 and evaluates
the body dynamics ``x_dot = Theta(x, u) Xi`` with its analytic Jacobians, vectorised over any
leading axes. It speaks SINDy's own terms (``f(x3, u)`` on the body states, used by the search,
the diagnosis and the adjustment) and is a :class:`groundfloor.dynamics.Dynamics` (six states,
used by the evaluation and the filters, which call it at every step: there only the model's
active terms are evaluated, :class:`ActiveTerms`); :class:`StackedSindy` is many such models as
one dynamics, for the search's rollout of all grid points at once. The JSON file records
everything needed to rebuild it and to judge where it may be trusted: feature names,
coefficients per equation, library, hyperparameters ``s, tau, alpha, T``, the envelope of
states and inputs seen in training, the package version and a format version.
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import dataclass, field
from itertools import combinations_with_replacement
from pathlib import Path

import numpy as np

from groundfloor import __version__
from groundfloor.dynamics import Dynamics, EnvelopeWarning, broadcast_inputs
from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json
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
FORMAT_VERSION = 1


def envelope_from_data(x_body: np.ndarray, u: np.ndarray) -> dict[str, list[float]]:
    """Return the per-variable ``[min, max]`` of training states ``(n, 3)`` and inputs ``(n, 2)``."""
    z = np.column_stack([x_body, u])
    return {name: [float(np.nanmin(z[:, i])), float(np.nanmax(z[:, i]))]
            for i, name in enumerate(LIBRARY_VARIABLE_NAMES)}


class ActiveTerms:
    """The active terms of coefficients ``coef (3, k)`` of a library, evaluated with their Jacobians.

    Returns the accelerations and their Jacobians in the six-state layout from one matrix
    product of a table of monomials with a fixed weight matrix ``(columns, 3 + 18 + 6)``: every
    active term adds its coefficient to the column of its monomial (accelerations) and, for each
    of its variables, exponent times coefficient to the column of the monomial one degree lower
    (product rule; Jacobians). Polynomial libraries take the table of the monomials of the five
    variables up to degree 3 (56 rows), each degree from the one below in one gather and one
    product, so the whole evaluation is a handful of numpy calls whatever the model's size; libraries with ``|x|`` atoms gather each active term's
    (at most three) atoms from a table of atom values and their derivatives instead. The filters
    evaluate the model four times per step on a few runs at a time, where numpy's per-call
    overhead, not the arithmetic, is the cost.
    """

    # atom code (^1, ^2, ^3, abs, signsq) -> table block of its value; of its derivative and factor
    _VALUE = ("z", "z2", "z3", "abs", "zabs")
    _DERIV = ((None, 1.0), ("z", 2.0), ("z2", 3.0), ("sign", 1.0), ("abs", 2.0))

    def __init__(self, library: FeatureLibrary, coef: np.ndarray):
        nv = len(library.variables)  # [vx, vy, omega, u1, u2]
        self.n_vars = nv
        self.monomials = all(code <= 2 for atoms in library.atoms for _, code in atoms) and \
            all(sum(code + 1 for _, code in atoms) <= 3 for atoms in library.atoms)

        def out(e: int, v: int) -> int:  # output column of d a_e / d z_v: J_a_x (3, 6), J_a_u (3, 2)
            return 3 + 6 * e + 3 + v if v < 3 else 3 + 18 + 2 * e + (v - 3)

        if self.monomials:
            # rows of the monomial table: 1, then each product of 1, 2 or 3 variables once (sorted
            # factors); a row of degree d is a row of degree d - 1 times one variable
            monomials = [()] + [m for d in (1, 2, 3) for m in combinations_with_replacement(range(nv), d)]
            row = {m: r for r, m in enumerate(monomials)}
            self.products = [(slice(row[m[0]], row[m[-1]] + 1),
                              np.array([[row[f[:-1]] for f in m], [row[f[-1:]] for f in m]]))
                             for m in ([f for f in monomials if len(f) == d] for d in (2, 3))]
            self.weight = np.zeros((len(monomials), 27))
            for j, atoms in enumerate(library.atoms):
                c = coef[:, j]
                factors = tuple(sorted(v for v, code in atoms for _ in range(code + 1)))
                self.weight[row[factors], :3] += c
                for v in set(factors):
                    rest = list(factors)
                    rest.remove(v)
                    self.weight[row[tuple(rest)], [out(e, v) for e in range(3)]] += factors.count(v) * c
            self.weight_a = np.ascontiguousarray(self.weight[:, :3])  # accelerations alone: a smaller product
            return

        self.blocks = ("z", "z2", "z3", "abs", "zabs", "sign")

        def col_atom(block: str | None, var: int) -> int:  # column 0 is the constant 1
            return 0 if block is None else 1 + self.blocks.index(block) * nv + var

        index, weight = [], []
        for j, atoms in enumerate(library.atoms):
            c = coef[:, j]
            if not np.any(c):
                continue
            cols = [col_atom(self._VALUE[code], v) for v, code in atoms]
            index.append(cols + [0] * (3 - len(cols)))
            w = np.zeros(27)
            w[:3] = c
            weight.append(w)
            for m, (v, code) in enumerate(atoms):  # product rule: one row per factor
                block, factor = self._DERIV[code]
                rest = cols[:m] + cols[m + 1:]
                index.append([col_atom(block, v)] + rest + [0] * (2 - len(rest)))
                w = np.zeros(27)
                w[[out(e, v) for e in range(3)]] = factor * c
                weight.append(w)
        self.index = np.array(index, dtype=np.intp).reshape(-1, 3).T.copy()  # (3, rows)
        self.weight = np.array(weight, dtype=float).reshape(-1, 27)
        self.weight_a = np.ascontiguousarray(self.weight[:, :3])

    def __call__(self, v_body: np.ndarray, u: np.ndarray, jacobians: bool = True):
        """Return ``a (..., 3)``, ``J_a_x (..., 3, 6)`` and ``J_a_u (..., 3, 2)`` at body velocities
        ``v_body (..., 3)`` and inputs ``u (..., 2)`` of one leading shape; ``a`` alone if not ``jacobians``."""
        lead = v_body.shape[:-1]
        n = math.prod(lead)
        weight = self.weight if jacobians else self.weight_a
        if self.monomials:
            # the monomial table, one row per monomial: each degree is one gather and one product
            # written in place, a handful of numpy calls whatever the model's size
            table = np.empty((len(weight), n))
            table[0] = 1.0
            table[1:4], table[4:1 + self.n_vars] = v_body.reshape(n, 3).T, u.reshape(n, 2).T
            for rows, factors in self.products:
                f = np.take(table, factors, axis=0)
                np.multiply(f[0], f[1], out=table[rows])
            out = table.T @ weight
        else:
            z = np.concatenate([v_body, u], axis=-1).reshape(n, -1)
            z2, az = z * z, np.abs(z)
            parts = [np.ones((n, 1)), z, z2, z2 * z, az, z * az, np.sign(z)]
            g = np.take(np.concatenate(parts, axis=-1), self.index, axis=-1)  # (n, 3, rows)
            out = (g[:, 0, :] * g[:, 1, :] * g[:, 2, :]) @ weight
        out = out.reshape(lead + (weight.shape[1],))
        if not jacobians:
            return out
        return out[..., :3], out[..., 3:21].reshape(lead + (3, 6)), out[..., 21:].reshape(lead + (3, 2))


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
    """

    library: FeatureLibrary
    coef: np.ndarray
    hyperparameters: dict = field(default_factory=dict)
    envelope: dict = field(default_factory=dict)
    training: dict = field(default_factory=dict)
    version: str = ""
    name = "sindy"
    _active: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self.coef = np.asarray(self.coef, dtype=float)
        if self.coef.shape != (len(LIBRARY_STATE_NAMES), self.library.n_features):
            raise InputError(f"model coefficients: shape {self.coef.shape}, expected "
                             f"{(len(LIBRARY_STATE_NAMES), self.library.n_features)} for library {self.library.name!r}")
        if not self.version:
            self.version = __version__

    # dynamics -------------------------------------------------------------------------------
    def f(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return body accelerations ``[vx_dot, vy_dot, omega_dot]`` ``(..., 3)``. Implements eq. 5.53."""
        return self.library.transform(np.concatenate(_stack_xu(x, u), axis=-1)) @ self.coef.T

    def f_and_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``f (..., 3)``, ``J_f_x (..., 3, 3)`` and ``J_f_u (..., 3, 2)`` in one pass."""
        theta, d_theta = self.library.transform_with_jacobian(np.concatenate(_stack_xu(x, u), axis=-1))
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
        equal to :meth:`f_and_jacobians` up to the order of summation.
        """
        x6, u = broadcast_inputs(x6, u)
        return self._active_terms()(x6[..., 3:], u)

    def _active_terms(self) -> ActiveTerms:
        """Return the :class:`ActiveTerms` of the current ``coef`` (built again when it changed)."""
        key = self.coef.tobytes()
        if self._active is None or self._active[0] != key:
            self._active = (key, ActiveTerms(self.library, self.coef))
        return self._active[1]

    def in_envelope(self, x6: np.ndarray, u: np.ndarray, margin: float = 0.1) -> np.ndarray:
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
    def check_envelope(self, x: np.ndarray, u: np.ndarray, margin: float = 0.1, name: str = "data") -> float:
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
            "envelope": self.envelope,
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
            raise InputError(f"{source}: not a sindy-ekf model file (format {got!r}, expected {FORMAT!r})")
        if d.get("format_version") != FORMAT_VERSION:
            raise InputError(f"{source}: model format_version {d.get('format_version')!r} not supported "
                             f"(this is sindy-ekf reading version {FORMAT_VERSION})")
        lib_name = (d.get("library") or {}).get("name")
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
        return cls(library=library, coef=coef, hyperparameters=dict(d.get("hyperparameters") or {}),
                   envelope=dict(d.get("envelope") or {}), training=dict(d.get("training") or {}),
                   version=str(d.get("package_version", "")))

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


class StackedSindy(Dynamics):
    """Many SINDy models of one library as one dynamics: ``coef (M, 3, k)``, states ``(M, W, 6)``.

    The search's rollout predicts the held-out windows ``(W,)`` of all ``M`` models at once;
    inputs ``(W, 2)`` are shared by the models.
    """

    name = "stacked_sindy"

    def __init__(self, library: FeatureLibrary, coef: np.ndarray):
        self.library, self.coef = library, coef

    def _features(self, x6: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Return the library's variables ``(M, W, 5)`` at states ``(M, W, 6)`` and inputs ``(W, 2)``."""
        return np.concatenate([x6[..., 3:], np.broadcast_to(u, x6.shape[:-1] + (2,))], axis=-1)

    def accel(self, x6: np.ndarray, u: np.ndarray, t=0.0) -> np.ndarray:
        """Return accelerations ``(M, W, 3)``."""
        theta = self.library.transform(self._features(x6, u))
        return np.einsum("mwk,mek->mwe", theta, self.coef, optimize=False)

    def accel_and_jacobians(self, x6: np.ndarray, u: np.ndarray, t=0.0):
        """Return accelerations ``(M, W, 3)`` and their Jacobians ``(M, W, 3, 6)``, ``(M, W, 3, 2)``."""
        theta, d_theta = self.library.transform_with_jacobian(self._features(x6, u))
        J_a_z = np.einsum("mwvk,mek->mwev", d_theta, self.coef, optimize=False)
        J_a_x = np.zeros(J_a_z.shape[:-1] + (6,))
        J_a_x[..., 3:] = J_a_z[..., :3]
        return np.einsum("mwk,mek->mwe", theta, self.coef, optimize=False), J_a_x, J_a_z[..., 3:]


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
    """Return ``{equation: {term: fraction of models using it}}``, most common first (fig. 7.11)."""
    lib = models[0].library
    used = np.stack([m.coef != 0 for m in models])  # (n_models, 3, k)
    frac = used.mean(axis=0)
    out = {}
    for i, eq in enumerate(LIBRARY_STATE_NAMES):
        order = np.argsort(-frac[i], kind="stable")
        out[eq] = {lib.feature_names[j]: float(frac[i, j]) for j in order if frac[i, j] > 0}
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
