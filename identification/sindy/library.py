"""Candidate-function libraries for SINDy with control (thesis 5.3.2, 5.3.4 and 7.8).

Every library is built from pysindy (``PolynomialLibrary``, ``CustomLibrary`` joined by
``GeneralizedLibrary``) on the variables ``[vx, vy, omega, u1, u2]``, and has a stable name
that a model file records:

- ``poly1``, ``poly2``, ``poly3``: polynomials up to that degree with bias, as the thesis
  (section 5.3.4, degree 3: 56 features);
- ``poly3_absu``: ``poly3`` plus ``|u1|, |u2|, u1|u1|, u2|u2|``, the input terms section 7.8
  proposes to keep the model symmetric without quadratic inputs;
- ``poly3_signsq``: ``poly3_absu`` plus the sign-keeping squares ``vx|vx|, vy|vy|,
  omega|omega|`` of the states (section 7.8, "terms like a|a|").

pysindy builds the library and names its features. For speed (the EKF evaluates the model and
its Jacobian at every step) :class:`FeatureLibrary` evaluates the same features without
pysindy: each feature name is parsed into at most three *atoms* (``x``, ``x^2``, ``x^3``,
``|x|``, ``x|x|`` of one variable), and the features become two vectorised products over an
atom table; their derivatives follow from the product rule. The tests check both against
``pysindy``'s ``transform`` and against numerical derivatives.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from groundfloor.errors import InputError

# The library's variables: the body states its equations predict and the inputs (not the six
# estimated states of groundfloor.dynamics.STATE_NAMES).
LIBRARY_STATE_NAMES = ("vx", "vy", "omega")
LIBRARY_INPUT_NAMES = ("u1", "u2")
LIBRARY_VARIABLE_NAMES = LIBRARY_STATE_NAMES + LIBRARY_INPUT_NAMES
LIBRARY_NAMES = ("poly1", "poly2", "poly3", "poly3_absu", "poly3_signsq")

# Atom codes per variable: powers 1..3, absolute value, sign-keeping square.
_ATOM_CODES = ("^1", "^2", "^3", "abs", "signsq")
_N_CODES = len(_ATOM_CODES)
_TOKEN = re.compile(r"^(?:\|(?P<abs>\w+)\||(?P<sq>\w+)\|(?P=sq)\||(?P<var>\w+)(?:\^(?P<pow>\d))?)$")


def parse_term(name: str, variables: tuple[str, ...] = LIBRARY_VARIABLE_NAMES) -> tuple[tuple[int, int], ...]:
    """Return a feature name as sorted ``(variable index, atom code)`` pairs.

    ``"vx omega^2"`` gives ``((0, 0), (2, 1))``; ``"1"`` gives ``()``. The order of the factors
    in the name does not matter, so names written by hand (the simulator's ``true_terms``)
    compare equal to pysindy's.

    Raises
    ------
    InputError
        If a factor is not a known variable, power (1 to 3), ``|x|`` or ``x|x|``.
    """
    name = name.strip()
    if name == "1":
        return ()
    atoms = []
    for token in name.split():
        m = _TOKEN.match(token)
        if m is None:
            raise InputError(f"feature {name!r}: cannot parse factor {token!r}")
        if m["abs"]:
            var, code = m["abs"], 3
        elif m["sq"]:
            var, code = m["sq"], 4
        else:
            var, power = m["var"], int(m["pow"] or 1)
            if not 1 <= power <= 3:
                raise InputError(f"feature {name!r}: power {power} outside 1..3")
            code = power - 1
        if var not in variables:
            raise InputError(f"feature {name!r}: unknown variable {var!r} (known: {', '.join(variables)})")
        atoms.append((variables.index(var), code))
    if len({v for v, _ in atoms}) != len(atoms):
        raise InputError(f"feature {name!r}: a variable appears twice")
    return tuple(sorted(atoms))


def term_name(atoms: tuple[tuple[int, int], ...], variables: tuple[str, ...] = LIBRARY_VARIABLE_NAMES) -> str:
    """Return the pysindy-style name of a term given as ``(variable index, atom code)`` pairs."""
    if not atoms:
        return "1"
    parts = []
    for var, code in atoms:
        v = variables[var]
        parts.append({0: v, 1: f"{v}^2", 2: f"{v}^3", 3: f"|{v}|", 4: f"{v}|{v}|"}[code])
    return " ".join(parts)


def _pysindy_library(name: str):
    """Return the unfitted pysindy library called ``name``."""
    import pysindy as ps  # local: pysindy loads scikit-learn (about 2 s); importing the package must not

    m = re.fullmatch(r"poly([123])(_absu|_signsq)?", name)
    if m is None:
        raise InputError(f"library {name!r}: unknown (known: {', '.join(LIBRARY_NAMES)})")
    poly = ps.PolynomialLibrary(degree=int(m[1]), include_bias=True)
    if m[2] is None:
        return poly
    abs_u = ps.CustomLibrary(
        library_functions=[lambda x: np.abs(x), lambda x: x * np.abs(x)],
        function_names=[lambda s: f"|{s}|", lambda s: f"{s}|{s}|"],
    )
    libs, inputs = [poly, abs_u], [[0, 1, 2, 3, 4], [3, 4]]
    if m[2] == "_signsq":
        sq_x = ps.CustomLibrary(library_functions=[lambda x: x * np.abs(x)],
                                function_names=[lambda s: f"{s}|{s}|"])
        libs.append(sq_x)
        inputs.append([0, 1, 2])
    return ps.GeneralizedLibrary(libs, inputs_per_library=inputs)


@dataclass(frozen=True)
class FeatureLibrary:
    """A named candidate library on ``[vx, vy, omega, u1, u2]`` with fast evaluation.

    Build it with :func:`make_library`. ``feature_names`` are pysindy's names in pysindy's order;
    :meth:`transform` equals pysindy's ``transform`` (tested) but works on any leading axes.
    """

    name: str
    feature_names: tuple[str, ...]
    variables: tuple[str, ...] = LIBRARY_VARIABLE_NAMES
    atoms: tuple[tuple[tuple[int, int], ...], ...] = field(init=False, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "atoms", tuple(parse_term(n, self.variables) for n in self.feature_names))
        if max(len(a) for a in self.atoms) > 3:
            raise InputError(f"library {self.name!r}: features with more than three factors")

    @property
    def n_features(self) -> int:
        """Number of candidate functions."""
        return len(self.feature_names)

    @property
    def params(self) -> dict:
        """JSON-ready description of how the library was built."""
        return {"name": self.name, "variables": list(self.variables), "n_features": self.n_features}

    @cached_property
    def _index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return atom-table column indices: factors ``(k, 3)``, derivative ``(nv, k)``, others ``(nv, k, 2)``.

        Column 0 of the atom table is the constant 1 (its derivative column is 0), column
        ``1 + var * 5 + code`` holds atom ``code`` of variable ``var``.
        """
        k, nv = self.n_features, len(self.variables)
        factors = np.zeros((k, 3), dtype=np.intp)
        d_idx = np.zeros((nv, k), dtype=np.intp)
        others = np.zeros((nv, k, 2), dtype=np.intp)
        for j, atoms in enumerate(self.atoms):
            cols = [1 + v * _N_CODES + c for v, c in atoms]
            factors[j, : len(cols)] = cols
            for m, (v, _) in enumerate(atoms):
                d_idx[v, j] = cols[m]
                rest = cols[:m] + cols[m + 1 :]
                others[v, j, : len(rest)] = rest
        return factors, d_idx, others

    def _atom_table(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return atom values and their derivatives, each ``(..., 1 + nv * 5)``."""
        a = np.abs(z)
        z2 = z * z
        vals = np.stack([z, z2, z2 * z, a, z * a], axis=-1)
        ders = np.stack([np.ones_like(z), 2 * z, 3 * z2, np.sign(z), 2 * a], axis=-1)
        shape = z.shape[:-1] + (-1,)
        one = np.ones(z.shape[:-1] + (1,))
        return (np.concatenate([one, vals.reshape(shape)], axis=-1),
                np.concatenate([0 * one, ders.reshape(shape)], axis=-1))

    def transform(self, z: np.ndarray) -> np.ndarray:
        """Return the features ``(..., k)`` of variables ``z`` ``(..., 5)`` = ``[x, u]``."""
        z = np.asarray(z, dtype=float)
        if z.shape[-1] != len(self.variables):
            raise InputError(f"library {self.name!r}: expected {len(self.variables)} variables, got {z.shape[-1]}")
        factors = self._index[0]
        a = np.concatenate([np.ones(z.shape[:-1] + (1,)),
                            np.stack([z, z * z, z**3, np.abs(z), z * np.abs(z)], -1).reshape(z.shape[:-1] + (-1,))],
                           axis=-1)
        return a[..., factors[:, 0]] * a[..., factors[:, 1]] * a[..., factors[:, 2]]

    def transform_with_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the features ``(..., k)`` and their derivatives ``d theta / d z`` ``(..., nv, k)``."""
        z = np.asarray(z, dtype=float)
        factors, d_idx, others = self._index
        a, da = self._atom_table(z)
        theta = a[..., factors[:, 0]] * a[..., factors[:, 1]] * a[..., factors[:, 2]]
        d_theta = da[..., d_idx] * a[..., others[..., 0]] * a[..., others[..., 1]]
        return theta, d_theta

    def pysindy(self):
        """Return the fitted pysindy library this one mirrors (for fitting and cross-checks)."""
        lib = _pysindy_library(self.name)
        lib.fit(np.random.default_rng(0).normal(size=(8, len(self.variables))))
        return lib


def make_library(name: str = "poly3") -> FeatureLibrary:
    """Return the library called ``name`` (one of :data:`LIBRARY_NAMES`), named by pysindy.

    Raises
    ------
    InputError
        If ``name`` is not a known library.
    """
    lib = _pysindy_library(name)
    lib.fit(np.zeros((4, len(LIBRARY_VARIABLE_NAMES))))
    return FeatureLibrary(name=name, feature_names=tuple(lib.get_feature_names(list(LIBRARY_VARIABLE_NAMES))))
