"""The active terms of an identified SINDy model, evaluated for the filters: numpy and compiled.

:class:`ActiveTerms` turns a library and its coefficients ``Xi`` (eq. 5.53) into a fixed table of
monomials (or atoms) and a weight matrix, so that the accelerations and their Jacobians are one
product whatever the model's size. Two evaluations share that table:

- :meth:`ActiveTerms.__call__`, numpy, vectorised over any leading axes (the evaluation's
  rollouts, the search, the diagnosis);
- :meth:`ActiveTerms.rk4_step`, the held-input RK4 step of eqs. 5.70 and 5.71 with its exact
  chain-rule Jacobians, compiled with numba (:func:`_rk4_steps`): the filters call it once per
  grid step on a few runs at a time, where numpy's per-call overhead (about a hundred calls per
  step), not the arithmetic, was the cost (``bench/results/ekf_speed.md``). It computes what
  ``groundfloor.dynamics.Dynamics.rk4_step_and_jacobians`` computes from :meth:`__call__`; the
  tests hold the two against each other and against finite differences.

Both evaluate *frozen extrapolation* when given the widened training envelope of the body
velocities: the nonlinear terms see the velocities clamped to it while the constant and linear
terms go on linearly (:class:`identification.sindy.model.SindyModel`). :class:`StackedSindy` is
many models of one library as one :class:`groundfloor.dynamics.Dynamics`, for the search's
rollout of all its grid points at once.
"""

from __future__ import annotations

import math
from itertools import combinations_with_replacement

import numpy as np
from numba import njit

from groundfloor.dynamics import Dynamics
from identification.sindy.library import FeatureLibrary

N_X = 6  # [x, y, psi, vx, vy, omega] (eq. 5.60)
N_OUT_X = 3 + 18  # accelerations and J_a_x (3, 6): the columns the EKF's F needs
N_OUT = N_OUT_X + 6  # and J_a_u (3, 2)


def linear_part(library: FeatureLibrary, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the constant ``b (3,)`` and the matrix ``W (3, 5)`` of the linear columns of ``coef``."""
    b, W = np.zeros(3), np.zeros((3, len(library.variables)))
    for j, atoms in enumerate(library.atoms):
        if not atoms:
            b += coef[:, j]
        elif len(atoms) == 1 and atoms[0][1] == 0:
            W[:, atoms[0][0]] += coef[:, j]
    return b, W


def linear_columns(library: FeatureLibrary) -> np.ndarray:
    """Return per feature whether it is the constant or a plain variable (extrapolates linearly)."""
    return np.array([len(a) == 0 or (len(a) == 1 and a[0][1] == 0) for a in library.atoms])


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

    With ``frozen = (lo (3,), hi (3,))`` the nonlinear terms are evaluated at the body velocities
    clamped to ``[lo, hi]`` (a clamped velocity moves none of them) and the constant and linear
    terms at the velocities themselves.
    """

    # atom code (^1, ^2, ^3, abs, signsq) -> table block of its value; of its derivative and factor
    _VALUE = ("z", "z2", "z3", "abs", "zabs")
    _DERIV = ((None, 1.0), ("z", 2.0), ("z2", 3.0), ("sign", 1.0), ("abs", 2.0))

    def __init__(self, library: FeatureLibrary, coef: np.ndarray, frozen: tuple | None = None):
        nv = len(library.variables)  # [vx, vy, omega, u1, u2]
        self.frozen = frozen is not None
        self.lo, self.hi = (np.full(3, -np.inf), np.full(3, np.inf)) if frozen is None else \
            (np.asarray(frozen[0], float).copy(), np.asarray(frozen[1], float).copy())
        self.lin_b, self.lin_W = np.zeros(3), np.zeros((3, nv))
        if self.frozen:
            lin = linear_columns(library)
            self.lin_b, self.lin_W = linear_part(library, np.where(lin, coef, 0.0))
            coef = np.where(lin, 0.0, coef)
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
            self.index = np.zeros((3, 0), dtype=np.intp)
        else:
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
        self.weight_a = np.ascontiguousarray(self.weight[:, :3])  # accelerations alone: a smaller product
        # the compiled step's view of the same tables: the degree-by-degree products flattened
        if self.monomials:
            self._prod_rows = np.concatenate([np.arange(r.start, r.stop) for r, _ in self.products])
            self._prod_f0, self._prod_f1 = np.concatenate([f for _, f in self.products], axis=1)
            self._n_table = len(self.weight)
        else:
            self._prod_rows = self._prod_f0 = self._prod_f1 = np.zeros(0, dtype=np.intp)
            self._n_table = 1 + 6 * nv
        # the compiled evaluation's weights: the non-zero entries of the rows that carry one, row by
        # row (about an eighth of the dense table for a model of a few dozen poly3 terms): row
        # _sp_rows[q] holds the entries _sp_ptr[q]:_sp_ptr[q + 1] of _sp_col and _sp_w
        self._sp_rows = np.flatnonzero(np.any(self.weight != 0, axis=1)).astype(np.intp)
        r, c = np.nonzero(self.weight[self._sp_rows])
        self._sp_ptr = np.searchsorted(r, np.arange(len(self._sp_rows) + 1)).astype(np.intp)
        self._sp_col = c.astype(np.intp)
        self._sp_w = self.weight[self._sp_rows[r], c].copy()

    def __call__(self, v_body: np.ndarray, u: np.ndarray, jacobians: bool = True):
        """Return ``a (..., 3)``, ``J_a_x (..., 3, 6)`` and ``J_a_u (..., 3, 2)`` at body velocities
        ``v_body (..., 3)`` and inputs ``u (..., 2)`` of one leading shape; ``a`` alone if not ``jacobians``."""
        lead = v_body.shape[:-1]
        n = math.prod(lead)
        weight = self.weight if jacobians else self.weight_a
        if self.frozen:
            v_free = v_body
            linear = self.lin_b + v_free @ self.lin_W[:, :3].T + u @ self.lin_W[:, 3:].T
            v_body = np.clip(v_free, self.lo, self.hi)
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
            return out + linear if self.frozen else out
        a, J_x, J_u = out[..., :3], out[..., 3:21].reshape(lead + (3, 6)), out[..., 21:].reshape(lead + (3, 2))
        if self.frozen:  # a clamped velocity moves no nonlinear term; the linear ones add theirs
            J_x[..., 3:] *= (v_body == v_free)[..., None, :]
            J_x[..., 3:] += self.lin_W[:, :3]
            return a + linear, J_x, J_u + self.lin_W[:, 3:]
        return a, J_x, J_u

    def rk4_step(self, x6: np.ndarray, u: np.ndarray, dt, input_jacobian: bool = True
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Return the held-input RK4 step ``x_next (..., 6)`` and its exact Jacobians ``F (..., 6, 6)``
        and ``G (..., 6, 2)`` (``None`` unless ``input_jacobian``), compiled (:func:`_rk4_steps`).

        ``x6 (..., 6)``, ``u (..., 2)`` and ``dt`` (s, scalar or ``(...)``) broadcast to one leading
        shape. The dynamics do not depend on time, so no time is passed.
        """
        x6, u, dt = np.asarray(x6, dtype=float), np.asarray(u, dtype=float), np.asarray(dt, dtype=float)
        lead = x6.shape[:-1]
        if u.shape[:-1] != lead or dt.shape != lead:  # the filters' case (one shape) skips this: per
            # grid step the broadcasting cost several times the compiled step itself
            lead = np.broadcast_shapes(lead, u.shape[:-1], dt.shape)
            x6, u, dt = (np.broadcast_to(x6, lead + (N_X,)), np.broadcast_to(u, lead + (2,)),
                         np.broadcast_to(dt, lead))
        m = math.prod(lead)
        x = np.ascontiguousarray(x6).reshape(m, N_X)
        uu = np.ascontiguousarray(u).reshape(m, 2)
        h = np.ascontiguousarray(dt).reshape(m)
        x_next, F = np.empty((m, N_X)), np.empty((m, N_X, N_X))
        G = np.empty((m, N_X, 2) if input_jacobian else (0, N_X, 2))
        _rk4_steps(x, uu, h, input_jacobian, self._n_table, self.monomials, self._prod_rows, self._prod_f0,
                   self._prod_f1, self.index, self._sp_rows, self._sp_ptr, self._sp_col, self._sp_w, self.frozen,
                   self.lo, self.hi, self.lin_b, self.lin_W, x_next, F, G)
        return (x_next.reshape(lead + (N_X,)), F.reshape(lead + (N_X, N_X)),
                G.reshape(lead + (N_X, 2)) if input_jacobian else None)


@njit(cache=True)
def _terms_into(out: np.ndarray, table: np.ndarray, z: np.ndarray, n_out: int, monomials: bool,
                prod_rows: np.ndarray, prod_f0: np.ndarray, prod_f1: np.ndarray,
                index: np.ndarray, sp_rows: np.ndarray, sp_ptr: np.ndarray, sp_col: np.ndarray,
                sp_w: np.ndarray) -> None:
    """Write ``sum_r feature_r(z) weight[r, :n_out]`` into ``out`` (one sample ``z (5,)``).

    The compiled twin of :meth:`ActiveTerms.__call__`: the same table (monomials built degree by
    degree from ``prod_*``, or the atom blocks ``1, z, z^2, z^3, |z|, z|z|, sign z`` gathered by
    ``index``) and the same weights, as their non-zero entries row by row (``weight[sp_rows[q],
    sp_col[k]] = sp_w[k]`` for ``k`` in ``sp_ptr[q]:sp_ptr[q + 1]``): each output sums its terms in
    the order of the rows, as the dense product does (the same bits where the features are
    finite; a zero weight no longer turns an infinite feature into a NaN).
    """
    nv = z.shape[0]
    # 1 and z lead both tables; the monomials' products follow (none for an atom table). Built
    # outside any branch: inside one the compiled evaluation took half as long again (measured)
    table[0] = 1.0
    for v in range(nv):
        table[1 + v] = z[v]
    for p in range(prod_rows.shape[0]):  # degree 2 rows first, then degree 3 from them
        table[prod_rows[p]] = table[prod_f0[p]] * table[prod_f1[p]]
    if not monomials:
        for v in range(nv):
            zv = z[v]
            az = abs(zv)
            table[1 + nv + v] = zv * zv
            table[1 + 2 * nv + v] = zv * zv * zv
            table[1 + 3 * nv + v] = az
            table[1 + 4 * nv + v] = zv * az
            table[1 + 5 * nv + v] = np.sign(zv)
    for c in range(n_out):
        out[c] = 0.0
    for q in range(sp_rows.shape[0]):
        r = sp_rows[q]
        g = table[r] if monomials else table[index[0, r]] * table[index[1, r]] * table[index[2, r]]
        for k in range(sp_ptr[q], sp_ptr[q + 1]):
            c = sp_col[k]
            if c < n_out:
                out[c] += g * sp_w[k]


@njit(cache=True)
def _accel_into(acc: np.ndarray, table: np.ndarray, z: np.ndarray, zc: np.ndarray, want_g: bool, monomials: bool,
                prod_rows: np.ndarray, prod_f0: np.ndarray, prod_f1: np.ndarray, index: np.ndarray,
                sp_rows: np.ndarray, sp_ptr: np.ndarray, sp_col: np.ndarray, sp_w: np.ndarray, frozen: bool,
                lo: np.ndarray, hi: np.ndarray, lin_b: np.ndarray, lin_W: np.ndarray) -> None:
    """Write the accelerations, ``J_a_x`` and (if ``want_g``) ``J_a_u`` at ``z = [v_body, u] (5,)``
    into ``acc`` (the :data:`N_OUT` columns of :class:`ActiveTerms`); ``zc (5,)`` is scratch.

    With ``frozen`` the nonlinear terms see the body velocities clamped to ``[lo, hi]`` and the
    linear part ``lin_b + lin_W z`` is added (:class:`ActiveTerms`).
    """
    n_out = N_OUT if want_g else N_OUT_X
    if not frozen:
        _terms_into(acc, table, z, n_out, monomials, prod_rows, prod_f0, prod_f1, index, sp_rows, sp_ptr, sp_col, sp_w)
        return
    for v in range(5):
        zc[v] = min(max(z[v], lo[v]), hi[v]) if v < 3 else z[v]
    _terms_into(acc, table, zc, n_out, monomials, prod_rows, prod_f0, prod_f1, index, sp_rows, sp_ptr, sp_col, sp_w)
    for e in range(3):
        acc[e] += lin_b[e]
        for v in range(5):
            acc[e] += lin_W[e, v] * z[v]
        for v in range(3):
            c_ev = 3 + 6 * e + 3 + v
            acc[c_ev] = (acc[c_ev] if zc[v] == z[v] else 0.0) + lin_W[e, v]
        if want_g:
            acc[21 + 2 * e] += lin_W[e, 3]
            acc[22 + 2 * e] += lin_W[e, 4]


@njit(cache=True)
def _rk4_steps(x: np.ndarray, u: np.ndarray, dt: np.ndarray, want_g: bool, n_table: int, monomials: bool,
               prod_rows: np.ndarray, prod_f0: np.ndarray, prod_f1: np.ndarray, index: np.ndarray,
               sp_rows: np.ndarray, sp_ptr: np.ndarray, sp_col: np.ndarray, sp_w: np.ndarray, frozen: bool,
               lo: np.ndarray, hi: np.ndarray, lin_b: np.ndarray, lin_W: np.ndarray, x_next: np.ndarray,
               F: np.ndarray, G: np.ndarray) -> None:
    """Write the held-input RK4 step (eqs. 5.70, 5.71) of every sample and its exact Jacobians.

    ``x (m, 6)``, ``u (m, 2)``, ``dt (m,)``; out: ``x_next (m, 6)``, ``F (m, 6, 6)`` and, if
    ``want_g``, ``G (m, 6, 2)``. Each stage evaluates the eq. 5.75 derivative (body velocities
    rotated by ``psi``, accelerations from :func:`_terms_into`) with its Jacobians ``A_s``,
    ``B_s``; the step's Jacobians follow the chain rule ``D_s = A_s (I + c_s h D_{s-1})``.
    With ``frozen`` the nonlinear terms see the body velocities clamped to ``[lo, hi]`` and the
    linear part ``lin_b + lin_W z`` is added (:func:`_accel_into`).
    """
    table = np.empty(n_table)
    acc = np.empty(N_OUT)
    z = np.empty(5)
    zc = np.empty(5)
    xs = np.empty(N_X)
    k = np.empty((4, N_X))
    A = np.zeros((4, N_X, N_X))
    B = np.zeros((4, N_X, 2))
    D = np.empty((N_X, N_X))
    Dn = np.empty((N_X, N_X))
    Du = np.empty((N_X, 2))
    Dun = np.empty((N_X, 2))
    Fs = np.empty((N_X, N_X))
    Gs = np.empty((N_X, 2))
    for i in range(x.shape[0]):
        h = dt[i]
        hh = 0.5 * h
        for s in range(4):
            c = 0.0 if s == 0 else (hh if s < 3 else h)
            for j in range(N_X):
                xs[j] = x[i, j] + (c * k[s - 1, j] if s > 0 else 0.0)
            z[0], z[1], z[2], z[3], z[4] = xs[3], xs[4], xs[5], u[i, 0], u[i, 1]
            _accel_into(acc, table, z, zc, want_g, monomials, prod_rows, prod_f0, prod_f1, index, sp_rows, sp_ptr,
                        sp_col, sp_w, frozen, lo, hi, lin_b, lin_W)
            cp, sp = math.cos(xs[2]), math.sin(xs[2])
            k[s, 0] = cp * xs[3] - sp * xs[4]
            k[s, 1] = sp * xs[3] + cp * xs[4]
            k[s, 2] = xs[5]
            A[s, 0, 2], A[s, 1, 2] = -k[s, 1], k[s, 0]
            A[s, 0, 3], A[s, 0, 4], A[s, 1, 3], A[s, 1, 4], A[s, 2, 5] = cp, -sp, sp, cp, 1.0
            for e in range(3):
                k[s, 3 + e] = acc[e]
                for j in range(N_X):
                    A[s, 3 + e, j] = acc[3 + 6 * e + j]
                if want_g:
                    B[s, 3 + e, 0], B[s, 3 + e, 1] = acc[21 + 2 * e], acc[22 + 2 * e]
        for j in range(N_X):
            x_next[i, j] = x[i, j] + (hh / 3.0) * (k[0, j] + 2.0 * (k[1, j] + k[2, j]) + k[3, j])
        # F = I + h/6 (A_1 + 2 D_2 + 2 D_3 + D_4); G likewise from B_1 and the D_s^u
        Fs[:, :] = A[0]
        D[:, :] = A[0]
        Gs[:, :] = B[0]
        Du[:, :] = B[0]
        for s in range(1, 4):
            c = hh if s < 3 else h
            for r in range(N_X):
                for q in range(N_X):
                    acc_rq = 0.0
                    for p in range(N_X):
                        acc_rq += A[s, r, p] * D[p, q]
                    Dn[r, q] = A[s, r, q] + c * acc_rq
                if want_g:
                    for q in range(2):
                        acc_rq = 0.0
                        for p in range(N_X):
                            acc_rq += A[s, r, p] * Du[p, q]
                        Dun[r, q] = B[s, r, q] + c * acc_rq
            w = 2.0 if s < 3 else 1.0
            D[:, :] = Dn
            Fs += w * Dn
            if want_g:
                Du[:, :] = Dun
                Gs += w * Dun
        for r in range(N_X):
            for q in range(N_X):
                F[i, r, q] = (hh / 3.0) * Fs[r, q] + (1.0 if r == q else 0.0)
            if want_g:
                for q in range(2):
                    G[i, r, q] = (hh / 3.0) * Gs[r, q]


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
