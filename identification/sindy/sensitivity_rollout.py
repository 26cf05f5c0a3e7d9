"""The output-error fit's inner loop, compiled: RK4 over all windows with the parameter sensitivities.

:func:`identification.sindy.output_error.rollout_with_sensitivities` integrates the states and
their sensitivities ``S = d x / d p`` through classical RK4 in numpy, one vectorised stage at a
time over the windows: about forty numpy calls per stage, 240 stages per 3 s window at 0.05 s,
so that on the output-error windows (a few hundred at most) the per-call overhead, not the
arithmetic, was the cost (``bench/results/identify_speed.md``). :func:`sensitivity_rollout` is
the same recursion for a SINDy structure in one compiled pass: the accelerations and their
Jacobians come from the model's :class:`~identification.sindy.active_terms.ActiveTerms` (the
filters' compiled evaluation, frozen extrapolation included), ``d a_e / d xi_(e, j)`` is the
feature ``theta_j`` (clamped like the accelerations' nonlinear terms), and each stage adds
``J_f_x S + d f / d p`` with the dead times' and input lags' columns from the input rates and lag
sensitivities the caller computed. The tests hold it against the numpy recursion and against
finite differences of :func:`identification.sindy.evaluate.rollout`.

numba keys the cache of the compiled kernel by this file alone: after editing
:func:`identification.sindy.active_terms._accel_into` (which it compiles in), remove this folder's
``__pycache__/*.nbi`` files, or the kernel runs the evaluation it was cached with. An install
writes every file anew and invalidates them all.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from identification.sindy.active_terms import N_OUT, ActiveTerms, _accel_into

_N_CODES = 5  # atoms per variable in FeatureLibrary's atom table: z, z^2, z^3, |z|, z |z|


def sensitivity_rollout(terms: ActiveTerms, param_eq: np.ndarray, param_factors: np.ndarray,
                        param_linear: np.ndarray, x0: np.ndarray, u_half: np.ndarray, dt: float, n: int,
                        u_rate: np.ndarray | None = None, u_dlag: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Return predicted states ``(W, n, 6)`` and their sensitivities ``(W, n, 6, P)``.

    ``terms`` are the model's active terms; the ``p`` model parameters are coefficients
    ``xi_(param_eq[m], j)`` whose feature is the product of the atom-table columns
    ``param_factors[m] (3,)`` (:attr:`FeatureLibrary._index`), evaluated at the unclamped body
    velocities where ``param_linear[m]``. ``x0 (W, 6)`` start states, ``u_half (W, 2n - 1, 2)``
    the inputs the model sees at the steps and their midpoints; ``u_rate`` (their time
    derivatives) adds the two dead-time columns, ``u_dlag`` (their derivatives in the input lags)
    the two lag columns, in that order after the ``p`` parameters.
    """
    n_d = 0 if u_rate is None else 2
    n_lag = 0 if u_dlag is None else 2
    n_par = len(param_eq) + n_d + n_lag
    W = len(x0)
    out_s = np.empty((W, n, 6))
    out_S = np.empty((W, n, 6, n_par))
    dummy = np.zeros((1, 1, 2))
    t = terms
    _sensitivity_rollout(np.ascontiguousarray(x0, dtype=float), np.ascontiguousarray(u_half, dtype=float),
                         dummy if u_rate is None else np.ascontiguousarray(u_rate, dtype=float),
                         dummy if u_dlag is None else np.ascontiguousarray(u_dlag, dtype=float),
                         float(dt), np.asarray(param_eq, dtype=np.intp),
                         np.ascontiguousarray(param_factors, dtype=np.intp), np.asarray(param_linear, dtype=np.bool_),
                         n_d, n_lag, t._n_table, t.monomials, t._prod_rows, t._prod_f0, t._prod_f1, t.index,
                         t._sp_rows, t._sp_ptr, t._sp_col, t._sp_w, t.frozen, t.lo, t.hi, t.lin_b, t.lin_W, out_s,
                         out_S)
    return out_s, out_S


@njit(cache=True)
def _atoms_into(table: np.ndarray, z: np.ndarray) -> None:
    """Write the atom table of ``z (5,)``: column 0 is 1, column ``1 + 5 v + code`` atom ``code`` of ``z_v``."""
    table[0] = 1.0
    for v in range(z.shape[0]):
        zv = z[v]
        az = abs(zv)
        b = 1 + _N_CODES * v
        table[b], table[b + 1], table[b + 2], table[b + 3], table[b + 4] = zv, zv * zv, zv * zv * zv, az, zv * az


@njit(cache=True)
def _sensitivity_rollout(x0, u_half, u_rate, u_dlag, dt, param_eq, param_factors, param_linear, n_d, n_lag,
                         n_table, monomials, prod_rows, prod_f0, prod_f1, index, sp_rows, sp_ptr, sp_col, sp_w, frozen,
                         lo, hi, lin_b, lin_W, out_s, out_S) -> None:
    """Write :func:`sensitivity_rollout`'s states and sensitivities into ``out_s``, ``out_S``.

    Per stage ``s`` at ``x_s = x + c_s k_{s-1}``, ``S_s = S + c_s K_{s-1}``:
    ``k_s = f(x_s, u)`` (eq. 5.75) and ``K_s = J_f_x S_s + d f / d p``; the step adds
    ``h / 6 (k_1 + 2 k_2 + 2 k_3 + k_4)`` to both (classical RK4, eqs. 5.70, 5.71). The loops over the
    parameters run along a row's contiguous slice with the stage's branches outside them, so that
    they compile to vector instructions (a third faster than the one loop over ``q`` with a
    conditional inside, to the same bits).
    """
    n_w, n = out_s.shape[0], out_s.shape[1]
    n_par = out_S.shape[3]
    p = param_eq.shape[0]
    table = np.empty(n_table)
    atoms = np.empty(1 + _N_CODES * 5)
    atoms_c = np.empty(1 + _N_CODES * 5)
    acc = np.empty(N_OUT)
    z = np.empty(5)
    zc = np.empty(5)
    x = np.empty(6)
    S = np.empty((6, n_par))
    xs = np.empty(6)
    Ss = np.empty((6, n_par))
    k = np.empty((4, 6))
    K = np.empty((4, 6, n_par))
    for w in range(n_w):
        for r in range(6):
            x[r] = x0[w, r]
            out_s[w, 0, r] = x[r]
            for q in range(n_par):
                S[r, q] = 0.0
                out_S[w, 0, r, q] = 0.0
        for i in range(n - 1):
            for s in range(4):
                j = 2 * i + (0 if s == 0 else (1 if s < 3 else 2))
                if s == 0:
                    for r in range(6):
                        xs[r] = x[r]
                        Sr = S[r]
                        Ssr = Ss[r]
                        for q in range(n_par):
                            Ssr[q] = Sr[q]
                else:
                    c = 0.5 * dt if s < 3 else dt
                    for r in range(6):
                        xs[r] = x[r] + c * k[s - 1, r]
                        Sr = S[r]
                        Ssr = Ss[r]
                        Kr = K[s - 1, r]
                        for q in range(n_par):
                            Ssr[q] = Sr[q] + c * Kr[q]
                z[0], z[1], z[2], z[3], z[4] = xs[3], xs[4], xs[5], u_half[w, j, 0], u_half[w, j, 1]
                _accel_into(acc, table, z, zc, True, monomials, prod_rows, prod_f0, prod_f1, index, sp_rows, sp_ptr,
                            sp_col, sp_w, frozen, lo, hi, lin_b, lin_W)
                cp, sp = math.cos(xs[2]), math.sin(xs[2])
                k[s, 0] = cp * xs[3] - sp * xs[4]
                k[s, 1] = sp * xs[3] + cp * xs[4]
                k[s, 2] = xs[5]
                for e in range(3):
                    k[s, 3 + e] = acc[e]
                # J_f_x S: the pose rows of eq. 5.75's Jacobian, the accelerations' on the velocities
                nk1 = -k[s, 1]
                k0 = k[s, 0]
                S2 = Ss[2]
                S3 = Ss[3]
                S4 = Ss[4]
                S5 = Ss[5]
                K0 = K[s, 0]
                K1 = K[s, 1]
                K2 = K[s, 2]
                for q in range(n_par):
                    K0[q] = nk1 * S2[q] + cp * S3[q] - sp * S4[q]
                    K1[q] = k0 * S2[q] + sp * S3[q] + cp * S4[q]
                    K2[q] = S5[q]
                for e in range(3):
                    b = 3 + 6 * e + 3
                    a0, a1, a2 = acc[b], acc[b + 1], acc[b + 2]
                    Ke = K[s, 3 + e]
                    for q in range(n_par):
                        Ke[q] = a0 * S3[q] + a1 * S4[q] + a2 * S5[q]
                _atoms_into(atoms, z)
                if frozen:
                    _atoms_into(atoms_c, zc)  # _accel_into left the clamped variables in zc
                for m in range(p):
                    a = atoms if (param_linear[m] or not frozen) else atoms_c
                    K[s, 3 + param_eq[m], m] += a[param_factors[m, 0]] * a[param_factors[m, 1]] * \
                        a[param_factors[m, 2]]
                for v in range(n_d):  # d f / d d_v = -J_f_u[:, v] du_v/dt
                    for e in range(3):
                        K[s, 3 + e, p + v] -= acc[21 + 2 * e + v] * u_rate[w, j, v]
                for v in range(n_lag):  # d f / d T_v = J_f_u[:, v] du_v/dT_v
                    for e in range(3):
                        K[s, 3 + e, p + n_d + v] += acc[21 + 2 * e + v] * u_dlag[w, j, v]
            h6 = dt / 6.0
            for r in range(6):
                x[r] = x[r] + h6 * (k[0, r] + 2.0 * k[1, r] + 2.0 * k[2, r] + k[3, r])
                out_s[w, i + 1, r] = x[r]
                Sr = S[r]
                K0 = K[0, r]
                K1 = K[1, r]
                K2 = K[2, r]
                K3 = K[3, r]
                o = out_S[w, i + 1, r]
                for q in range(n_par):
                    Sr[q] = Sr[q] + h6 * (K0[q] + 2.0 * K1[q] + 2.0 * K2[q] + K3[q])
                    o[q] = Sr[q]
