"""The diagnosis's two inner kernels against a hand computation, on the layouts the families hand them.

``Split.integrate`` (the window integrals of eq. 5.56) against scipy's trapezoid rule window by
window; ``normal_equations`` against its definition written out, with the windows in run order (a
slice per run, as ``split_from_states`` makes them) and with targets shared by every candidate (the
broadcast view an additive family passes), besides the shuffled runs of ``test_diagnose``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import trapezoid

from groundfloor.types import BodyStates
from identification.sindy.model import model_from_terms
from sindy_ekf.diagnose import columns
from sindy_ekf.diagnose.columns import PATCH_ZERO_M, patch_support, residual_and_columns
from sindy_ekf.diagnose.data import split_from_states
from sindy_ekf.diagnose.design import normal_equations, run_groups
from sindy_ekf.diagnose.families import FAMILY_SPECS, PATCH_EDGE_M


def _split(rng, lengths=(57, 80, 43), tau=0.4):
    states = []
    for n in lengths:
        t = np.cumsum(rng.uniform(0.015, 0.025, size=n))
        cols = rng.normal(size=(8, n))
        states.append(BodyStates(t=t, x=cols[0], y=cols[1], yaw=cols[2], vx=cols[3], vy=cols[4],
                                 omega=cols[5], u1=cols[6], u2=cols[7]))
    return split_from_states(states, [f"run_{i}" for i in range(len(lengths))], tau, stride_s=0.05)


def test_window_integrals_are_the_trapezoid_rule_over_each_window():
    rng = np.random.default_rng(11)
    sp = _split(rng)
    t = np.concatenate([[0.0], np.cumsum(sp.dt_next[:-1])])  # a run boundary adds no time (dt_next 0)
    values = rng.normal(size=(4, len(sp.run), 3))  # candidates x samples x columns
    got = sp.integrate(values)
    assert got.shape == (4, sp.n_windows, 3)
    for j, (a, e) in enumerate(zip(sp.start, sp.end)):
        assert sp.run[a] == sp.run[e]  # no window crosses a run's end
        want = trapezoid(values[:, a:e + 1], t[a:e + 1], axis=1)
        np.testing.assert_allclose(got[:, j], want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sp.integrate(values[0]), got[0], rtol=0, atol=0)  # no candidate axis


@pytest.mark.parametrize("where", ["inside", "at both ends", "none"])
def test_values_zero_but_at_some_samples_integrate_as_the_dense_ones_to_the_last_bit(where):
    rng = np.random.default_rng(12)
    sp = _split(rng)
    n = len(sp.run)
    idx = {"inside": np.sort(rng.choice(np.arange(1, n - 1), size=40, replace=False)),
           "at both ends": np.r_[0, 1, 56, 57, 58, n - 2, n - 1],  # a run's last sample, the next one's first
           "none": np.zeros(0, int)}[where]
    sparse = rng.normal(size=(3, len(idx), 2))
    dense = np.zeros((3, n, 2))
    dense[:, idx] = sparse
    np.testing.assert_array_equal(sp.integrate_sparse(sparse, idx), sp.integrate(dense))


def test_a_floor_patch_is_exactly_zero_beyond_its_support():
    # the support is a box around the patches' centres; the dense columns outside it must be 0 to the last
    # bit (the logistic edge's tanh is -1 there), or the sparse integrals would differ from the dense ones
    assert PATCH_ZERO_M >= 19.1 * PATCH_EDGE_M / (2 * np.log(9))
    rng = np.random.default_rng(4)
    fam = FAMILY_SPECS["position_dependence"]
    x6 = np.column_stack([rng.uniform(-20, 20, size=(5000, 2)), rng.normal(size=(5000, 4))])
    theta = np.column_stack([rng.uniform(-2, 2, size=(30, 2)), rng.choice([0.5, 0.8, 1.2, 1.8], size=30)])
    idx = patch_support(fam, x6[:, :3], theta)
    assert idx is not None and 0 < len(idx) < 1000
    cols = fam.columns(x6, np.zeros((5000, 2)), np.arange(5000.0), theta)
    outside = np.setdiff1d(np.arange(5000), idx)
    assert np.all(cols[:, outside] == 0.0) and np.any(cols[:, idx] != 0.0)


def test_patch_columns_on_their_support_are_the_dense_ones(monkeypatch):
    rng = np.random.default_rng(8)
    sp = _split(rng, lengths=(300, 250), tau=0.5)
    walk = np.cumsum(rng.normal(0, 0.8, size=(550, 2)), 0)  # a track over some 30 m, as outdoors
    sp = replace(sp, pose_local=np.column_stack([walk, sp.pose_local[:, 2]]))
    fam = FAMILY_SPECS["position_dependence"]
    grid = fam.grid(sp)
    theta = grid[grid[:, 0] <= grid[0, 0] + 0.5]  # the patches of the first two columns of centres
    idx = patch_support(fam, sp.pose_local, theta)
    assert idx is not None and 0 < len(idx) < 0.5 * len(sp.run)  # the sparse path is the one compared
    model = model_from_terms({"vx": {"vx": -1.0, "u1": 1.0}, "omega": {"omega": -2.0, "u2": 2.0}}, "poly1")
    y, X = residual_and_columns(fam, model, sp, theta, base_pred=np.zeros((sp.n_windows, 3)))
    monkeypatch.setattr(columns, "patch_support", lambda *a: None)
    y0, X0 = residual_and_columns(fam, model, sp, theta, base_pred=np.zeros((sp.n_windows, 3)))
    np.testing.assert_array_equal(X, X0)


def _by_definition(y, X, w, run, R):
    C, m = X.shape[0], X.shape[-1]
    G, b, yy = np.zeros((C, R, m, m)), np.zeros((C, R, m)), np.zeros((C, R))
    for c in range(C):
        for k in range(len(run)):
            for e in range(3):
                G[c, run[k]] += w[e] * np.outer(X[c, k, e], X[c, k, e])
                b[c, run[k]] += w[e] * X[c, k, e] * y[c, k, e]
                yy[c, run[k]] += w[e] * y[c, k, e] ** 2
    return G, b, yy


@pytest.mark.parametrize("shared_targets", [False, True])
def test_normal_equations_on_windows_in_run_order(shared_targets):
    rng = np.random.default_rng(5)
    sp = _split(rng)
    run, R, C, m = sp.window_run, len(sp.names), 3, 4
    assert all(isinstance(g, slice) for g in run_groups(run, R))
    y = rng.normal(size=(C, len(run), 3))
    if shared_targets:  # one target for every candidate, as a broadcast view
        y = np.broadcast_to(y[:1], y.shape)
    X, w = rng.normal(size=(C, len(run), 3, m)), rng.uniform(0.5, 2.0, size=3)
    d = normal_equations(y, X, w, run, R)
    for got, want in zip((d.G, d.b, d.yy), _by_definition(y, X, w, run, R)):
        np.testing.assert_allclose(got, want, rtol=1e-12)
    # the windows of different runs interleaved, each run's in its order: picked by masks, the same sums
    # to the last bit (the slices change where the data sit, not the order they are summed in)
    pos = rng.permutation(len(run))
    for r in range(R):
        pos[run == r] = np.sort(pos[run == r])
    yp, Xp, run_p = np.empty(y.shape), np.empty(X.shape), np.empty_like(run)
    yp[:, pos], Xp[:, pos], run_p[pos] = y, X, run
    assert not any(isinstance(g, slice) for g in run_groups(run_p, R))
    masked = normal_equations(yp, Xp, w, run_p, R)
    for k in ("G", "b", "yy"):
        np.testing.assert_array_equal(getattr(masked, k), getattr(d, k), err_msg=k)
