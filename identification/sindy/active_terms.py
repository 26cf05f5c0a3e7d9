"""SINDy terms evaluated fast: one model's active terms, and many models as one dynamics.

The filters evaluate the model four times per step on a few runs at a time, where numpy's
per-call overhead, not the arithmetic, is the cost; :class:`ActiveTerms` keeps that to a
handful of numpy calls whatever the model's size. :class:`StackedSindy` is many models of one
library as one :class:`groundfloor.dynamics.Dynamics`, for the search's rollout of all its grid
points at once.
"""

from __future__ import annotations

import numpy as np

from groundfloor.dynamics import Dynamics
from identification.sindy.library import FeatureLibrary


class ActiveTerms:
    """The active terms of coefficients ``coef (3, k)`` of a library, evaluated with their Jacobians.

    Returns the accelerations and their Jacobians in the six-state layout from one matrix
    product of a table of monomials with a fixed weight matrix ``(columns, 3 + 18 + 6)``: every
    active term adds its coefficient to the column of its monomial (accelerations) and, for each
    of its variables, exponent times coefficient to the column of the monomial one degree lower
    (product rule; Jacobians). Polynomial libraries take the table of all monomials of the five
    variables up to degree 3 as two outer products, so the whole evaluation is a handful of numpy
    calls whatever the model's size; libraries with ``|x|`` atoms gather each active term's
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
            def col(factors: list[int]) -> int:  # column of the monomial prod z[factors] (sorted)
                return sum(nv ** d for d in range(len(factors))) + sum(
                    f * nv ** (len(factors) - 1 - i) for i, f in enumerate(factors))

            self.weight = np.zeros((sum(nv ** d for d in range(4)), 27))
            for j, atoms in enumerate(library.atoms):
                c = coef[:, j]
                factors = sorted(v for v, code in atoms for _ in range(code + 1))
                self.weight[col(factors), :3] += c
                for v in set(factors):
                    rest = list(factors)
                    rest.remove(v)
                    self.weight[col(rest), [out(e, v) for e in range(3)]] += factors.count(v) * c
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

    def __call__(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``a (..., 3)``, ``J_a_x (..., 3, 6)`` and ``J_a_u (..., 3, 2)`` at ``z = [v_body, u] (..., 5)``."""
        lead = z.shape[:-1]
        weight = self.weight
        if self.monomials:
            z2 = z[..., :, None] * z[..., None, :]
            z3 = z2[..., None] * z[..., None, None, :]
            table = np.concatenate([z, z2.reshape(lead + (-1,)), z3.reshape(lead + (-1,))], axis=-1)
            out = table @ weight[1:] + weight[0]  # row 0: the constant monomial
        else:
            z2, az = z * z, np.abs(z)
            parts = [np.ones(lead + (1,)), z, z2, z2 * z, az, z * az, np.sign(z)]
            g = np.take(np.concatenate(parts, axis=-1), self.index, axis=-1)  # (..., 3, rows)
            out = (g[..., 0, :] * g[..., 1, :] * g[..., 2, :]) @ weight
        return out[..., :3], out[..., 3:21].reshape(lead + (3, 6)), out[..., 21:].reshape(lead + (3, 2))


class StackedSindy(Dynamics):
    """Many SINDy models of one library as one dynamics: ``coef (M, 3, k)``, states ``(M, W, 6)``.

    The search's rollout predicts the held-out windows ``(W,)`` of all ``M`` models at once;
    inputs ``(W, 2)`` are shared by the models.
    """

    name = "stacked_sindy"

    def __init__(self, library: FeatureLibrary, coef: np.ndarray, dead_time_s=(0.0, 0.0)):
        self.library, self.coef = library, coef
        self.dead_time_s = dead_time_s  # (2,) shared by the models, or (M, 2)

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
