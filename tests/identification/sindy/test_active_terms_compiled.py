"""The compiled RK4 step of an identified model against two implementations it does not share.

``SindyModel.rk4_step_and_jacobians`` (numba, :mod:`identification.sindy.active_terms`) is held
against (1) the generic numpy step of the dynamics interface, ``Dynamics.rk4_step_and_jacobians``,
which reaches the model through ``accel_and_jacobians``; (2) a classical RK4 step written here on
``SindyModel.f``, the library's own feature transform (``FeatureLibrary.transform``, not the
active-terms table); (3) central finite differences of that step for ``F`` and ``G``. Each also
with frozen extrapolation and an envelope that most of the states leave, so the clamping of the
nonlinear terms (``SindyModel.features``, written apart from the active terms) is exercised.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.dynamics import Dynamics
from identification.sindy.library import make_library
from identification.sindy.model import SindyModel

LIBRARIES = ("poly1", "poly2", "poly3", "poly3_absu")


FROZEN_ENVELOPE = {"vx": [-0.5, 0.6], "vy": [-0.2, 0.1], "omega": [-0.4, 0.5], "u1": [-1, 1], "u2": [-1, 1]}


def _model(library: str, seed: int, frozen: bool = False) -> SindyModel:
    """Return a model with about half of the library's terms active, coefficients of order 1
    (frozen outside :data:`FROZEN_ENVELOPE` when ``frozen``, which most test states leave)."""
    lib = make_library(library)
    rng = np.random.default_rng(seed)
    coef = rng.normal(size=(3, lib.n_features)) * (rng.random((3, lib.n_features)) < 0.5)
    if frozen:
        return SindyModel(lib, coef, envelope=FROZEN_ENVELOPE, extrapolation="frozen")
    return SindyModel(lib, coef)


def _states(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.column_stack([rng.normal(size=(m, 2)) * 3, rng.uniform(-3, 3, m), rng.normal(size=(m, 3)) * 0.7])
    return x, rng.uniform(-1, 1, (m, 2)), rng.uniform(0.005, 0.05, m)


def _rk4_by_hand(model: SindyModel, x: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
    """One classical RK4 step of eq. 5.75 with ``model.f`` (features from the library transform)."""
    def deriv(s):
        psi, vx, vy, w = s[2], s[3], s[4], s[5]
        a = model.f(s[3:], u)
        return np.array([vx * np.cos(psi) - vy * np.sin(psi), vx * np.sin(psi) + vy * np.cos(psi), w, *a])
    k1 = deriv(x)
    k2 = deriv(x + 0.5 * h * k1)
    k3 = deriv(x + 0.5 * h * k2)
    k4 = deriv(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


@pytest.mark.parametrize("frozen", (False, True))
@pytest.mark.parametrize("library", LIBRARIES)
def test_compiled_step_equals_the_generic_numpy_step(library, frozen):
    model = _model(library, 1, frozen)
    x, u, dt = _states(np.random.default_rng(2), 11)
    t = np.linspace(0, 3, 11)
    fast = model.rk4_step_and_jacobians(x, u, t, dt)
    slow = Dynamics.rk4_step_and_jacobians(model, x, u, t, dt)
    for got, want in zip(fast, slow):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-13)
    x_next, F, G = model.rk4_step_and_jacobians(x, u, t, dt, input_jacobian=False)
    assert G is None
    np.testing.assert_array_equal(F, fast[1])
    np.testing.assert_array_equal(x_next, fast[0])


@pytest.mark.parametrize("frozen", (False, True))
@pytest.mark.parametrize("library", LIBRARIES)
def test_compiled_step_and_jacobians_against_rk4_by_hand_and_finite_differences(library, frozen):
    model = _model(library, 3, frozen)
    x_all, u_all, dt_all = _states(np.random.default_rng(4), 4)
    for x, u, h in zip(x_all, u_all, dt_all):
        x_next, F, G = model.rk4_step_and_jacobians(x, u, 0.0, h)
        np.testing.assert_allclose(x_next, _rk4_by_hand(model, x, u, h), rtol=1e-12, atol=1e-13)
        eps = 1e-6
        F_num = np.column_stack([(_rk4_by_hand(model, x + d, u, h) - _rk4_by_hand(model, x - d, u, h)) / (2 * eps)
                                 for d in np.eye(6) * eps])
        G_num = np.column_stack([(_rk4_by_hand(model, x, u + d, h) - _rk4_by_hand(model, x, u - d, h)) / (2 * eps)
                                 for d in np.eye(2) * eps])
        np.testing.assert_allclose(F, F_num, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(G, G_num, rtol=1e-6, atol=1e-8)


def test_compiled_step_broadcasts_like_the_interface():
    """Leading shapes and a scalar step length broadcast as in the numpy step; one sample equals
    its row of a batch exactly (the compiled loop treats samples independently)."""
    model = _model("poly3", 5)
    x, u, _ = _states(np.random.default_rng(6), 6)
    batch = model.rk4_step_and_jacobians(x.reshape(2, 3, 6), u.reshape(2, 3, 2), 0.0, 0.02)
    assert [a.shape for a in batch] == [(2, 3, 6), (2, 3, 6, 6), (2, 3, 6, 2)]
    one = model.rk4_step_and_jacobians(x[4], u[4], 0.0, 0.02)
    for got, want in zip(one, batch):
        np.testing.assert_array_equal(got, want.reshape((6,) + want.shape[2:])[4])


def test_changed_coefficients_are_seen_by_the_compiled_step():
    """The compiled tables follow ``coef`` (the adjustment and the diagnosis change it in place)."""
    model = _model("poly2", 7)
    x, u, dt = _states(np.random.default_rng(8), 3)
    before = model.rk4_step_and_jacobians(x, u, 0.0, dt)[0]
    model.coef = model.coef * 1.5
    after = model.rk4_step_and_jacobians(x, u, 0.0, dt)[0]
    np.testing.assert_allclose(after, Dynamics.rk4_step_and_jacobians(model, x, u, 0.0, dt)[0], rtol=1e-12)
    assert np.max(np.abs(after - before)) > 1e-4


def test_frozen_extrapolation_changes_the_step_outside_the_envelope_only():
    """Inside the widened envelope frozen and polynomial models step alike; outside they differ
    (so the frozen tests above are not the polynomial ones again)."""
    plain, frozen = _model("poly3", 9), _model("poly3", 9, frozen=True)
    x_in = np.array([0.0, 0.0, 0.3, 0.1, -0.05, 0.1])
    x_out = np.array([0.0, 0.0, 0.3, 2.0, 0.8, -1.5])
    u = np.array([0.2, -0.1])
    np.testing.assert_allclose(frozen.rk4_step_and_jacobians(x_in, u, 0.0, 0.02)[0],
                               plain.rk4_step_and_jacobians(x_in, u, 0.0, 0.02)[0], rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(frozen.rk4_step_and_jacobians(x_out, u, 0.0, 0.02)[0]
                         - plain.rk4_step_and_jacobians(x_out, u, 0.0, 0.02)[0])) > 1e-3
